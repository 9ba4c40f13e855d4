"""Directional reflectance (BRF) of a region of interest (paper section 4.3–4.4, Figs. 7–9).

The ROI's BRF for a view direction (θ_v, φ_v) is its mean reflectance as rendered from
that direction: a camera at the model's typical flying distance looks at the ROI centre
from (θ_v, φ_v) with a field of view just holding the ROI; the pixels whose surface point
(unprojected from the rendered depth) lies in the ROI and whose accumulated opacity is
≥ ``min_alpha`` are decoded and averaged. Occluders are rendered (their pixels are not in
the ROI), so what a sensor would see of the ROI is what is averaged.

- :func:`roi_brf` — BRF [D, B'] of one ROI for D directions (any bands).
- :func:`principal_plane` — signed view zenith −75…75° in the sun's plane.
- :func:`polar_map` — view hemisphere grid (zenith × absolute azimuth).
- :func:`frame_observations` — per training/test frame: observed, reconstructed (and truth)
  mean spectra of the ROI, and the frame's view direction seen from the ROI centre.
- :func:`nearest_to_plane` — the observations closest to the principal plane (Fig. 8).
- :func:`log_error` — ln(reconstructed / observed) (Fig. 7).
- :func:`truth_brf` — on simulated scenes, the truth BRF of the ROI rendered again by the
  simulator for given directions; :func:`brf_error` — per-band RMSE / bias against it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from brfgs.analysis.renderer import BRFModel, render_features
from brfgs.analysis.roi import ROI, unproject_depth
from brfgs.analysis.views import (
    hemisphere_grid,
    principal_plane_directions,
    view_angles_from_points,
    view_camera,
)
from brfgs.data.angles import relative_azimuth_deg, signed_principal_plane_zenith_deg
from brfgs.errors import UserError

__all__ = [
    "ROIBRF",
    "roi_pixels",
    "roi_mean_from_view",
    "roi_brf",
    "principal_plane",
    "polar_map",
    "frame_observations",
    "nearest_to_plane",
    "log_error",
    "truth_brf",
    "check_truth_spp",
    "brf_error",
]

MIN_ALPHA = 0.5


@dataclass
class ROIBRF:
    """BRF samples of one ROI: directions, values [D, nb] per band, pixel counts [D]."""

    view_zenith_deg: np.ndarray
    view_azimuth_deg: np.ndarray
    wavelengths_nm: np.ndarray
    values: np.ndarray
    n_pixels: np.ndarray
    extra: dict = field(default_factory=dict)


def roi_pixels(roi: ROI, depth_m: np.ndarray, alpha: np.ndarray, c2w: np.ndarray, intr, *,
               min_alpha: float = MIN_ALPHA) -> np.ndarray:
    """bool [H, W]: pixels whose rendered surface point lies in the ROI (and alpha ≥ min_alpha)."""
    ok = (np.asarray(alpha) >= min_alpha) & (np.asarray(depth_m) > 0)
    if not ok.any():
        return ok
    pts = unproject_depth(np.where(ok, depth_m, np.nan), c2w, intr)
    inside = np.zeros(ok.shape, bool)
    inside[ok] = roi.contains(pts[ok])
    return inside


def roi_mean_from_view(bm: BRFModel, roi: ROI, c2w: np.ndarray, intr, omega_i, *, backend: str = "auto",
                       min_alpha: float = MIN_ALPHA, return_pixels: bool = False):
    """(mean reflectance [B], number of ROI pixels, ROI mask [H, W]) of one rendered view
    (plus the decoded ROI pixels [n, B] in mask order when ``return_pixels``).

    Only the ROI pixels are decoded (the decoder is nonlinear: spectra are decoded per pixel
    and then averaged, as a sensor would average reflectance).
    """
    out = render_features(bm, lambda idx, oo: bm.gaussian_latent(omega_i, oo, idx), c2w, intr, backend=backend)
    alpha = out.alpha.numpy()
    depth = out.depth.numpy()
    mask = roi_pixels(roi, depth, alpha, c2w, intr, min_alpha=min_alpha)
    n = int(mask.sum())
    if n == 0:
        empty = np.full(len(bm.wavelengths_nm), np.nan, np.float32)
        return (empty, 0, mask, np.zeros((0, len(empty)), np.float32)) if return_pixels else (empty, 0, mask)
    lat = out.image.numpy()[mask]
    if bm.bg_latent is not None:
        lat = lat + (1.0 - alpha[mask])[:, None] * bm.bg_latent.numpy()[None]
    spec = bm.decode(lat)                                     # [n, B]
    if return_pixels:
        return spec.mean(0), n, mask, spec
    return spec.mean(0), n, mask


def robust_keep(spectra: np.ndarray, k_mad: float = 3.0, min_pixels: int = 10) -> np.ndarray:
    """bool [n]: pixels whose mean reflectance lies within k·1.4826·MAD of the median
    (pixel-wise outlier removal before ROI means, paper §4.3); all kept below ``min_pixels``."""
    x = np.asarray(spectra, float)
    keep = np.isfinite(x).all(1)
    if keep.sum() < min_pixels or k_mad <= 0:
        return keep
    b = x.mean(1)
    med = np.median(b[keep])
    mad = 1.4826 * np.median(np.abs(b[keep] - med))
    if mad == 0:
        return keep
    return keep & (np.abs(b - med) <= k_mad * mad)


def _roi_target(bm: BRFModel, roi: ROI) -> np.ndarray:
    c = np.asarray(roi.centre_m, float)
    if getattr(roi, "kind", "") == "polygon" and getattr(roi, "surface_dz_m", 0.0) == 0.0 \
            and getattr(roi, "surface_z_m", 0.0) == 0.0:
        roi.set_surface_height(bm.model.means.detach().double().numpy())
        c = np.asarray(roi.centre_m, float)
    return c


def training_footprint_m(bm: BRFModel) -> float:
    """Ground size (m) of one training pixel: median camera distance / focal length (px)."""
    return bm.typical_distance_m() / (0.5 * (bm.intrinsics.fl_x + bm.intrinsics.fl_y))


def auto_roi_size(bm: BRFModel, half_extent_m: float, lo: int = 16, hi: int = 512) -> int:
    """Pixels of an ROI camera spanning 2·half_extent_m with the training pixel footprint."""
    return int(np.clip(math.ceil(2.0 * half_extent_m / training_footprint_m(bm)), lo, hi))


def roi_brf(bm: BRFModel, roi: ROI, view_zenith_deg, view_azimuth_deg, band_idx=None, *,
            sun_zenith_deg: float | None = None, sun_azimuth_deg: float | None = None, size: int | None = None,
            distance_m: float | None = None, backend: str = "auto", progress: bool = False,
            desc: str = "BRF", min_alpha: float = MIN_ALPHA) -> ROIBRF:
    """BRF of ``roi`` for the directions (arrays of equal length, degrees) in bands ``band_idx``.

    ``size``: pixels of the square ROI camera (the ROI spans ~90 % of it); default: the size
    whose pixel footprint equals the training images' (:func:`auto_roi_size`) — 3DGS renders
    change with the pixel footprint (the 0.3 px² low-pass, opacity coverage), so the ROI is
    rendered at the scale the model was trained on. ``distance_m``:
    camera distance (default: the training cameras' median distance, at least 8 ROI radii so
    the direction is nearly the same over the ROI). Directions where the ROI is not seen
    (fully occluded) give NaN and 0 pixels.
    """
    zen = np.atleast_1d(np.asarray(view_zenith_deg, float))
    az = np.atleast_1d(np.asarray(view_azimuth_deg, float))
    if zen.shape != az.shape:
        raise ValueError("zenith and azimuth arrays must have the same shape")
    bi = np.arange(len(bm.wavelengths_nm)) if band_idx is None else np.asarray(band_idx, int)
    target = _roi_target(bm, roi)
    half = 1.1 * roi.radius_m
    if distance_m is None:
        # the training cameras' distance, but far enough that the view direction varies by at
        # most ~±7° across the ROI (an ROI's BRF is for one direction)
        dist = max(bm.typical_distance_m(), 8.0 * roi.radius_m)
    else:
        dist = max(float(distance_m), 1.5 * half)
    if size is None:
        size = auto_roi_size(bm, half)
    omega_i = bm.sun_direction(sun_zenith_deg, sun_azimuth_deg)
    vals = np.full((zen.size, bi.size), np.nan, np.float32)
    counts = np.zeros(zen.size, np.int64)
    it = range(zen.size)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc=desc, leave=False)
    for k in it:
        c2w, intr = view_camera(zen.flat[k], az.flat[k], dist, target, size=size, half_extent_m=half)
        mean, n, _ = roi_mean_from_view(bm, roi, c2w, intr, omega_i, backend=backend, min_alpha=min_alpha)
        counts[k] = n
        if n:
            vals[k] = mean[bi]
    return ROIBRF(zen, az, bm.wavelengths_nm[bi], vals, counts,
                  {"distance_m": dist, "size_px": size, "half_extent_m": half, "target_m": target.tolist(),
                   "min_alpha": min_alpha,
                   "sun_zenith_deg": bm.sun_zenith_deg if sun_zenith_deg is None else sun_zenith_deg,
                   "sun_azimuth_deg": bm.sun_azimuth_deg if sun_azimuth_deg is None else sun_azimuth_deg})


def principal_plane(bm: BRFModel, roi: ROI, band_idx, *, max_zenith_deg: float = 75.0, step_deg: float = 2.5,
                    **kw) -> tuple[np.ndarray, ROIBRF]:
    """(signed view zenith [D] in degrees, ROIBRF) along the principal plane, −max…+max.

    Positive = sun's side (backscatter; the hotspot is at +θ_s), negative = forward
    (the specular direction is at −θ_s).
    """
    n = int(round(2 * max_zenith_deg / step_deg)) + 1
    s = np.linspace(-max_zenith_deg, max_zenith_deg, n)
    sun_az = bm.sun_azimuth_deg if kw.get("sun_azimuth_deg") is None else kw["sun_azimuth_deg"]
    zen, az = principal_plane_directions(s, sun_az)
    return s, roi_brf(bm, roi, zen, az, band_idx, desc="principal plane", **kw)


def polar_map(bm: BRFModel, roi: ROI, band_idx, *, n_azimuth: int = 60, n_zenith: int = 24,
              max_zenith_deg: float = 75.0, **kw) -> tuple[np.ndarray, np.ndarray, np.ndarray, ROIBRF]:
    """(zenith_deg [Z], azimuth_deg [A] (absolute view azimuth), values [Z, A, nb], ROIBRF)."""
    zc, ac = hemisphere_grid(n_azimuth, n_zenith, max_zenith_deg)
    Z, A = np.meshgrid(zc, ac, indexing="ij")
    res = roi_brf(bm, roi, Z.ravel(), A.ravel(), band_idx, desc="polar map", **kw)
    return zc, ac, res.values.reshape(len(zc), len(ac), -1), res


# ----------------------------------------------------------------------------------------
# observations


@dataclass
class FrameObservation:
    """One frame's ROI statistics: view direction from the ROI centre, mean spectra [B], pixels."""

    name: str
    split: str
    view_zenith_deg: float
    view_azimuth_deg: float
    relative_azimuth_deg: float
    signed_zenith_deg: float
    plane_offset_deg: float          # azimuthal distance to the principal plane (0 = on it)
    n_pixels: int
    observed: np.ndarray | None
    reconstructed: np.ndarray | None
    truth: np.ndarray | None = None
    truth_n_pixels: int = 0


