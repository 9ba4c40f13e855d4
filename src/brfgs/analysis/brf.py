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

The simulator's truth BRF of an ROI (simulated scenes) is in :mod:`brfgs.analysis.truth`; the
``brf`` command's report (CSV, PNG, JSON) in :mod:`brfgs.analysis.brf_report`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import spectral.io.envi as envi
import torch
from numpy.typing import ArrayLike
from torch import Tensor
from tqdm import tqdm

from brfgs.analysis.roi import ROI, intrinsics_for_shape, points_in_roi, unproject_depth
from brfgs.analysis.views import (
    hemisphere_grid,
    principal_plane_directions,
    view_angles_from_points,
    view_camera,
)
from brfgs.data.angles import relative_azimuth_deg, signed_principal_plane_zenith_deg
from brfgs.data.cameras import Intrinsics
from brfgs.data.cube_io import envi_image_path
from brfgs.data.scene import Scene
from brfgs.errors import UserError
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from brfgs.model.view import pixel_spectra, sky_share, spectral_features

__all__ = [
    "MIN_ALPHA",
    "ROIBRF",
    "FrameObservation",
    "roi_pixels",
    "roi_mean_from_view",
    "robust_keep",
    "training_footprint_m",
    "auto_roi_size",
    "roi_brf",
    "principal_plane",
    "polar_map",
    "frame_observations",
    "nearest_to_plane",
    "log_error",
    "curve_peak",
]

MIN_ALPHA = 0.5


@dataclass
class ROIBRF:
    """BRF samples of one ROI: directions, values [D, nb] per band, pixel counts [D]."""

    view_zenith_deg: np.ndarray  # [D]
    view_azimuth_deg: np.ndarray  # [D]
    wavelengths_nm: np.ndarray  # [nb]
    values: np.ndarray  # [D, nb]
    n_pixels: np.ndarray  # [D]
    extra: dict = field(default_factory=dict)


def roi_pixels(
    roi: ROI,
    depth_m: np.ndarray,  # [H, W] m along the optical axis
    alpha: np.ndarray,  # [H, W]
    c2w: np.ndarray,  # [4, 4] OpenGL camera-to-world
    intr: Intrinsics,
    *,
    min_alpha: float = MIN_ALPHA,
) -> np.ndarray:  # [H, W] bool
    """bool [H, W]: pixels whose rendered surface point lies in the ROI (and alpha ≥ min_alpha)."""
    ok = (np.asarray(alpha) >= min_alpha) & (np.asarray(depth_m) > 0)
    if not ok.any():
        return ok
    return points_in_roi(roi, unproject_depth(np.where(ok, depth_m, np.nan), c2w, intr))


def roi_mean_from_view(
    tm: TrainedModel,
    roi: ROI,
    c2w: np.ndarray,  # [4, 4] OpenGL camera-to-world
    intr: Intrinsics,
    omega_i: Tensor,  # [3] unit, toward the sun
    *,
    backend: str = "auto",
    min_alpha: float = MIN_ALPHA,
    return_pixels: bool = False,
    diffuse_fraction=None,
) -> tuple:
    """(mean reflectance [B], number of ROI pixels, ROI mask [H, W]) of one rendered view
    (plus the decoded ROI pixels [n, B] in mask order when ``return_pixels``).

    Spectra in the model's decode order (:func:`brfgs.model.view.pixel_spectra`); with order
    "pixel" only the ROI pixels are decoded (the decoder is nonlinear: spectra are decoded per
    pixel and then averaged, as a sensor would average reflectance). A model trained with shadows is
    lit under the sky ``diffuse_fraction`` (default its own for this sun; :func:`brfgs.model.view.sky_share`).
    """
    sky = sky_share(tm, diffuse_fraction, omega_i) if tm.shadowed else None  # [B] this sun's
    rv = render(tm, camera_from_intrinsics(c2w, intr), features=spectral_features(tm, omega_i, backend=backend,
                diffuse_fraction=sky), backend=backend)
    mask = roi_pixels(roi, rv.depth, rv.alpha, c2w, intr, min_alpha=min_alpha)
    n = int(mask.sum())
    if n == 0:
        empty = np.full(len(tm.wavelengths_nm), np.nan, np.float32)
        return (empty, 0, mask, np.zeros((0, len(empty)), np.float32)) if return_pixels else (empty, 0, mask)
    m = torch.as_tensor(mask)
    spec = pixel_spectra(tm, rv.image[m], torch.as_tensor(rv.alpha)[m], diffuse_fraction=sky)  # [n, B]
    if return_pixels:
        return spec.mean(0), n, mask, spec
    return spec.mean(0), n, mask


