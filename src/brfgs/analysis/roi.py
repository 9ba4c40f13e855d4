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

ROI specifications on the command line (:func:`parse_roi_spec`):

    polygon:X1,Y1;X2,Y2;X3,Y3[;...]      ground polygon, ENU metres
    PATH.geojson | PATH.json | geojson:PATH
                                          GeoJSON file (:func:`read_geojson_polygons`): a Polygon or
                                          MultiPolygon geometry, a Feature holding one, or a
                                          FeatureCollection / GeometryCollection of them (their union);
                                          coordinates (x, y[, z ignored]) in the scene's local ENU
                                          metres, NOT longitude/latitude; a ``crs`` member other than a
                                          local/ENU one is refused
    box:VIEW:COL0,ROW0,COL1,ROW1          pixel box (inclusive-exclusive) in training view VIEW
    mask:VIEW:PATH                        boolean mask (.npy, or .png: nonzero = in) in view VIEW
    material:NAME                         material NAME of a simulated scene (truth/materials)
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from brfgs.data.cameras import Intrinsics, pixel_rays
from brfgs.errors import UserError

__all__ = [
    "ROI",
    "PolygonROI",
    "PointSetROI",
    "points_in_polygon",
    "unproject_depth",
    "pixel_footprint_m",
    "roi_from_view_mask",
    "read_materials_json",
    "material_points",
    "parse_roi_spec",
    "points_in_polygons",
    "read_geojson_polygons",
]


def points_in_polygon(xy: np.ndarray, polygon_xy: np.ndarray) -> np.ndarray:
    """Even-odd rule: bool [N] for points ``xy`` [N, 2] inside ``polygon_xy`` [V, 2] (closed implicitly)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    poly = np.asarray(polygon_xy, float).reshape(-1, 2)
    x, y = xy[:, 0:1], xy[:, 1:2]                          # [N, 1]
    x0, y0 = poly[:, 0][None], poly[:, 1][None]            # [1, V]
    x1, y1 = np.roll(poly[:, 0], -1)[None], np.roll(poly[:, 1], -1)[None]
    crosses = (y0 > y) != (y1 > y)                          # edge straddles the horizontal line
    with np.errstate(divide="ignore", invalid="ignore"):
        x_int = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    hit = crosses & (x < x_int)
    return (hit.sum(1) % 2) == 1


def points_in_polygons(xy: np.ndarray, polygons) -> np.ndarray:
    """bool [N]: points ``xy`` [N, 2] inside the union of ``polygons``.

    ``polygons``: list of polygons, each a list of rings [V, 2] — the exterior ring first,
    then its holes (GeoJSON layout). A point is inside a polygon when it is inside the
    exterior and in none of the holes (even-odd rule per ring).
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    out = np.zeros(len(xy), bool)
    for rings in polygons:
        inside = points_in_polygon(xy, rings[0])
        for hole in rings[1:]:
            inside &= ~points_in_polygon(xy, hole)
        out |= inside
    return out


def ring_area(ring_xy: np.ndarray) -> float:
    """Unsigned area (m²) of a ring [V, 2] (shoelace)."""
    v = np.asarray(ring_xy, float)
    return 0.5 * abs(float(np.dot(v[:, 0], np.roll(v[:, 1], -1)) - np.dot(v[:, 1], np.roll(v[:, 0], -1))))


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

    def _kdtree(self):
        if self._tree is None:
            from scipy.spatial import cKDTree

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
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"invalid JSON ({exc})", file=path) from None
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