def frame_observations(bm: BRFModel, roi: ROI, scene=None, *, splits=("train", "test"), truth: bool = True,
                       backend: str = "auto", progress: bool = False, min_alpha: float = MIN_ALPHA,
                       outlier_k_mad: float = 3.0) -> list[FrameObservation]:
    """ROI statistics of every frame of the model (training poses), optionally with images.

    For each frame: render the model from the frame's pose → ROI pixel mask (rendered
    depth) → mean reconstructed spectrum; with ``scene`` (brfgs.data.Scene matching the
    model's frames), the observed mean over the same pixels (valid pixels, outliers of the
    observed brightness beyond ``outlier_k_mad`` MADs removed — the reconstructed mean then
    uses the same pixels); with the
    scene's truth/ (simulated scenes), the truth mean over the pixels whose *true* surface
    point (truth/depth) lies in the ROI (same outlier removal). The view direction is measured from the ROI centre.
    """
    target = _roi_target(bm, roi)
    omega_i = bm.sun_direction()
    intr = bm.intrinsics
    name_to_index = {}
    if scene is not None:
        name_to_index = {f.name: i for i, f in enumerate(scene.frames)}
        if (scene.width, scene.height) != (intr.w, intr.h):
            raise UserError(f"the scene's images are {scene.width}x{scene.height} but the model was trained on "
                            f"{intr.w}x{intr.h} (use the same --downscale)", field="--scene")
    truth_dir = getattr(scene, "truth_dir", None) if (scene is not None and truth) else None
    frames = [f for f in bm.frames if f.get("split", "train") in splits]
    it = frames
    if progress:
        from tqdm import tqdm

        it = tqdm(frames, desc="frames", leave=False)
    out = []
    for fr in it:
        c2w = np.asarray(fr["c2w"], float)
        zen, az = view_angles_from_points(c2w[:3, 3], target)
        rel = float(relative_azimuth_deg(az, bm.sun_azimuth_deg))
        signed = float(signed_principal_plane_zenith_deg(zen, rel))
        off = float(min(rel % 180.0, 180.0 - rel % 180.0)) if zen > 1e-6 else 0.0
        rec, n, mask, pix = roi_mean_from_view(bm, roi, c2w, intr, omega_i, backend=backend, min_alpha=min_alpha,
                                               return_pixels=True)
        obs = None
        tru, tn = None, 0
        if scene is not None and fr["name"] in name_to_index and n:
            i = name_to_index[fr["name"]]
            img = scene.load_image(i)
            o_pix = img[mask]                                 # [n, B], mask order as pix
            keep = robust_keep(o_pix, outlier_k_mad)
            if keep.any():
                obs = o_pix[keep].mean(0)
                rec = pix[keep].mean(0)
                n = int(keep.sum())
            if truth_dir is not None:
                tru, tn = _truth_mean(truth_dir, fr["name"], c2w, intr, roi, outlier_k_mad)
        out.append(FrameObservation(fr["name"], fr.get("split", "train"), zen, az, rel, signed, off, n,
                                    obs, rec if n else None, tru, tn))
    return out