def robust_keep(
    spectra: np.ndarray,  # [n, B]
    k_mad: float = 3.0,
    min_pixels: int = 10,
) -> np.ndarray:  # [n] bool
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


def _roi_target(tm: TrainedModel, roi: ROI) -> np.ndarray:  # [3] m
    c = np.asarray(roi.centre_m, float)
    if getattr(roi, "kind", "") == "polygon" and getattr(roi, "surface_dz_m", 0.0) == 0.0 \
            and getattr(roi, "surface_z_m", 0.0) == 0.0:
        roi.set_surface_height(tm.gaussians.means.detach().double().numpy())
        c = np.asarray(roi.centre_m, float)
    return c


def training_footprint_m(tm: TrainedModel) -> float:
    """Ground size (m) of one training pixel: median camera distance / focal length (px)."""
    return tm.typical_distance_m() / (0.5 * (tm.intrinsics.fl_x + tm.intrinsics.fl_y))


def auto_roi_size(tm: TrainedModel, half_extent_m: float, lo: int = 16, hi: int = 512) -> int:
    """Pixels of an ROI camera spanning 2·half_extent_m with the training pixel footprint."""
    return int(np.clip(math.ceil(2.0 * half_extent_m / training_footprint_m(tm)), lo, hi))


def roi_brf(
    tm: TrainedModel,
    roi: ROI,
    view_zenith_deg: ArrayLike,  # [D] deg (or a scalar)
    view_azimuth_deg: ArrayLike,  # [D] deg (or a scalar)
    band_idx: Sequence[int] | None = None,  # [nb] band indices (None: all)
    *,
    sun_deg: tuple[float, float] | None = None,
    size: int | None = None,
    distance_m: float | None = None,
    backend: str = "auto",
    progress: bool | str = False,
    min_alpha: float = MIN_ALPHA,
    diffuse_fraction=None,
) -> ROIBRF:
    """BRF of ``roi`` for the directions (arrays of equal length, degrees) in bands ``band_idx``,
    under the sun ``sun_deg`` = (zenith, azimuth) in degrees (default: the acquisition's) and, for a
    model trained with shadows, the sky ``diffuse_fraction`` (default the model's).

    ``size``: pixels of the square ROI camera (the ROI spans ~90 % of it); default: the size
    whose pixel footprint equals the training images' (:func:`auto_roi_size`) — 3DGS renders
    change with the pixel footprint (the 0.3 px² low-pass, opacity coverage), so the ROI is
    rendered at the scale the model was trained on. ``distance_m``:
    camera distance (default: the training cameras' median distance, at least 8 ROI radii so
    the direction is nearly the same over the ROI). Directions where the ROI is not seen
    (fully occluded) give NaN and 0 pixels. ``progress``: a progress bar (a string labels it).
    """
    zen = np.atleast_1d(np.asarray(view_zenith_deg, float))
    az = np.atleast_1d(np.asarray(view_azimuth_deg, float))
    if zen.shape != az.shape:
        raise ValueError("zenith and azimuth arrays must have the same shape")
    bi = np.arange(len(tm.wavelengths_nm)) if band_idx is None else np.asarray(band_idx, int)
    target = _roi_target(tm, roi)
    half = 1.1 * roi.radius_m
    if distance_m is None:
        # the training cameras' distance, but far enough that the view direction varies by at
        # most ~±7° across the ROI (an ROI's BRF is for one direction)
        dist = max(tm.typical_distance_m(), 8.0 * roi.radius_m)
    else:
        dist = max(float(distance_m), 1.5 * half)
    if size is None:
        size = auto_roi_size(tm, half)
    sun_z, sun_a = (tm.sun_zenith_deg, tm.sun_azimuth_deg) if sun_deg is None else sun_deg
    omega_i = tm.sun_direction(sun_z, sun_a)
    vals = np.full((zen.size, bi.size), np.nan, np.float32)
    counts = np.zeros(zen.size, np.int64)
    desc = progress if isinstance(progress, str) else "BRF"
    for k in tqdm(range(zen.size), desc=desc, leave=False, disable=not progress):
        c2w, intr = view_camera(zen.flat[k], az.flat[k], dist, target, size=size, half_extent_m=half)
        mean, n, _ = roi_mean_from_view(tm, roi, c2w, intr, omega_i, backend=backend, min_alpha=min_alpha,
                                        diffuse_fraction=diffuse_fraction)
        counts[k] = n
        if n:
            vals[k] = mean[bi]
    return ROIBRF(zen, az, tm.wavelengths_nm[bi], vals, counts,
                  {"distance_m": dist, "size_px": size, "half_extent_m": half, "target_m": target.tolist(),
                   "min_alpha": min_alpha, "sun_zenith_deg": sun_z, "sun_azimuth_deg": sun_a})


