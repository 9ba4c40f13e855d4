"""A click on the rendered surface → a disc ROI, and its spectrum and BRF.

The hit point is where the clicked pixel's ray meets the surface: the depth at which the
opacity accumulated along the ray first reaches half of its total (the median depth of the
ray's blending weights), found with the rasterizer itself (:func:`surface_hit`); a ray whose
total opacity is below :data:`brfgs.viewer.frames.SURFACE_MIN_ALPHA` hits nothing. The ROI is a
ground disc (:class:`PolygonROI`, a regular polygon) around the point. Its spectrum for the current
view is :func:`brfgs.analysis.brf.roi_mean_from_view`, its principal-plane curve and polar map are
:func:`brfgs.analysis.brf.roi_brf` over the directions of
:func:`brfgs.analysis.brf.principal_plane` and :func:`brfgs.analysis.brf.polar_map` — the
functions of ``brfgs brf``, with pixels counted from the same opacity as clicks
(``brfgs brf --min-alpha 0.1``), one direction at a time so the caller can report progress.
:func:`save_roi` writes the CSVs and a GeoJSON of the disc (ENU metres, readable by
``brfgs brf --roi FILE.geojson``).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from matplotlib import colormaps
from torch import Tensor

from brfgs.analysis import brf as B
from brfgs.analysis.plots import write_csv
from brfgs.analysis.roi import PolygonROI
from brfgs.analysis.views import hemisphere_grid, principal_plane_directions
from brfgs.data import atomic, lock
from brfgs.data.angles import relative_azimuth_deg
from brfgs.data.cameras import Intrinsics, pixel_rays
from brfgs.errors import UserError
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from brfgs.model.rendering import frustum_subset
from brfgs.viewer.frames import SURFACE_MIN_ALPHA

__all__ = ["surface_hit", "click_ray", "disc_roi", "RoiResult", "roi_spectrum", "roi_directional", "polar_image",
           "save_roi", "save_roi_folder", "DEFAULT_BANDS_NM"]

DEFAULT_BANDS_NM = (480.0, 680.0, 760.0, 860.0)
_PROBE_THRESHOLDS = 64  # depth thresholds per probe render


def _pixel_camera(intr: Intrinsics, x: float, y: float) -> Intrinsics:
    """The one-pixel image centred on the point (x, y) ∈ [0, 1]² (0, 0 top left) of ``intr``'s image."""
    return Intrinsics(intr.fl_x, intr.fl_y, intr.cx - x * intr.w + 0.5, intr.cy - y * intr.h + 0.5, 1, 1)