def _truth_mean(truth_dir, name: str, c2w, intr, roi: ROI, outlier_k_mad: float = 3.0
                ) -> tuple[np.ndarray | None, int]:
    """Mean truth spectrum over pixels whose true surface point lies in the ROI, with the same
    outlier removal as the observed mean (:func:`robust_keep`: border pixels that mix the ROI
    with a brighter neighbour, e.g. water next to vegetation in the near infrared)."""
    from pathlib import Path

    from brfgs.data.cube_io import envi_image_path

    truth_dir = Path(truth_dir)
    hdr = truth_dir / "images" / f"{name}.hdr"
    dp = truth_dir / "depth" / f"{name}.npy"
    if not (hdr.is_file() and dp.is_file() and envi_image_path(hdr) is not None):
        return None, 0
    import spectral.io.envi as envi

    cube = np.asarray(envi.open(str(hdr), str(envi_image_path(hdr))).load(), np.float32)
    depth = np.load(dp, allow_pickle=False).astype(float)
    h, w = depth.shape
    if (w, h) != (intr.w, intr.h):
        from brfgs.data.cameras import Intrinsics

        fx, fy = w / intr.w, h / intr.h
        intr = Intrinsics(intr.fl_x * fx, intr.fl_y * fy, intr.cx * fx, intr.cy * fy, w, h)
    pts = unproject_depth(depth, c2w, intr)
    ok = np.isfinite(pts).all(-1)
    sel = np.zeros(ok.shape, bool)
    sel[ok] = roi.contains(pts[ok])
    sel &= np.isfinite(cube).all(-1)
    if not sel.any():
        return None, 0
    vals = cube[sel]                                          # [n, B]
    keep = robust_keep(vals, outlier_k_mad)
    return vals[keep].mean(0), int(keep.sum())


