"""Direct-sun visibility from the model's own geometry: a deep opacity map seen from the sun.

A camera far out along the sun direction ω_s (:data:`SUN_DISTANCE_M`: over a scene of a few hundred
metres its rays are parallel to ~1e-2 rad) sees the Gaussians as the sun does. Rasterizing, for
depth planes t_1 < … < t_S along its rays, the feature [t_k < t_m] of every Gaussian k gives at each
pixel the blending weight in front of each plane, Σ_{k: t_k < t_m} w_k = 1 − T(t_m): one minus the
transmittance of the sun's light down to that depth (front-to-back compositing). A Gaussian's
visibility is that transmittance at ``bias_m`` in front of its centre, read at its projection
(bilinear across pixels, linear between planes):

    V_k = T(u_k, v_k, t_k − bias)          (k: Gaussian; u, v: pixel in the sun camera; t: depth along ω_s)

The sun camera's pixels are sized by the Gaussians (:data:`PIXEL_SCALES`) and the bias is
:data:`BIAS_SCALES` of their median size divided by the cosine of the sun zenith (a slope-scaled
bias, as shadow maps use, for the ground's slope toward the sun), so that the ground does not shadow
itself however low the sun. (Each Gaussian's own normal for the slope measured worse on trained
models: their normals are too noisy.) A view's
visibility map is V rendered as a feature with the view's blending weights, divided by the view's
opacity: the share of the surface seen in the pixel that the direct sun reaches (1 lit, 0 in shadow,
NaN where the view sees nothing). The acquisition's shadows baked into the appearance are not in V:
it is the geometry's answer for any sun.

A model trained with shadows (option ``shadows``) renders the reflectance of the lit surface times
the illumination (1 − f_b) V + f_b (:func:`sun_sky_light`; f_b the scene's diffuse fraction,
:mod:`brfgs.data.sky`), V blended per pixel: a shadow is then illumination, not albedo, and moves
with the sun.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from brfgs.data.cameras import Intrinsics, look_at_c2w
from brfgs.data.sky import clear_sky_diffuse_fraction
from brfgs.model.camera import Camera, camera_from_intrinsics
from brfgs.model.rendering import rasterize_splats

__all__ = ["SUN_DISTANCE_M", "SUN_MAP_PX", "sun_camera", "gaussian_visibility", "gaussian_sun_visibility",
           "scene_diffuse_fraction", "pixel_visibility", "sun_sky_light"]

SUN_DISTANCE_M = 1.0e4     # the sun camera's distance from the scene
SUN_MAP_PX = 768           # the sun camera's largest image side (pixels; 96 planes: ~230 MB)
BIAS_SCALES = 2.0          # default bias: this many median Gaussian sizes (largest axis)
MIN_COS = 0.25             # the slope-scaled bias grows as 1 / cos(sun zenith) down to this cosine
PIXEL_SCALES = 0.75        # sun camera pixel: this many median Gaussian sizes (within SUN_MAP_PX a side)
SLABS = 96                 # depth planes of the sun camera's opacity map


def sun_camera(means: Tensor, omega_sun: Tensor, size_px: int = SUN_MAP_PX, pixel_m: float | None = None) -> Camera:
    """A square camera at :data:`SUN_DISTANCE_M` along ``omega_sun`` [3] (unit, toward the sun) from the
    median of ``means`` [N, 3] (m), looking back at it, its field of view just holding 99.8 % of the
    means (robust to far outliers); ``size_px`` pixels a side, or fewer when ``pixel_m`` (m, at the
    scene) asks for coarser pixels (at least 64)."""
    m = means.detach().double().numpy()  # [N, 3]
    centre = np.median(m, axis=0)
    w = np.asarray(omega_sun, np.float64)
    c2w = look_at_c2w(centre + SUN_DISTANCE_M * w, centre)
    right, up, back = c2w[:3, 0], c2w[:3, 1], c2w[:3, 2]
    rel = m - c2w[:3, 3]                                   # [N, 3]
    depth = -(rel @ back)                                   # [N] > 0 in front
    tan = np.maximum(np.abs(rel @ right), np.abs(rel @ up)) / np.maximum(depth, 1e-6)
    half = float(np.quantile(tan, 0.998)) * 1.02 + 1e-9
    if pixel_m is not None and pixel_m > 0:
        size_px = int(np.clip(np.ceil(2 * half * SUN_DISTANCE_M / pixel_m), 64, size_px))
    f = 0.5 * size_px / half
    intr = Intrinsics(fl_x=f, fl_y=f, cx=0.5 * size_px, cy=0.5 * size_px, w=int(size_px), h=int(size_px))
    return camera_from_intrinsics(c2w, intr, "sun")


def _bilinear_rows(img: Tensor, u: Tensor, v: Tensor) -> Tensor:  # img [H, W, C], u, v [N] px -> [N, C]
    """Bilinear sample of every channel at pixel coordinates (pixel centres at +0.5), edge-clamped."""
    h, w = img.shape[:2]
    x = (u - 0.5).clamp(0, w - 1)
    y = (v - 0.5).clamp(0, h - 1)
    x0, y0 = x.floor().long().clamp(max=max(w - 2, 0)), y.floor().long().clamp(max=max(h - 2, 0))
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x1] * fx * (1 - fy)
            + img[y1, x0] * (1 - fx) * fy + img[y1, x1] * fx * fy)


def gaussian_visibility(
    means: Tensor,  # [N, 3] m
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3] m
    opacities: Tensor,  # [N]
    omega_sun: Tensor,  # [3] unit, toward the sun
    size_px: int = SUN_MAP_PX,
    bias_m: float | None = None,
    slabs: int = SLABS,
    backend: str = "auto",
) -> Tensor:  # [N] in [0, 1]
    """V_k of every Gaussian for the sun direction ``omega_sun``: the transmittance T_k along the sun's
    ray up to a bias in front of the Gaussian's centre (see the module docstring): ``bias_m`` (m;
    default :data:`BIAS_SCALES` × the median of the Gaussians' largest axes) / cos(sun zenith)."""
    with torch.no_grad():
        means, quats, scales, opacities = (t.detach().contiguous() for t in (means, quats, scales, opacities))
        scale = float(scales.max(1).values.median())
        cam = sun_camera(means, omega_sun, size_px, PIXEL_SCALES * scale)
        vm = cam.viewmat.to(means.dtype)
        t = means @ vm[2, :3] + vm[2, 3]                               # [N] m along the sun's rays
        rel = t - t.median()                                           # [N] (float32-safe)
        edges = torch.linspace(float(rel.min()), float(rel.max()), slabs, dtype=means.dtype)  # [S]
        in_front = (rel[:, None] < edges[None, :]).to(means.dtype)     # [N, S] 1 before edge m
        occ = rasterize_splats(means, quats, scales, opacities, in_front, cam, backend).image.to(means.dtype)
        K = cam.K.to(means.dtype)
        x, y = means @ vm[0, :3] + vm[0, 3], means @ vm[1, :3] + vm[1, 3]
        a_k = _bilinear_rows(occ, K[0, 0] * x / t + K[0, 2], K[1, 1] * y / t + K[1, 2])  # [N, S] 1 − T at edges
        slant = float(omega_sun[2].clamp_min(MIN_COS))                 # cos of the sun zenith: ground's slope
        bias = (BIAS_SCALES * scale if bias_m is None else float(bias_m)) / slant      # m, slope-scaled
        step = max(float(edges[-1] - edges[0]) / max(slabs - 1, 1), 1e-9)
        pos = ((rel - bias - edges[0]) / step).clamp(0, slabs - 1)    # [N] fractional edge index
        lo = pos.floor().long().clamp(max=slabs - 2) if slabs > 1 else pos.long() * 0
        hi = (lo + 1).clamp(max=slabs - 1)
        frac = pos - lo
        occluded = a_k.gather(1, lo[:, None])[:, 0] * (1 - frac) + a_k.gather(1, hi[:, None])[:, 0] * frac
        return (1.0 - occluded).clamp(0, 1)


