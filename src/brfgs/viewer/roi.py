"""A click on the rendered surface → a disc ROI, and its spectrum and BRF.

The hit point comes from the rendered depth (metres along the optical axis,
:func:`brfgs.analysis.roi.unproject_depth`); the ROI is a ground disc (:class:`PolygonROI`, a
regular polygon) around it. Its spectrum for the current view is
:func:`brfgs.analysis.brf.roi_mean_from_view`, its principal-plane curve and polar map are
:func:`brfgs.analysis.brf.principal_plane` and :func:`brfgs.analysis.brf.polar_map` — the
functions of ``brfgs brf``. :func:`save_roi` writes the CSVs and a GeoJSON of the disc (ENU
metres, readable by ``brfgs brf --roi FILE.geojson``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib import colormaps

from brfgs.analysis import brf as B
from brfgs.analysis.plots import write_csv
from brfgs.analysis.roi import PolygonROI, unproject_depth
from brfgs.data import atomic
from brfgs.data.angles import relative_azimuth_deg
from brfgs.data.cameras import Intrinsics
from brfgs.errors import UserError
from brfgs.model import TrainedModel

__all__ = ["hit_point", "disc_roi", "RoiResult", "roi_spectrum", "roi_directional", "polar_image", "save_roi",
           "DEFAULT_BANDS_NM"]

DEFAULT_BANDS_NM = (480.0, 680.0, 760.0, 860.0)


def hit_point(depth_m: np.ndarray, c2w: np.ndarray, intr: Intrinsics, x_px: float, y_px: float,
              alpha: np.ndarray | None = None, min_alpha: float = B.MIN_ALPHA) -> np.ndarray | None:
    """World point [3] (m, ENU) of the surface seen at pixel (x right, y down; pixel units, the
    pixel containing the point) of a render with ``depth_m`` [H, W]; None where nothing is hit."""
    i, j = int(math.floor(y_px)), int(math.floor(x_px))
    if not (0 <= i < intr.h and 0 <= j < intr.w):
        return None
    if alpha is not None and alpha[i, j] < min_alpha:
        return None
    p = unproject_depth(depth_m, c2w, intr)[i, j]  # [3]
    return p if np.isfinite(p).all() else None


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
                 sun_deg: tuple[float, float], backend: str = "auto") -> RoiResult:
    """The ROI's mean spectrum [B] in the view (c2w OpenGL [4, 4], intr) under the sun ``sun_deg``
    (zenith, azimuth; degrees) — :func:`brfgs.analysis.brf.roi_mean_from_view`; BRF fields empty."""
    spec, n, _ = B.roi_mean_from_view(tm, roi, c2w, intr, tm.sun_direction(*sun_deg), backend=backend)
    wl = np.asarray(tm.wavelengths_nm, float)
    empty = np.zeros((0,))
    return RoiResult(roi, wl, spec, n, empty, empty, np.zeros((0, 0)), empty, empty, np.zeros((0, 0, 0)),
                     (float(sun_deg[0]), float(sun_deg[1])))


def roi_directional(tm: TrainedModel, res: RoiResult, *, bands_nm=DEFAULT_BANDS_NM, step_deg: float = 5.0,
                    polar_azimuths: int = 24, polar_zeniths: int = 8, max_zenith_deg: float = 75.0,
                    backend: str = "auto") -> RoiResult:
    """Fill ``res`` with the principal-plane BRF and polar map of its ROI in ``bands_nm`` (those within
    the model's range) under its sun, as ``brfgs brf`` computes them
    (:func:`brfgs.analysis.brf.principal_plane`, :func:`brfgs.analysis.brf.polar_map`)."""
    wl = res.wavelengths_nm
    bands = [w for w in bands_nm if wl.min() - 10 <= w <= wl.max() + 10] or [float(wl[len(wl) // 2])]
    bi = tm.band_indices(bands)
    s, pp = B.principal_plane(tm, res.roi, bi, max_zenith_deg=max_zenith_deg, step_deg=step_deg,
                              sun_deg=res.sun_deg, backend=backend)
    zc, ac, vals, _ = B.polar_map(tm, res.roi, bi, n_azimuth=polar_azimuths, n_zenith=polar_zeniths,
                                  max_zenith_deg=max_zenith_deg, sun_deg=res.sun_deg, backend=backend)
    res.band_nm, res.pp_signed_zenith_deg, res.pp_values = wl[bi], s, pp.values
    res.polar_zenith_deg, res.polar_azimuth_deg, res.polar_values = zc, ac, vals
    res.extra["principal_plane_pixels"] = pp.n_pixels.tolist()
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
    last two once the BRF is computed) and roi.geojson into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    cols = [f"brf_{w:.0f}nm" for w in res.band_nm]
    paths = [write_csv(out / "spectrum.csv", ["wavelength_nm", "reflectance"],
                       [[float(w), float(v)] for w, v in zip(res.wavelengths_nm, res.spectrum)])]
    if res.pp_values.size == 0:  # the BRF is not computed yet
        return paths + [atomic.write_json(out / "roi.geojson", roi_geojson(res.roi))]
    paths.append(write_csv(out / "principal_plane.csv", ["signed_view_zenith_deg"] + cols,
                           [[float(s)] + [float(v) for v in row] for s, row in zip(res.pp_signed_zenith_deg,
                                                                                    res.pp_values)]))
    rows = [[float(z), float(a), float(relative_azimuth_deg(a, res.sun_deg[1]))]
            + [float(v) for v in res.polar_values[i, k]]
            for i, z in enumerate(res.polar_zenith_deg) for k, a in enumerate(res.polar_azimuth_deg)]
    paths.append(write_csv(out / "polar.csv", ["view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg"]
                           + cols, rows))
    paths.append(atomic.write_json(out / "roi.geojson", roi_geojson(res.roi)))
    return paths