def nearest_to_plane(obs: list[FrameObservation], max_offset_deg: float = 20.0, zenith_bin_deg: float = 4.0
                     ) -> list[FrameObservation]:
    """For each zenith ring and side of the principal plane, the observation nearest the plane.

    Observations whose azimuthal distance to the plane exceeds ``max_offset_deg`` are
    dropped (nadir always qualifies). Sorted by signed zenith.
    """
    best: dict[tuple[int, int], FrameObservation] = {}
    for o in obs:
        if o.reconstructed is None or o.plane_offset_deg > max_offset_deg:
            continue
        side = 0 if o.view_zenith_deg < 2.0 else (1 if o.signed_zenith_deg > 0 else -1)
        key = (side, int(round(o.view_zenith_deg / zenith_bin_deg)))
        if key not in best or o.plane_offset_deg < best[key].plane_offset_deg:
            best[key] = o
    return sorted(best.values(), key=lambda o: o.signed_zenith_deg)


def log_error(reconstructed: np.ndarray, observed: np.ndarray, floor: float = 1e-4) -> np.ndarray:
    """Logarithmic error ln(reconstructed / observed) per band (both clipped to ≥ ``floor``)."""
    r = np.maximum(np.asarray(reconstructed, float), floor)
    o = np.maximum(np.asarray(observed, float), floor)
    return np.log(r / o)