def gaussian_sun_visibility(model, sun_zenith_deg: float, sun_azimuth_deg: float,
                            size_px: int = SUN_MAP_PX, bias_m: float | None = None, slabs: int = SLABS,
                            backend: str = "auto") -> Tensor:  # [N] in [0, 1]
    """:func:`gaussian_visibility` of the Gaussians of ``model`` (a :class:`brfgs.model.trained.TrainedModel`)
    for the sun (deg)."""
    f = model.frozen()
    omega = model.sun_direction(sun_zenith_deg, sun_azimuth_deg).to(f["means"].dtype)
    return gaussian_visibility(f["means"], f["quats"], f["scales"], f["opacities"], omega, size_px, bias_m, slabs,
                               backend)


def scene_diffuse_fraction(scene: dict, frame: int | None = None,
                           sun_zenith_deg: float | None = None) -> Tensor:  # [B] float32
    """f_b of a scene description (:func:`brfgs.model.camera.scene_description`): frame ``frame``'s own
    ``diffuse_fraction`` when given and it has one, else the scene's, else the clear-sky default of
    :mod:`brfgs.data.sky` for the sun ``sun_zenith_deg`` (default: the frame's, else the scene's)."""
    fr = scene["frames"][frame] if frame is not None else {}
    f = fr.get("diffuse_fraction")
    f = scene.get("diffuse_fraction") if f is None else f
    if f is None:
        z = sun_zenith_deg if sun_zenith_deg is not None else fr.get("sun_zenith_deg", scene["sun_zenith_deg"])
        alt = (scene.get("origin") or {}).get("altitude_m", 0.0)
        f = clear_sky_diffuse_fraction(np.asarray(scene["wavelengths_nm"], float), float(z), float(alt))
    return torch.as_tensor(np.asarray(f, np.float64), dtype=torch.float32)


def pixel_visibility(
    blended: Tensor,  # [...] the Gaussians' visibilities V rendered as a feature (premultiplied)
    alpha: Tensor,  # [...] the pixels' opacity
) -> Tensor:  # [...]
    """The direct-sun visibility of rendered pixels: the blended V plus the background's share 1 − α,
    which is lit."""
    return blended + (1.0 - alpha.to(blended.dtype))


def sun_sky_light(
    diffuse_fraction: Tensor,  # [B] f_b, sky share of the downwelling irradiance
    visibility: Tensor,  # [...] direct-sun visibility V in [0, 1]
) -> Tensor:  # [..., B]
    """Illumination relative to the open sky, (1 − f_b) V + f_b: the sun's direct share where it
    reaches (V = 1), the sky's alone in full shadow (V = 0). The rendered reflectance of a shadowed
    model is the surface's reflectance times this (sky-view factor 1)."""
    f = diffuse_fraction.to(visibility.dtype)
    return (1.0 - f) * visibility[..., None] + f
