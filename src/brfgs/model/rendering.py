"""The one render path: a trained model and a camera -> latent, reflectance cube, CIR, alpha,
depth and normal maps.

:func:`render` is what evaluation, ``brfgs render``, ``brf``, ``products``, ``export``, the
benchmarks and every later feature call. Per Gaussian it evaluates the appearance head for the
sun (paper eq. 12; :mod:`brfgs.model.features`), rasterizes (premultiplied,
:func:`brfgs.render.rasterize`), composites the learned background with (1 − α) and decodes
with the spectral decoder D_φ in one of two orders (the model's ``decode`` option):

- ``"gaussian"`` — eq. 13 as published: r_k = D_φ(z_k(ω_i, ω_o)) per Gaussian, then the spectra
  are alpha-blended (B channels rasterized);
- ``"pixel"`` — the latents are alpha-blended and each pixel decoded, D_φ(Σ_k w_k z_k) (d
  channels rasterized). With a nonlinear decoder the two differ.

Training uses the same pieces (:func:`rasterize_features`, :func:`composite_background`,
:func:`decode_image`) with gradients.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch
from torch import Tensor

from brfgs.brdf.geometry import gaussian_normals, view_directions
from brfgs.data.cir import cir_composite
from brfgs.spectral.fast_decode import can_fast_decode, fast_decode
from brfgs.model.camera import Camera
from brfgs.model.gaussians import GaussianModel
from brfgs.render import RenderOutput, rasterize
from brfgs.render.rasterize import antialias_opacities
from brfgs.render.supersample import box_downsample, fine_intrinsics
from brfgs.render.geometry import project_pinhole

if TYPE_CHECKING:  # type only: trained.py imports this module
    from brfgs.model.trained import TrainedModel

# features(idx [n] long, omega_o [n, 3]) -> [n, C]: per-Gaussian features of the Gaussians kept
FeaturesFn = Callable[[Tensor, Tensor], Tensor]


def rasterize_splats(
    means: Tensor,  # [N, 3] m
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3] m
    opacities: Tensor,  # [N]
    feats: Tensor,  # [N, C]
    cam: Camera,
    backend: str = "auto",
    antialiased: bool = False,
    normals: Tensor | None = None,  # [N, 3]
    absgrad: bool = False,
    supersample: int = 1,
) -> RenderOutput:
    """:func:`brfgs.render.rasterize` for ``cam``; with ``antialiased`` the opacities first get
    Mip-Splatting's compensation for the view (:func:`brfgs.render.rasterize.antialias_opacities`);
    ``absgrad``: also AbsGS's screen-space gradient (``meta["means2d"].absgrad``);
    ``supersample`` s > 1: each pixel the mean of s × s sub-pixel samples (a box integral over
    the pixel, :mod:`brfgs.render.supersample`)."""
    K, w, h = cam.K, cam.width, cam.height
    if supersample > 1:
        K, w, h = fine_intrinsics(K, supersample), w * supersample, h * supersample
    if antialiased:
        opacities = antialias_opacities(means, quats, scales, opacities, cam.viewmat, K, w, h)
    out = rasterize(means, quats, scales, opacities, feats, cam.viewmat, K, w, h,
                    backend=backend, normals=normals, absgrad=absgrad)
    return box_downsample(out, supersample)


def rasterize_features(
    model: GaussianModel,
    feats: Tensor,  # [N, C]
    cam: Camera,
    backend: str = "auto",
    antialiased: bool = False,
    absgrad: bool = False,
    supersample: int = 1,
) -> RenderOutput:
    """Rasterize ``feats`` for ``cam``: image [H, W, C] (premultiplied), alpha [H, W], depth, meta."""
    return rasterize_splats(model.means, model.quats, model.scales, model.opacities, feats, cam, backend, antialiased,
                            absgrad=absgrad, supersample=supersample)


def composite_background(
    image: Tensor,  # [H, W, C] premultiplied
    alpha: Tensor,  # [H, W]
    bg: Tensor | None,  # [C]
) -> Tensor:  # [H, W, C]
    """image + (1 - alpha) * bg for a premultiplied render."""
    if bg is None:
        return image
    return image + (1.0 - alpha)[..., None] * bg


def decode_image(decoder, latent: Tensor, chunk: int = 1 << 16) -> Tensor:
    """Decode latent vectors [..., d] to reflectance [..., B] pixel by pixel (eq. 13): through
    :func:`brfgs.spectral.fast_decode.fast_decode` when the decoder's weights need no gradient (a frozen or
    loaded decoder), else through ``decoder.decode`` (the reference) in chunks of ``chunk`` vectors (the
    decoder is per pixel: chunking does not change the result)."""
    shape, d = latent.shape[:-1], latent.shape[-1]
    flat = latent.reshape(-1, d)
    if can_fast_decode(decoder, flat):                   # the fused kernels (same map, gradient to the latent)
        return fast_decode(decoder, flat).reshape(*shape, -1)
    if flat.shape[0] <= chunk:
        return decoder.decode(flat).reshape(*shape, -1)
    parts = [decoder.decode(flat[i : i + chunk]) for i in range(0, flat.shape[0], chunk)]
    return torch.cat(parts, 0).reshape(*shape, -1)


def frustum_subset(
    means: Tensor,  # [N, 3] m
    max_scale: Tensor,  # [N] m, largest standard deviation
    cam: Camera,
    margin_sigma: float = 3.0,
) -> Tensor:  # [n] long
    """Indices of Gaussians that can touch the image: in front of the camera and within the image
    grown by ``margin_sigma`` × their largest scale (a superset of what the rasterizer keeps).
    Gaussians straddling the camera plane cannot be projected reliably; 3DGS drops them too."""
    uv, z = project_pinhole(means, cam.viewmat.to(means.dtype), cam.K.to(means.dtype))  # [N, 2], [N]
    zs = z.clamp_min(1e-6)
    r = margin_sigma * max_scale
    ru = cam.K[0, 0] * r / zs + 2.0
    rv = cam.K[1, 1] * r / zs + 2.0
    u, v = uv[:, 0], uv[:, 1]
    ok = (z > 0.01) & (u + ru >= 0) & (u - ru <= cam.width) & (v + rv >= 0) & (v - rv <= cam.height)
    return torch.nonzero(ok).squeeze(1)


@dataclass
class RenderedView:
    """One rendered view (numpy planes unless said otherwise).

    image: raw premultiplied features [H, W, C] (torch); latent: background-composited latent
    [H, W, d] (None for custom features, the CIR variant or decode order "gaussian"); cube: reflectance [H, W, B] (None
    unless decoded); cir: CIR composite [H, W, 3] in [0, 1]-ish (None unless decoded, or always for
    the CIR variant); alpha [H, W]; depth [H, W] (m along the optical axis, 0 where nothing);
    normal [H, W, 3] (unit, world, facing the camera, 0 where α = 0; None unless asked).
    """

    image: Tensor
    alpha: np.ndarray
    depth: np.ndarray
    latent: np.ndarray | None = None
    cube: np.ndarray | None = None
    cir: np.ndarray | None = None
    normal: np.ndarray | None = None
    timings_s: dict = field(default_factory=dict)


def _rasterize_subset(model: "TrainedModel", cam: Camera, features: FeaturesFn, want_normals: bool, cull: bool,
                      backend: str) -> RenderOutput:
    """Rasterize ``features`` of the Gaussians that can touch ``cam`` (all when not ``cull``)."""
    f = model.frozen()
    means = f["means"]
    idx = frustum_subset(means, f["max_scale"], cam) if cull else torch.arange(means.shape[0])
    omega_o = view_directions(means[idx], cam.centre)  # [n, 3]
    feats = features(idx, omega_o).to(means.dtype).contiguous()  # [n, C]
    normals = gaussian_normals(f["quats"][idx], f["scales"][idx], omega_o).contiguous() if want_normals else None
    if idx.numel() == 0:
        z = torch.zeros(cam.height, cam.width)
        return RenderOutput(torch.zeros(cam.height, cam.width, feats.shape[1]), z, z.clone(),
                            torch.zeros(cam.height, cam.width, 3) if want_normals else None, {"backend": "none"})
    return rasterize_splats(means[idx].contiguous(), f["quats"][idx].contiguous(), f["scales"][idx].contiguous(),
                            f["opacities"][idx].contiguous(), feats, cam, backend, model.antialiased, normals,
                            supersample=model.supersample)


def _unit_normals(normal: Tensor | None) -> np.ndarray | None:
    """Blended normals [H, W, 3] scaled to unit length (0 where nothing was hit)."""
    if normal is None:
        return None
    n = normal.numpy().astype(np.float64)
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(nn > 1e-8, n / np.maximum(nn, 1e-12), 0.0).astype(np.float32)


def spectral_features(model: "TrainedModel", omega_i: Tensor, order: str | None = None) -> FeaturesFn:
    """Per-Gaussian features whose rendering gives the model's spectra for the sun ω_i [3]:
    latents [n, d] (decode order "pixel") or decoded spectra [n, B] ("gaussian", eq. 13)."""
    order = order or model.decode_order

    def features(idx: Tensor, omega_o: Tensor) -> Tensor:
        lat = model.gaussian_latent(omega_i, omega_o, idx)  # [n, d]
        return decode_image(model.decoder, lat) if order == "gaussian" else lat

    return features


@torch.no_grad()
def pixel_spectra(model: "TrainedModel", image: Tensor, alpha: Tensor, order: str | None = None) -> np.ndarray:
    """Reflectance [..., B] of rendered pixels ``image`` [..., C] (premultiplied features of
    :func:`spectral_features`) with coverage ``alpha`` [...]: the background composited, then
    decoded per pixel (order "pixel"), or the decoded background spectrum composited ("gaussian")."""
    order = order or model.decode_order
    bg = model.bg_latent
    if order == "gaussian":
        bg_spec = None if bg is None else decode_image(model.decoder, bg.to(image.dtype)[None])[0]  # [B]
        return composite_background(image, alpha, bg_spec).numpy().astype(np.float32)
    return _decode_hits(model, composite_background(image, alpha, bg), alpha)


def _decode_hits(model: "TrainedModel", latent: Tensor, alpha: Tensor) -> np.ndarray:
    """Decoded cube [..., B] of latents [..., d]; pixels showing only the background share one
    decoded spectrum."""
    bg = model.bg_latent
    hit = alpha > 0
    if bg is None or bool(hit.all()):
        return decode_image(model.decoder, latent).numpy()
    bg_spec = decode_image(model.decoder, bg.to(latent.dtype)[None])[0].numpy()  # [B]
    cube = np.broadcast_to(bg_spec, tuple(latent.shape[:-1]) + bg_spec.shape).copy()
    if bool(hit.any()):
        cube[hit.numpy()] = decode_image(model.decoder, latent[hit]).numpy()
    return cube


@torch.no_grad()
def render(
    model: "TrainedModel",
    cam: Camera,
    *,
    sun_zenith_deg: float | None = None,
    sun_azimuth_deg: float | None = None,
    features: FeaturesFn | None = None,
    decode: bool = True,
    normals: bool = False,
    cull: bool = True,
    backend: str = "auto",
    decode_order: str | None = None,
) -> RenderedView:
    """Render ``model`` from ``cam`` under a sun (default: the acquisition's).

    With ``features`` None the appearance head's latent is rendered, the learned background
    composited, and (``decode``) decoded to reflectance in the model's decode order (or
    ``decode_order``: "pixel" | "gaussian", see the module docstring) and the CIR composite
    formed; the CIR variant renders its CIR colours directly. With ``features(idx, omega_o) -> [n, C]``
    any per-Gaussian quantity (kernel contributions, NBAR latents, ...) is rasterized instead
    and returned raw in ``image``. ``cull`` drops Gaussians that cannot touch the image first
    (same image, less work).
    """
    t0 = time.perf_counter()
    omega_i = model.sun_direction(sun_zenith_deg, sun_azimuth_deg)  # [3]
    custom = features is not None
    order = "pixel" if not model.spectral else (decode_order or model.decode_order)
    if order not in ("pixel", "gaussian"):
        raise ValueError(f"decode_order must be pixel or gaussian, got {order!r}")
    by_gaussian = not custom and decode and order == "gaussian"
    if not custom:
        features = spectral_features(model, omega_i, "gaussian" if by_gaussian else "pixel") if model.spectral else (
            lambda idx, omega_o: model.gaussian_latent(omega_i, omega_o, idx))
    out = _rasterize_subset(model, cam, features, normals, cull, backend)
    t1 = time.perf_counter()
    rv = RenderedView(image=out.image, alpha=out.alpha.numpy(), depth=out.depth.numpy(), normal=_unit_normals(out.normal))
    if by_gaussian:
        rv.cube = pixel_spectra(model, out.image, out.alpha, "gaussian")
        rv.cir = cir_composite(rv.cube, model.cir_indices, model.cir_scale)
    elif not custom and model.spectral:
        latent = composite_background(out.image, out.alpha, model.bg_latent)  # [H, W, d]
        rv.latent = latent.numpy().astype(np.float32)
        if decode:
            rv.cube = _decode_hits(model, latent, out.alpha)
            rv.cir = cir_composite(rv.cube, model.cir_indices, model.cir_scale)
    elif not custom:  # CIR variant: SH colours on the CIR composite
        rv.cir = composite_background(out.image, out.alpha, model.extra.get("bg_colors")).clamp(0, 1).numpy()
    rv.timings_s = {"rasterize_s": t1 - t0, "decode_s": time.perf_counter() - t1, "total_s": time.perf_counter() - t0}
    return rv