def principal_plane(tm: TrainedModel, roi: ROI, band_idx: Sequence[int], *, max_zenith_deg: float = 75.0,
                    step_deg: float = 2.5, **kw: Any) -> tuple[np.ndarray, ROIBRF]:
    """(signed view zenith [D] in degrees, ROIBRF) along the principal plane, −max…+max, in the
    bands ``band_idx`` [nb]; ``kw``: the sampling options of :func:`roi_brf`.

    Positive = sun's side (backscatter; the hotspot is at +θ_s), negative = forward
    (the specular direction is at −θ_s).
    """
    n = int(round(2 * max_zenith_deg / step_deg)) + 1
    s = np.linspace(-max_zenith_deg, max_zenith_deg, n)
    sun_az = tm.sun_azimuth_deg if kw.get("sun_deg") is None else kw["sun_deg"][1]
    zen, az = principal_plane_directions(s, sun_az)
    kw["progress"] = bool(kw.get("progress")) and "principal plane"
    return s, roi_brf(tm, roi, zen, az, band_idx, **kw)


def polar_map(tm: TrainedModel, roi: ROI, band_idx: Sequence[int], *, n_azimuth: int = 60, n_zenith: int = 24,
              max_zenith_deg: float = 75.0, **kw: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, ROIBRF]:
    """(zenith_deg [Z], azimuth_deg [A] (absolute view azimuth), values [Z, A, nb], ROIBRF) of the
    bands ``band_idx`` [nb]; ``kw``: the sampling options of :func:`roi_brf`."""
    zc, ac = hemisphere_grid(n_azimuth, n_zenith, max_zenith_deg)
    Z, A = np.meshgrid(zc, ac, indexing="ij")
    kw["progress"] = bool(kw.get("progress")) and "polar map"
    res = roi_brf(tm, roi, Z.ravel(), A.ravel(), band_idx, **kw)
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


def _frame_geometry(c2w: np.ndarray, target: np.ndarray, sun_azimuth_deg: float) -> tuple[float, ...]:
    """(zenith, azimuth, relative azimuth, signed principal-plane zenith, azimuthal distance to the
    principal plane) in degrees of a camera at ``c2w`` [4, 4] seen from ``target`` [3]."""
    zen, az = view_angles_from_points(c2w[:3, 3], target)
    rel = float(relative_azimuth_deg(az, sun_azimuth_deg))
    signed = float(signed_principal_plane_zenith_deg(zen, rel))
    off = float(min(rel % 180.0, 180.0 - rel % 180.0)) if zen > 1e-6 else 0.0
    return zen, az, rel, signed, off


def _check_scene_size(scene: Scene, intr: Intrinsics) -> None:
    if (scene.width, scene.height) != (intr.w, intr.h):
        raise UserError(f"the scene's images are {scene.width}x{scene.height} but the model was trained on "
                        f"{intr.w}x{intr.h} (use the same --downscale)", field="--scene")