def material_points(truth_dir: Path, material: str, frames, intrinsics: Intrinsics, *,
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
        h, w = mat.shape
        intr = intrinsics
        if (w, h) != (intrinsics.w, intrinsics.h):
            fx, fy = w / intrinsics.w, h / intrinsics.h
            intr = Intrinsics(intrinsics.fl_x * fx, intrinsics.fl_y * fy, intrinsics.cx * fx, intrinsics.cy * fy, w, h)
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


# ----------------------------------------------------------------------------------------
# command-line specifications


@dataclass
class ROISpec:
    """A parsed ROI specification (resolved against a model/scene by brfgs.analysis.brf)."""

    kind: str                       # "polygon" | "box" | "mask" | "material"
    name: str
    polygon_xy_m: np.ndarray | None = None
    polygons: list | None = None    # polygon kind from a GeoJSON file: [[exterior, holes...], ...]
    source: dict | None = None
    view: str | None = None
    box: tuple[int, int, int, int] | None = None
    mask_path: Path | None = None
    material: str | None = None


def _floats(text: str, field_: str) -> list[float]:
    try:
        vals = [float(t) for t in text.split(",")]
    except ValueError:
        raise UserError(f"expected comma-separated numbers, got {text!r}", field=field_) from None
    if not all(math.isfinite(v) for v in vals):
        raise UserError(f"expected finite numbers, got {text!r}", field=field_)
    return vals


# ----------------------------------------------------------------------------------------
# GeoJSON polygons

GEOJSON_SUFFIXES = (".geojson", ".json")
_LOCAL_CRS_WORDS = ("enu", "local")


def _is_local_crs(crs) -> bool:
    """True for a GeoJSON ``crs`` member that names a local / ENU frame (or is null)."""
    if crs is None:
        return True
    if not isinstance(crs, dict):
        return False
    props = crs.get("properties") if isinstance(crs.get("properties"), dict) else {}
    name = str(props.get("name", "")).lower()
    if crs.get("type") != "name" or not name:
        return False
    tokens = [t for t in re.split(r"[^a-z0-9]+", name) if t]
    return any(w in tokens for w in _LOCAL_CRS_WORDS) or "local_cs" in name or "engineering" in tokens


def _check_crs(obj: dict, path: Path, where: str) -> None:
    if "crs" in obj and not _is_local_crs(obj["crs"]):
        raise UserError(f"coordinate reference system {json.dumps(obj['crs'])} is not supported: the scene frame is "
                        "local ENU metres (x east, y north, around the scene centre), so the polygon must be "
                        "given in it; transform the coordinates into that frame and remove the 'crs' member "
                        "(or name a local one, e.g. {\"type\": \"name\", \"properties\": {\"name\": \"local-ENU\"}})",
                        file=path, field=f"{where}crs" if where else "crs")


def _geojson_ring(ring, path: Path, where: str) -> np.ndarray:
    if not isinstance(ring, list):
        raise UserError("a linear ring must be a list of positions [x, y]", file=path, field=where)
    pts = []
    for k, pos in enumerate(ring):
        if (not isinstance(pos, list) or len(pos) < 2
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in pos)):
            raise UserError(f"a position must be [x, y] or [x, y, z] numbers (ENU metres), got {json.dumps(pos)}",
                            file=path, field=f"{where}[{k}]")
        if not all(math.isfinite(float(c)) for c in pos[:2]):
            raise UserError(f"non-finite coordinate {json.dumps(pos)}", file=path, field=f"{where}[{k}]")
        pts.append((float(pos[0]), float(pos[1])))
    v = np.array(pts, float).reshape(-1, 2)
    if len(v) >= 2 and np.array_equal(v[0], v[-1]):
        v = v[:-1]                                   # GeoJSON rings repeat the first position at the end
    if len(v) < 3:
        raise UserError(f"a linear ring needs at least 3 distinct positions (4 with the closing one), got {len(ring)}",
                        file=path, field=where)
    if ring_area(v) <= 0:
        raise UserError("the ring has zero area", file=path, field=where)
    return v


def _geojson_polygon(coords, path: Path, where: str) -> list[np.ndarray]:
    if not isinstance(coords, list) or not coords:
        raise UserError("Polygon coordinates must be a non-empty list of linear rings", file=path, field=where)
    return [_geojson_ring(r, path, f"{where}[{i}]") for i, r in enumerate(coords)]


def _geojson_geometry(geom, path: Path, where: str) -> list[list[np.ndarray]]:
    if not isinstance(geom, dict):
        raise UserError("expected a GeoJSON geometry object", file=path, field=where.rstrip(".") or "geometry")
    _check_crs(geom, path, where)
    gtype = geom.get("type")
    if gtype == "Polygon":
        return [_geojson_polygon(geom.get("coordinates"), path, f"{where}coordinates")]
    if gtype == "MultiPolygon":
        coords = geom.get("coordinates")
        if not isinstance(coords, list) or not coords:
            raise UserError("MultiPolygon coordinates must be a non-empty list of polygons", file=path,
                            field=f"{where}coordinates")
        return [_geojson_polygon(c, path, f"{where}coordinates[{i}]") for i, c in enumerate(coords)]
    if gtype == "GeometryCollection":
        geoms = geom.get("geometries")
        if not isinstance(geoms, list) or not geoms:
            raise UserError("GeometryCollection needs a non-empty 'geometries' list", file=path,
                            field=f"{where}geometries")
        return [p for i, g in enumerate(geoms) for p in _geojson_geometry(g, path, f"{where}geometries[{i}].")]
    raise UserError(f"geometry type {gtype!r} cannot be an ROI: use a Polygon or MultiPolygon (ENU metres)",
                    file=path, field=f"{where}type")