def curve_peak(signed_zenith_deg: np.ndarray, values: np.ndarray) -> float:
    """Signed zenith (deg) of a curve's maximum, refined by a parabola through the top 3 samples."""
    v = np.asarray(values, float)
    s = np.asarray(signed_zenith_deg, float)
    ok = np.isfinite(v)
    if not ok.any():
        return float("nan")
    k = int(np.nanargmax(np.where(ok, v, -np.inf)))
    if 0 < k < len(v) - 1 and ok[k - 1] and ok[k + 1]:
        y0, y1, y2 = v[k - 1], v[k], v[k + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            t = 0.5 * (y0 - y2) / den
            return float(s[k] + t * (s[k + 1] - s[k]))
    return float(s[k])


def has_simulator_truth(scene_root) -> bool:
    """True when ``scene_root`` is a simulated scene that the simulator can render again."""
    from pathlib import Path

    return scene_root is not None and (Path(scene_root) / "truth" / "scene.json").is_file()


def simulator_sampler(scene_root) -> tuple[str, int]:
    """(Mitsuba sampler, spp) of a simulated scene (truth/scene.json); scenes written before
    the sampler option used "independent"."""
    import json
    from pathlib import Path

    path = Path(scene_root) / "truth" / "scene.json"
    try:
        cfg = json.loads(path.read_text()).get("config", {})
    except (OSError, ValueError, AttributeError):
        raise UserError("unreadable simulator configuration", file=path, field="config") from None
    return str(cfg.get("sampler", "independent")), int(cfg.get("spp", 0) or 0)


def check_truth_spp(scene_root, spp: int | None, field: str = "--truth-spp") -> int | None:
    """``spp`` validated for the scene's sampler: a power of 4 (1, 4, 16, 64, 256, ...) for
    Mitsuba's low-discrepancy "ldsampler" (it would round other counts up silently), a power
    of two for "independent". None keeps the scene's own spp."""
    if spp is None:
        return None
    spp = int(spp)
    sampler, _ = simulator_sampler(scene_root)
    if spp < 1 or spp & (spp - 1):
        raise UserError(f"samples per pixel must be a power of two, got {spp}", field=field)
    if sampler == "ldsampler" and (spp.bit_length() - 1) % 2:
        raise UserError(f"this scene was simulated with the 'ldsampler' sampler, whose samples per pixel must be a "
                        f"power of 4 (1, 4, 16, 64, 256, ...), got {spp}", field=field)
    return spp


def truth_brf(scene_root, roi: ROI, view_zenith_deg, view_azimuth_deg, band_idx, *, distance_m: float,
              size: int = 128, spp: int | None = None, progress: bool = False, chunk: int = 64) -> ROIBRF:
    """Truth BRF of ``roi``: the simulator renders the clean scene again from each direction
    (brfgs.sim.acquisition.render_scene_views: cameras at ``distance_m`` looking at the ROI
    centre, the acquisition's field of view, ``size`` pixels, ``spp`` samples per pixel —
    default the scene's; see :func:`check_truth_spp`) and the ROI is the set of pixels
    whose *true* surface point (ray-cast depth) lies in it. Directions are rendered ``chunk``
    at a time (the simulator builds the scene once per call)."""
    from brfgs.data.cameras import Intrinsics
    from brfgs.sim.acquisition import render_scene_views

    zen = np.atleast_1d(np.asarray(view_zenith_deg, float))
    az = np.atleast_1d(np.asarray(view_azimuth_deg, float))
    bi = [int(b) for b in np.atleast_1d(band_idx)]
    spp = check_truth_spp(scene_root, spp, field="spp")
    target = np.asarray(roi.centre_m, float)
    vals = np.full((zen.size, len(bi)), np.nan, np.float32)
    counts = np.zeros(zen.size, np.int64)
    wl = None
    chunk = max(1, int(chunk))
    for k0 in range(0, zen.size, chunk):
        dirs = [(zen[k], az[k]) for k in range(k0, min(zen.size, k0 + chunk))]
        r = render_scene_views(scene_root, dirs, size=size, spp=spp, bands=bi, distance_m=distance_m,
                               target_m=target, progress=progress)
        wl = r["wavelengths_nm"]
        intr = r["intrinsics"]
        if not isinstance(intr, Intrinsics):
            intr = Intrinsics(**intr)
        for j in range(len(dirs)):
            k = k0 + j
            depth = r["depth"][j].astype(float)
            pts = unproject_depth(np.where(depth > 0, depth, np.nan), r["c2w"][j], intr)
            ok = np.isfinite(pts).all(-1)
            sel = np.zeros(ok.shape, bool)
            sel[ok] = roi.contains(pts[ok])
            refl = r["reflectance"][j]
            sel &= np.isfinite(refl).all(-1)
            counts[k] = int(sel.sum())
            if counts[k]:
                vals[k] = refl[sel].mean(0)
    return ROIBRF(zen, az, np.asarray(wl if wl is not None else []), vals, counts,
                  {"distance_m": distance_m, "size_px": size, "spp": spp, "target_m": target.tolist(),
                   "source": "simulator"})


def brf_error(model: np.ndarray, truth: np.ndarray, wavelengths_nm) -> dict:
    """Per-band error of model BRF [D, nb] against truth [D, nb] over the directions where both
    are finite: RMSE, mean bias (model − truth) and mean relative error |model − truth| / truth."""
    m = np.asarray(model, float)
    t = np.asarray(truth, float)
    ok = np.isfinite(m).all(1) & np.isfinite(t).all(1)
    keys = [f"{w:.0f}" for w in wavelengths_nm]
    if not ok.any():
        return {"n_directions": 0, "rmse": {k: None for k in keys}, "mean_bias": {k: None for k in keys},
                "mean_relative_error": {k: None for k in keys}, "reason": "no direction where both are seen"}
    e = m[ok] - t[ok]
    return {"n_directions": int(ok.sum()),
            "rmse": {k: float(np.sqrt(np.mean(e[:, j] ** 2))) for j, k in enumerate(keys)},
            "mean_bias": {k: float(np.mean(e[:, j])) for j, k in enumerate(keys)},
            "mean_relative_error": {k: float(np.mean(np.abs(e[:, j]) / np.maximum(np.abs(t[ok, j]), 1e-6)))
                                    for j, k in enumerate(keys)}}