def frame_observations(
    tm: TrainedModel,
    roi: ROI,
    scene: Scene | None = None,
    *,
    splits: tuple[str, ...] = ("train", "test"),
    truth: bool = True,
    backend: str = "auto",
    progress: bool = False,
    min_alpha: float = MIN_ALPHA,
    outlier_k_mad: float = 3.0,
    sun_deg: tuple[float, float] | None = None,
    diffuse_fraction=None,
) -> list[FrameObservation]:
    """ROI statistics of every frame of the model (training poses), optionally with images.

    For each frame: render the model from the frame's pose → ROI pixel mask (rendered
    depth) → mean reconstructed spectrum; with ``scene`` (brfgs.data.Scene matching the
    model's frames), the observed mean over the same pixels (valid pixels, outliers of the
    observed brightness beyond ``outlier_k_mad`` MADs removed — the reconstructed mean then
    uses the same pixels); with the
    scene's truth/ (simulated scenes), the truth mean over the pixels whose *true* surface
    point (truth/depth) lies in the ROI (same outlier removal). The view direction is measured from the ROI centre.
    The model is rendered under the sun ``sun_deg`` = (zenith, azimuth) deg (default: the acquisition's)
    and the sky ``diffuse_fraction`` (a model trained with shadows; default its own).
    """
    target = _roi_target(tm, roi)
    sun_z, sun_a = (tm.sun_zenith_deg, tm.sun_azimuth_deg) if sun_deg is None else sun_deg
    omega_i = tm.sun_direction(sun_z, sun_a)
    intr = tm.intrinsics
    name_to_index = {}
    if scene is not None:
        name_to_index = {f.name: i for i, f in enumerate(scene.frames)}
        _check_scene_size(scene, intr)
    truth_dir = getattr(scene, "truth_dir", None) if (scene is not None and truth) else None
    frames = [f for f in tm.frames if f.get("split", "train") in splits]
    out = []
    for fr in tqdm(frames, desc="frames", leave=False, disable=not progress):
        c2w = np.asarray(fr["c2w"], float)
        zen, az, rel, signed, off = _frame_geometry(c2w, target, sun_a)
        rec, n, mask, pix = roi_mean_from_view(tm, roi, c2w, intr, omega_i, backend=backend, min_alpha=min_alpha,
                                               return_pixels=True, diffuse_fraction=diffuse_fraction)
        obs = None
        tru, tn = None, 0
        if scene is not None and fr["name"] in name_to_index and n:
            o_pix = scene.load_image(name_to_index[fr["name"]])[mask]  # [n, B], mask order as pix
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


def _truth_mean(truth_dir: Path, name: str, c2w: np.ndarray, intr: Intrinsics, roi: ROI,
                outlier_k_mad: float = 3.0) -> tuple[np.ndarray | None, int]:
    """Mean truth spectrum [B] over pixels whose true surface point lies in the ROI, with the same
    outlier removal as the observed mean (:func:`robust_keep`: border pixels that mix the ROI
    with a brighter neighbour, e.g. water next to vegetation in the near infrared)."""
    truth_dir = Path(truth_dir)
    hdr = truth_dir / "images" / f"{name}.hdr"
    dp = truth_dir / "depth" / f"{name}.npy"
    if not (hdr.is_file() and dp.is_file() and envi_image_path(hdr) is not None):
        return None, 0
    cube = np.asarray(envi.open(str(hdr), str(envi_image_path(hdr))).load(), np.float32)
    depth = np.load(dp, allow_pickle=False).astype(float)
    intr = intrinsics_for_shape(intr, depth.shape)
    sel = points_in_roi(roi, unproject_depth(depth, c2w, intr))
    sel &= np.isfinite(cube).all(-1)
    if not sel.any():
        return None, 0
    vals = cube[sel]                                          # [n, B]
    keep = robust_keep(vals, outlier_k_mad)
    return vals[keep].mean(0), int(keep.sum())


def nearest_to_plane(obs: list[FrameObservation], max_offset_deg: float = 20.0,
                     zenith_bin_deg: float = 4.0) -> list[FrameObservation]:
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


def log_error(
    reconstructed: np.ndarray,  # [B]
    observed: np.ndarray,  # [B]
    floor: float = 1e-4,
) -> np.ndarray:  # [B]
    """Logarithmic error ln(reconstructed / observed) per band (both clipped to ≥ ``floor``)."""
    r = np.maximum(np.asarray(reconstructed, float), floor)
    o = np.maximum(np.asarray(observed, float), floor)
    return np.log(r / o)


def curve_peak(
    signed_zenith_deg: np.ndarray,  # [D]
    values: np.ndarray,  # [D]
) -> float:
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