def read_geojson_polygons(path: str | Path) -> tuple[list[list[np.ndarray]], str | None]:
    """Polygons of a GeoJSON file, as ``([[exterior, hole, ...], ...], name or None)``.

    Accepted: a bare Polygon / MultiPolygon / GeometryCollection, a Feature with such a
    geometry, or a FeatureCollection of them (the ROI is the union of all polygons).
    Coordinates are (x, y) in the scene's **local ENU metres** (x east, y north; a third
    coordinate is ignored) — not longitude/latitude: the scene frame is local, so a ``crs``
    member must be null or name a local/ENU frame (e.g. ``"local-ENU"``); any other CRS
    (EPSG codes, OGC:CRS84, ...) is refused. ``name`` is ``properties.name`` of the only
    Feature, if any. Every problem raises UserError naming the file and the JSON field.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError("ROI GeoJSON file not found", file=path, field="--roi")
    try:
        data = json.loads(path.read_text())
    except UnicodeDecodeError:
        raise UserError("not a text (UTF-8) GeoJSON file", file=path) from None
    except json.JSONDecodeError as exc:
        raise UserError(f"invalid JSON ({exc})", file=path) from None
    if not isinstance(data, dict) or "type" not in data:
        raise UserError("not a GeoJSON object (a JSON object with a 'type' member)", file=path, field="type")
    _check_crs(data, path, "")
    t = data["type"]
    name = None
    if t == "FeatureCollection":
        feats = data.get("features")
        if not isinstance(feats, list) or not feats:
            raise UserError("FeatureCollection needs a non-empty 'features' list", file=path, field="features")
        polys = []
        for i, f in enumerate(feats):
            if not isinstance(f, dict) or f.get("type") != "Feature":
                raise UserError("expected a Feature object", file=path, field=f"features[{i}].type")
            _check_crs(f, path, f"features[{i}].")
            if f.get("geometry") is None:
                raise UserError("the Feature has no geometry", file=path, field=f"features[{i}].geometry")
            polys += _geojson_geometry(f["geometry"], path, f"features[{i}].geometry.")
        if len(feats) == 1 and isinstance(feats[0].get("properties"), dict):
            name = feats[0]["properties"].get("name")
    elif t == "Feature":
        if data.get("geometry") is None:
            raise UserError("the Feature has no geometry", file=path, field="geometry")
        polys = _geojson_geometry(data["geometry"], path, "geometry.")
        if isinstance(data.get("properties"), dict):
            name = data["properties"].get("name")
    else:
        polys = _geojson_geometry(data, path, "")
    return polys, (str(name) if name not in (None, "") else None)


def _looks_like_geojson_path(text: str) -> bool:
    return text.lower().endswith(GEOJSON_SUFFIXES) or Path(text).is_file()


def parse_roi_spec(text: str, name: str | None = None) -> ROISpec:
    """Parse one ``--roi`` value (see the module docstring); UserError on malformed text.

    A GeoJSON file (``PATH.geojson``, ``PATH.json`` or ``geojson:PATH``) is read here, so a
    bad file fails before any model is loaded.
    """
    text = str(text).strip()
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    if kind == "geojson" or (kind not in ("polygon", "box", "mask", "material") and _looks_like_geojson_path(text)):
        path = Path(rest.strip() if kind == "geojson" else text)
        if kind == "geojson" and not rest.strip():
            raise UserError("geojson ROI: expected 'geojson:PATH'", field="--roi")
        polys, fname = read_geojson_polygons(path)
        nm = name or fname or path.stem
        return ROISpec("polygon", nm, polygon_xy_m=polys[0][0], polygons=polys,
                       source={"kind": "geojson", "file": str(path), "n_polygons": len(polys)})
    if kind == "polygon":
        pts = [p for p in rest.split(";") if p.strip()]
        xy = [_floats(p, "--roi") for p in pts]
        if len(xy) < 3 or any(len(v) != 2 for v in xy):
            raise UserError("polygon ROI: expected 'polygon:X1,Y1;X2,Y2;X3,Y3[;...]' (ENU metres)", field="--roi")
        return ROISpec("polygon", name or "polygon", polygon_xy_m=np.array(xy))
    if kind in ("box", "mask"):
        view, _, arg = rest.partition(":")
        if not view or not arg:
            raise UserError(f"{kind} ROI: expected '{kind}:VIEW:{'COL0,ROW0,COL1,ROW1' if kind == 'box' else 'PATH'}'",
                            field="--roi")
        if kind == "box":
            v = _floats(arg, "--roi")
            if len(v) != 4 or any(int(t) != t for t in v):
                raise UserError("box ROI: expected four integer pixel coordinates COL0,ROW0,COL1,ROW1", field="--roi")
            c0, r0, c1, r1 = (int(t) for t in v)
            if c1 <= c0 or r1 <= r0:
                raise UserError("box ROI: need COL1 > COL0 and ROW1 > ROW0", field="--roi")
            return ROISpec("box", name or f"box_{view}", view=view, box=(c0, r0, c1, r1))
        return ROISpec("mask", name or f"mask_{view}", view=view, mask_path=Path(arg))
    if kind == "material":
        if not rest.strip():
            raise UserError("material ROI: expected 'material:NAME'", field="--roi")
        return ROISpec("material", name or rest.strip(), material=rest.strip())
    raise UserError(f"unknown ROI kind {kind!r}; use polygon:, box:, mask:, material: or a GeoJSON file "
                    "(PATH.geojson)", field="--roi")


def load_mask(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """Boolean mask [H, W] from .npy or an image file (nonzero = in the ROI)."""
    path = Path(path)
    if not path.is_file():
        raise UserError("ROI mask file not found", file=path)
    if path.suffix.lower() == ".npy":
        m = np.load(path, allow_pickle=False)
    else:
        from PIL import Image

        m = np.asarray(Image.open(path))
        if m.ndim == 3:
            m = m[..., :3].max(-1)
    m = np.asarray(m) != 0
    if m.shape != tuple(shape):
        raise UserError(f"mask is {m.shape[1]}x{m.shape[0]} but the view is {shape[1]}x{shape[0]} pixels", file=path)
    return m