def click_ray(c2w: np.ndarray, intr: Intrinsics, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """(origin [3], unit direction [3]) of the ray through the point (x, y) ∈ [0, 1]² of the image
    (0, 0 top left) of the OpenGL camera ``c2w`` [4, 4] with ``intr``."""
    o, d = pixel_rays(np.asarray(c2w, float), _pixel_camera(intr, x, y))
    return np.asarray(o, float).reshape(-1, 3)[0], np.asarray(d, float).reshape(-1, 3)[0]


def _opacity_before(tm: TrainedModel, cam, z: Tensor, thresholds: np.ndarray, backend: str) -> tuple[np.ndarray, float]:
    """(opacity accumulated in front of each threshold depth [M], total opacity) of the one-pixel
    camera ``cam``: the rasterizer blends the indicator z_k ≤ t_m of each Gaussian, and with
    depth-ordered blending Σ_{z_k ≤ t} w_k is the opacity accumulated up to depth t."""
    t = torch.as_tensor(thresholds, dtype=z.dtype)

    def indicators(idx: Tensor, omega_o: Tensor) -> Tensor:  # [n, M]
        return (z[idx, None] <= t[None, :]).to(torch.float32)

    rv = render(tm, cam, features=indicators, backend=backend)
    return rv.image.reshape(-1, len(thresholds)).mean(0).numpy().astype(np.float64), float(rv.alpha.mean())


def surface_hit(tm: TrainedModel, c2w: np.ndarray, intr: Intrinsics, x: float, y: float, *,
                min_alpha: float = SURFACE_MIN_ALPHA, backend: str = "auto") -> np.ndarray | None:
    """World point [3] (m, ENU) of the surface seen at the point (x, y) ∈ [0, 1]² (0, 0 top left) of
    the view (OpenGL ``c2w`` [4, 4], ``intr``): on the pixel's ray, at the depth where the opacity
    accumulated along it first reaches half of its total (the median depth of the blending weights);
    None when the total is below ``min_alpha``.

    That pixel alone is rendered (the view's camera with a one-pixel image); each render blends, for
    up to 64 depth thresholds, the indicator "in front of the threshold", which gives the opacity
    accumulated up to those depths. The thresholds bracket the crossing among the depths of the
    Gaussians that can touch the pixel and narrow down to single Gaussians' depths (exact in a few
    renders)."""
    c2w = np.asarray(c2w, float)
    probe = _pixel_camera(intr, x, y)
    cam = camera_from_intrinsics(c2w, probe)
    origin, direction = click_ray(c2w, intr, x, y)
    axis = -c2w[:3, 2]  # the optical axis (OpenGL cameras look along -z): the rasterizer's depth
    f = tm.frozen()
    z = ((f["means"].double() - torch.as_tensor(origin)) @ torch.as_tensor(axis)).to(f["means"].dtype)  # [N]
    cand = np.unique(z[frustum_subset(f["means"], f["max_scale"], cam)].numpy().astype(np.float64))
    cand = cand[cand > 0.01]
    if cand.size == 0:
        return None
    _, total = _opacity_before(tm, cam, z, cand[-1:] + 1.0, backend)
    if total < min_alpha:
        return None
    target = 0.5 * total
    while True:
        if cand.size <= _PROBE_THRESHOLDS:  # every depth: thresholds between consecutive ones
            cuts = np.append(0.5 * (cand[:-1] + cand[1:]), cand[-1] + 1.0)
            acc, _ = _opacity_before(tm, cam, z, cuts, backend)
            k = int(np.argmax(acc >= target)) if (acc >= target).any() else cand.size - 1
            return origin + float(cand[k]) / float(direction @ axis) * direction
        pick = np.unique(np.linspace(0, cand.size - 1, _PROBE_THRESHOLDS).round().astype(int))
        acc, _ = _opacity_before(tm, cam, z, cand[pick], backend)
        k = int(np.argmax(acc >= target)) if (acc >= target).any() else len(pick) - 1
        lo = pick[k - 1] + 1 if k > 0 else 0
        cand = cand[lo:pick[k] + 1]


def disc_roi(centre_m: np.ndarray, radius_m: float, n_vertices: int = 32, name: str = "click") -> PolygonROI:
    """A ground disc (regular ``n_vertices``-gon) of ``radius_m`` around ``centre_m`` [3] (m, ENU)."""
    if not (math.isfinite(radius_m) and radius_m > 0):
        raise UserError(f"ROI radius must be a positive number of metres, got {radius_m!r}", field="radius")
    c = np.asarray(centre_m, float)
    t = np.linspace(0.0, 2.0 * math.pi, n_vertices, endpoint=False)
    xy = c[:2] + radius_m * np.stack([np.cos(t), np.sin(t)], -1)  # [V, 2]
    return PolygonROI(xy, name=name, source={"kind": "viewer click", "centre_m": c.tolist(), "radius_m": radius_m})


@dataclass
class RoiResult:
    """One ROI's analysis: spectrum [B] of the current view, principal plane (signed zenith [D],
    values [D, nb]), polar map (zenith [Z], azimuth [A], values [Z, A, nb])."""

    roi: PolygonROI
    wavelengths_nm: np.ndarray  # [B]
    spectrum: np.ndarray  # [B]
    n_pixels: int
    band_nm: np.ndarray  # [nb]
    pp_signed_zenith_deg: np.ndarray  # [D]
    pp_values: np.ndarray  # [D, nb]
    polar_zenith_deg: np.ndarray  # [Z]
    polar_azimuth_deg: np.ndarray  # [A]
    polar_values: np.ndarray  # [Z, A, nb]
    sun_deg: tuple[float, float] = (0.0, 0.0)
    extra: dict = field(default_factory=dict)


def roi_spectrum(tm: TrainedModel, roi: PolygonROI, c2w: np.ndarray, intr: Intrinsics,
                 sun_deg: tuple[float, float], backend: str = "auto", min_alpha: float = SURFACE_MIN_ALPHA
                 ) -> RoiResult:
    """The ROI's mean spectrum [B] in the view (c2w OpenGL [4, 4], intr) under the sun ``sun_deg``
    (zenith, azimuth; degrees) — :func:`brfgs.analysis.brf.roi_mean_from_view`; BRF fields empty."""
    spec, n, _ = B.roi_mean_from_view(tm, roi, c2w, intr, tm.sun_direction(*sun_deg), backend=backend,
                                      min_alpha=min_alpha)
    roi.source["min_alpha"] = min_alpha  # in roi.geojson: brfgs brf --min-alpha reads the same pixels
    wl = np.asarray(tm.wavelengths_nm, float)
    empty = np.zeros((0,))
    return RoiResult(roi, wl, spec, n, empty, empty, np.zeros((0, 0)), empty, empty, np.zeros((0, 0, 0)),
                     (float(sun_deg[0]), float(sun_deg[1])), {"min_alpha": min_alpha})


def roi_directional(tm: TrainedModel, res: RoiResult, *, bands_nm=DEFAULT_BANDS_NM, step_deg: float = 5.0,
                    polar_azimuths: int = 24, polar_zeniths: int = 8, max_zenith_deg: float = 75.0,
                    backend: str = "auto", each: Callable[[int, int], AbstractContextManager] | None = None,
                    principal_plane_done: Callable[[RoiResult], None] | None = None) -> RoiResult:
    """Fill ``res`` with the principal-plane BRF and polar map of its ROI in ``bands_nm`` (those within
    the model's range) under its sun: :func:`brfgs.analysis.brf.roi_brf` over the directions of
    :func:`brfgs.analysis.brf.principal_plane` and :func:`brfgs.analysis.brf.polar_map` (the same
    values), one direction at a time, each inside the context ``each(done, total)`` (which may wait,
    hold a lock, or raise to stop); the principal plane comes first and ``principal_plane_done(res)``
    is called once its fields are filled."""
    wl = res.wavelengths_nm
    bands = [w for w in bands_nm if wl.min() - 10 <= w <= wl.max() + 10] or [float(wl[len(wl) // 2])]
    bi = tm.band_indices(bands)
    n_pp = int(round(2 * max_zenith_deg / step_deg)) + 1
    s = np.linspace(-max_zenith_deg, max_zenith_deg, n_pp)
    pp_zen, pp_az = principal_plane_directions(s, res.sun_deg[1])
    zc, ac = hemisphere_grid(polar_azimuths, polar_zeniths, max_zenith_deg)
    Z, A = np.meshgrid(zc, ac, indexing="ij")
    zen, az = np.concatenate([pp_zen, Z.ravel()]), np.concatenate([pp_az, A.ravel()])
    vals = np.full((zen.size, len(bi)), np.nan, np.float32)
    counts = np.zeros(zen.size, np.int64)
    min_alpha = float(res.extra.get("min_alpha", SURFACE_MIN_ALPHA))
    for k in range(zen.size):
        with (each(k, zen.size) if each is not None else contextlib.nullcontext()):
            one = B.roi_brf(tm, res.roi, zen[k:k + 1], az[k:k + 1], bi, sun_deg=res.sun_deg, backend=backend,
                            min_alpha=min_alpha)
        vals[k], counts[k] = one.values[0], one.n_pixels[0]
        if k == n_pp - 1:
            res.band_nm, res.pp_signed_zenith_deg, res.pp_values = wl[bi], s, vals[:n_pp]
            res.extra["principal_plane_pixels"] = counts[:n_pp].tolist()
            if principal_plane_done is not None:
                principal_plane_done(res)
    res.polar_zenith_deg, res.polar_azimuth_deg = zc, ac
    res.polar_values = vals[n_pp:].reshape(len(zc), len(ac), -1)
    return res


def polar_image(zenith_deg: np.ndarray, azimuth_deg: np.ndarray, values: np.ndarray, size_px: int = 200,
                max_zenith_deg: float = 75.0) -> np.ndarray:  # [S, S, 3] uint8
    """A polar map as an image: north up, east right, radius ∝ view zenith; each pixel takes the
    nearest grid cell of ``values`` [Z, A] (zenith_deg [Z], azimuth_deg [A] cell centres), viridis
    over its 2–98 % range; outside the disc or NaN: white."""
    c = (np.arange(size_px) + 0.5) / size_px * 2.0 - 1.0
    X, Y = np.meshgrid(c, -c)  # [S, S], north (+y) up
    r_deg = np.hypot(X, Y) * max_zenith_deg
    az = np.degrees(np.arctan2(X, Y)) % 360.0  # clockwise from north
    zi = np.abs(r_deg[..., None] - np.asarray(zenith_deg)).argmin(-1)
    da = np.abs((az[..., None] - np.asarray(azimuth_deg) + 180.0) % 360.0 - 180.0)
    v = np.asarray(values, float)[zi, da.argmin(-1)]  # [S, S]
    ok = np.isfinite(v) & (r_deg <= max_zenith_deg)
    lo, hi = (np.percentile(v[ok], 2), np.percentile(v[ok], 98)) if ok.any() else (0.0, 1.0)
    rgb = colormaps["viridis"](np.clip((np.nan_to_num(v) - lo) / max(hi - lo, 1e-12), 0, 1))[..., :3]
    rgb[~ok] = 1.0
    return (rgb * 255 + 0.5).astype(np.uint8)


def roi_geojson(roi: PolygonROI) -> dict:
    """GeoJSON Feature of the disc in ENU metres (local coordinates, no CRS)."""
    ring = np.vstack([roi.vertices_xy_m, roi.vertices_xy_m[:1]]).tolist()
    return {"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"name": roi.name, "units": "m, local ENU", **roi.source},
        "geometry": {"type": "Polygon", "coordinates": [ring]}}]}


def save_roi(res: RoiResult, out_dir: Path) -> list[Path]:
    """Write spectrum.csv, principal_plane.csv, polar.csv (columns as ``brfgs brf`` writes them; the
    last two once they are computed) and roi.geojson into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    cols = [f"brf_{w:.0f}nm" for w in res.band_nm]
    paths = [write_csv(out / "spectrum.csv", ["wavelength_nm", "reflectance"],
                       [[float(w), float(v)] for w, v in zip(res.wavelengths_nm, res.spectrum)])]
    if res.pp_values.size:  # once computed
        paths.append(write_csv(out / "principal_plane.csv", ["signed_view_zenith_deg"] + cols,
                               [[float(s)] + [float(v) for v in row] for s, row in zip(res.pp_signed_zenith_deg,
                                                                                        res.pp_values)]))
    if res.polar_values.size:
        rows = [[float(z), float(a), float(relative_azimuth_deg(a, res.sun_deg[1]))]
                + [float(v) for v in res.polar_values[i, k]]
                for i, z in enumerate(res.polar_zenith_deg) for k, a in enumerate(res.polar_azimuth_deg)]
        paths.append(write_csv(out / "polar.csv", ["view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg"]
                               + cols, rows))
    paths.append(atomic.write_json(out / "roi.geojson", roi_geojson(res.roi)))
    return paths


def save_roi_folder(res: RoiResult, parent: Path, name: str | None = None) -> Path:
    """Save ``res`` (:func:`save_roi`) into a new folder ``parent/name`` (``name`` a checked ROI name,
    :func:`brfgs.viewer.checks.roi_name`; default the first free ``roi_NN``), holding ``parent``'s
    writer lock; an existing folder is never written into (UserError naming it)."""
    parent = Path(parent)
    with lock.folder_lock(parent, "brfgs view (saving an ROI)"):
        if name is None:
            n = 1
            while (parent / f"roi_{n:02d}").exists():
                n += 1
            name = f"roi_{n:02d}"
        folder = parent / name
        if folder.resolve().parent != parent.resolve():
            raise UserError(f"ROI name {name!r} leaves the ROI folder {parent}", field="ROI name")
        try:
            folder.mkdir()
        except FileExistsError:
            raise UserError(f"{folder} exists already; choose another ROI name", file=folder, field="ROI name") from None
        res.roi.name = name
        save_roi(res, folder)
    return folder
