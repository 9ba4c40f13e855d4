"""Regions of interest (ROI) on the reconstructed surface.

An ROI decides, for 3D surface points (ENU metres), whether they belong to it:

- :class:`PolygonROI` — a polygon in ground coordinates (x east, y north, metres), any
  height (optionally a z range).
- :class:`PointSetROI` — a set of surface points (from a pixel mask or box in a named
  view, unprojected with that view's depth, or from the material map of a simulated
  scene's truth) with a horizontal and a vertical tolerance: a point belongs to the ROI
  when an ROI point lies within ``tol_xy_m`` horizontally and ``tol_z_m`` vertically
  (an anisotropic neighbourhood, so the ground under a crown edge is not the crown).

The ROI's BRF for a direction (brfgs.analysis.brf) is the mean reflectance of the pixels,
rendered from that direction, whose surface point (from the rendered depth) lies in the ROI.
Polygon tests and GeoJSON files: :mod:`brfgs.analysis.polygons`; ROI specifications on the
command line (``--roi``): :mod:`brfgs.analysis.roi_spec`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from brfgs.analysis.polygons import MAX_COORDINATE, points_in_polygon, points_in_polygons, ring_area
from brfgs.data.cameras import Intrinsics, pixel_rays
from brfgs.data.validation import read_json_file
from brfgs.errors import UserError

__all__ = [
    "ROI",
    "PolygonROI",
    "PointSetROI",
    "points_in_polygon",
    "points_in_roi",
    "intrinsics_for_shape",
    "unproject_depth",
    "pixel_footprint_m",
    "roi_from_view_mask",
    "read_materials_json",
    "material_points",
    "points_in_polygons",
]


class ROI:
    """Base class: ``contains(points [N, 3]) -> bool [N]`` plus a centre and a bounding radius."""

    name: str = "roi"
    kind: str = "roi"

    def contains(self, points_m: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    @property
    def centre_m(self) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    @property
    def radius_m(self) -> float:  # pragma: no cover - interface
        """Radius of a sphere around :attr:`centre_m` that holds the ROI (metres)."""
        raise NotImplementedError

    def describe(self) -> dict:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class PolygonROI(ROI):
    """Ground polygon ``vertices_xy_m`` [V, 2] (ENU metres); ``z_range_m`` optional (lo, hi).

    ``polygons`` (optional): several polygons with holes, each a list of rings [V, 2]
    (exterior first, then holes; e.g. from a GeoJSON MultiPolygon); the ROI is their union
    and ``vertices_xy_m`` is then the first exterior ring (kept for display). ``source``
    records where the polygon came from (e.g. the GeoJSON file).

    The centre height is unknown until :meth:`set_surface_height` (the median height of
    the model's surface points inside the polygon); until then it is 0.
    """

    vertices_xy_m: np.ndarray
    name: str = "polygon"
    z_range_m: tuple[float, float] | None = None
    surface_z_m: float = 0.0
    surface_dz_m: float = 0.0
    polygons: list | None = None
    source: dict = field(default_factory=dict)
    kind: str = field(default="polygon", init=False)

    def __post_init__(self):
        polys = self.polygons if self.polygons is not None else [[self.vertices_xy_m]]
        clean = []
        for rings in polys:
            rr = []
            for ring in rings:
                v = np.asarray(ring, float)
                if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or not np.isfinite(v).all():
                    raise UserError("a polygon ROI needs at least 3 finite (x, y) vertices in metres", field="roi")
                if np.abs(v).max() > MAX_COORDINATE:
                    raise UserError(f"a vertex coordinate of {np.abs(v).max():.3g} is out of range: ROI vertices are "
                                    f"the scene's ENU metres, at most {MAX_COORDINATE:.0e} in size", field="roi")
                rr.append(v)
            if not rr:
                raise UserError("a polygon ROI needs at least one ring", field="roi")
            clean.append(rr)
        if not clean:
            raise UserError("a polygon ROI needs at least one polygon", field="roi")
        area = sum(max(ring_area(rr[0]) - sum(ring_area(h) for h in rr[1:]), 0.0) for rr in clean)
        if area <= 0:
            raise UserError("the polygon ROI has zero area", field="roi")
        self.polygons = clean
        self.vertices_xy_m = clean[0][0]

    @property
    def all_vertices_xy_m(self) -> np.ndarray:
        """Vertices [V, 2] of every exterior ring."""
        return np.concatenate([rr[0] for rr in self.polygons])

    @property
    def area_m2(self) -> float:
        """Area (m²) of the union (polygons assumed disjoint), holes removed."""
        return float(sum(max(ring_area(rr[0]) - sum(ring_area(h) for h in rr[1:]), 0.0) for rr in self.polygons))

    def contains(self, points_m: np.ndarray) -> np.ndarray:
        p = np.asarray(points_m, float).reshape(-1, 3)
        ok = np.isfinite(p).all(1)
        inside = np.zeros(len(p), bool)
        if len(self.polygons) == 1 and len(self.polygons[0]) == 1:
            inside[ok] = points_in_polygon(p[ok, :2], self.vertices_xy_m)
        else:
            inside[ok] = points_in_polygons(p[ok, :2], self.polygons)
        if self.z_range_m is not None:
            inside &= (p[:, 2] >= self.z_range_m[0]) & (p[:, 2] <= self.z_range_m[1])
        return inside

    def set_surface_height(self, surface_points_m: np.ndarray) -> None:
        """Centre height and height spread from surface points [N, 3] (e.g. Gaussian means)."""
        p = np.asarray(surface_points_m, float).reshape(-1, 3)
        inside = self.contains(p)
        if inside.any():
            z = p[inside, 2]
            self.surface_z_m = float(np.median(z))
            self.surface_dz_m = float(np.percentile(z, 98) - np.percentile(z, 2))

    @property
    def centre_m(self) -> np.ndarray:
        xy = self.all_vertices_xy_m.mean(0)
        return np.array([xy[0], xy[1], self.surface_z_m])

    @property
    def radius_m(self) -> float:
        v = self.all_vertices_xy_m
        r = float(np.max(np.linalg.norm(v - v.mean(0), axis=1)))
        return math.hypot(r, 0.5 * self.surface_dz_m)

    def describe(self) -> dict:
        d = {"kind": self.kind, "name": self.name, "vertices_xy_m": self.vertices_xy_m.tolist(),
             "z_range_m": list(self.z_range_m) if self.z_range_m else None,
             "centre_m": self.centre_m.tolist(), "radius_m": self.radius_m, "area_m2": self.area_m2}
        if len(self.polygons) > 1 or len(self.polygons[0]) > 1:
            d["polygons_xy_m"] = [[r.tolist() for r in rr] for rr in self.polygons]
        if self.source:
            d["source"] = self.source
        return d


@dataclass
class PointSetROI(ROI):
    """Surface points ``points_m`` [M, 3] with tolerances (metres); see the module docstring."""

    points_m: np.ndarray
    tol_xy_m: float
    tol_z_m: float
    name: str = "points"
    source: dict = field(default_factory=dict)
    kind: str = field(default="points", init=False)

    def __post_init__(self):
        p = np.asarray(self.points_m, float).reshape(-1, 3)
        p = p[np.isfinite(p).all(1)]
        if len(p) == 0:
            raise UserError(f"the ROI '{self.name}' has no surface points (empty mask, or no valid depth there)",
                            field="roi")
        if not (self.tol_xy_m > 0 and self.tol_z_m > 0):
            raise UserError("ROI tolerances must be positive metres", field="roi")
        self.points_m = p
        self._tree = None

    def _kdtree(self) -> cKDTree:
        if self._tree is None:
            scaled = self.points_m * np.array([1.0, 1.0, self.tol_xy_m / self.tol_z_m])
            self._tree = cKDTree(scaled)
        return self._tree

    def contains(self, points_m: np.ndarray) -> np.ndarray:
        """bool [N]: within tol_xy horizontally and tol_z vertically (an ellipsoidal neighbourhood)."""
        p = np.asarray(points_m, float).reshape(-1, 3)
        ok = np.isfinite(p).all(1)
        out = np.zeros(len(p), bool)
        if ok.any():
            scaled = p[ok] * np.array([1.0, 1.0, self.tol_xy_m / self.tol_z_m])
            d, _ = self._kdtree().query(scaled, k=1, distance_upper_bound=self.tol_xy_m * (1 + 1e-9))
            out[ok] = np.isfinite(d)
        return out

    @property
    def centre_m(self) -> np.ndarray:
        return np.median(self.points_m, axis=0)

    @property
    def radius_m(self) -> float:
        return float(np.max(np.linalg.norm(self.points_m - self.centre_m, axis=1))) + self.tol_xy_m

    def describe(self) -> dict:
        lo, hi = self.points_m.min(0), self.points_m.max(0)
        return {"kind": self.kind, "name": self.name, "n_points": int(len(self.points_m)),
                "tol_xy_m": self.tol_xy_m, "tol_z_m": self.tol_z_m, "bbox_min_m": lo.tolist(),
                "bbox_max_m": hi.tolist(), "centre_m": self.centre_m.tolist(), "radius_m": self.radius_m,
                "source": self.source}


# ----------------------------------------------------------------------------------------
# unprojection


def points_in_roi(
    roi: ROI,
    points_m: np.ndarray,  # [..., 3] (NaN: no point)
) -> np.ndarray:  # [...] bool
    """bool mask of the points that lie in ``roi`` (non-finite points are not in it)."""
    p = np.asarray(points_m, float)
    return roi.contains(p.reshape(-1, 3)).reshape(p.shape[:-1])


def intrinsics_for_shape(intr: Intrinsics, shape: tuple[int, int]) -> Intrinsics:
    """``intr`` rescaled to images of ``shape`` (H, W) (the same field of view), or ``intr`` itself."""
    h, w = shape
    if (w, h) == (intr.w, intr.h):
        return intr
    fx, fy = w / intr.w, h / intr.h
    return Intrinsics(intr.fl_x * fx, intr.fl_y * fy, intr.cx * fx, intr.cy * fy, w, h)


def unproject_depth(depth_m: np.ndarray, c2w_gl: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """World points [H, W, 3] of pixels with ``depth_m`` [H, W] (metres along the optical axis).

    Pixels with non-finite or non-positive depth give NaN.
    """
    depth = np.asarray(depth_m, float)
    if depth.shape != (intr.h, intr.w):
        raise ValueError(f"depth shape {depth.shape} does not match the camera {intr.h}x{intr.w}")
    o, d = pixel_rays(c2w_gl, intr)                      # [H, W, 3] each, d unit
    forward = -np.asarray(c2w_gl, float)[:3, 2]          # OpenGL camera looks along −Z
    t = depth / np.clip(d @ forward, 1e-9, None)         # ray length for that axial depth
    pts = o + d * t[..., None]
    pts[~(np.isfinite(depth) & (depth > 0))] = np.nan
    return pts


def pixel_footprint_m(depth_m: np.ndarray, intr: Intrinsics, mask: np.ndarray | None = None) -> float:
    """Median size of one pixel on the surface (metres): depth / focal length over the pixels."""
    d = np.asarray(depth_m, float)
    sel = np.isfinite(d) & (d > 0)
    if mask is not None:
        sel &= np.asarray(mask, bool)
    if not sel.any():
        return float("nan")
    return float(np.median(d[sel])) / (0.5 * (intr.fl_x + intr.fl_y))


def roi_from_view_mask(mask: np.ndarray, depth_m: np.ndarray, c2w_gl: np.ndarray, intr: Intrinsics, *,
                       name: str = "mask", tol_xy_m: float | None = None, tol_z_m: float | None = None,
                       source: dict | None = None) -> PointSetROI:
    """Project a pixel mask [H, W] of one view onto the surface given by that view's depth.

    Tolerances default to 1.5 pixel footprints horizontally and max(2 m, 4 footprints)
    vertically (keeps crown sides, rejects the ground under a crown's edge).
    """
    mask = np.asarray(mask, bool)
    if mask.shape != (intr.h, intr.w):
        raise UserError(f"ROI mask is {mask.shape[1]}x{mask.shape[0]} pixels but the view is {intr.w}x{intr.h}",
                        field="roi")
    if not mask.any():
        raise UserError("the ROI mask selects no pixel", field="roi")
    pts = unproject_depth(depth_m, c2w_gl, intr)[mask]   # [M, 3]
    fp = pixel_footprint_m(depth_m, intr, mask)
    if not math.isfinite(fp):
        raise UserError("no valid depth under the ROI mask (the model shows nothing there)", field="roi")
    tol_xy = 1.5 * fp if tol_xy_m is None else float(tol_xy_m)
    tol_z = max(2.0, 4.0 * fp) if tol_z_m is None else float(tol_z_m)
    return PointSetROI(pts, tol_xy, tol_z, name=name, source=source or {})


# ----------------------------------------------------------------------------------------
# materials of simulated scenes


def read_materials_json(truth_dir: Path) -> dict[int, str]:
    """{material id: name} from truth/materials.json (accepts a few layouts)."""
    path = Path(truth_dir) / "materials.json"
    if not path.is_file():
        raise UserError("no materials.json: material ROIs need a simulated scene's truth/ folder", file=path)
    data = read_json_file(path, "materials file")
    out: dict[int, str] = {}
    items = data.get("materials", data) if isinstance(data, dict) else data
    if isinstance(items, dict):
        for k, v in items.items():
            if isinstance(v, dict):
                if "id" in v:  # {name: {"id": i, ...}}
                    out[int(v["id"])] = str(v.get("name", k))
                else:          # {id: {"name": ..., "spectrum": ...}}
                    out[int(k)] = str(v.get("name", k))
            else:              # {id: name}
                out[int(k)] = str(v)
    elif isinstance(items, list):
        for i, v in enumerate(items):
            if isinstance(v, dict):
                out[int(v.get("id", i))] = str(v["name"])
            else:
                out[i] = str(v)
    if not out:
        raise UserError("no materials listed", file=path)
    return out


def material_points(truth_dir: Path, material: str, frames: Sequence, intrinsics: Intrinsics, *,
                    max_points: int = 200_000, seed: int = 0) -> tuple[np.ndarray, float]:
    """Surface points [M, 3] of ``material`` seen in the truth material maps of ``frames``.

    ``frames``: objects with ``.name`` and ``.c2w`` (the scene's frames). Uses
    truth/materials/<name>.npy (int16 ids) and truth/depth/<name>.npy (metres along the
    optical axis), at the maps' own resolution (intrinsics rescaled if the maps differ from
    ``intrinsics``). Returns (points, median pixel footprint in metres).
    """
    truth_dir = Path(truth_dir)
    ids = read_materials_json(truth_dir)
    want = [i for i, n in ids.items() if n == material]
    if not want:
        raise UserError(f"material {material!r} not in this scene; known: {sorted(set(ids.values()))}",
                        file=truth_dir / "materials.json", field="roi")
    pts, fps = [], []
    for fr in frames:
        mp = truth_dir / "materials" / f"{fr.name}.npy"
        dp = truth_dir / "depth" / f"{fr.name}.npy"
        if not (mp.is_file() and dp.is_file()):
            continue
        mat = np.load(mp, allow_pickle=False)
        dep = np.load(dp, allow_pickle=False).astype(float)
        sel = np.isin(mat, want)
        if not sel.any():
            continue
        intr = intrinsics_for_shape(intrinsics, mat.shape)
        pts.append(unproject_depth(dep, fr.c2w, intr)[sel])
        fps.append(pixel_footprint_m(dep, intr, sel))
    if not pts:
        raise UserError(f"material {material!r} is not visible in any truth material map", file=truth_dir,
                        field="roi")
    p = np.concatenate(pts)
    p = p[np.isfinite(p).all(1)]
    if len(p) > max_points:
        p = p[np.sort(np.random.default_rng(seed).choice(len(p), max_points, replace=False))]
    return p, float(np.nanmedian(fps))
