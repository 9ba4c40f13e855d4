"""ROI specifications of the command line (``--roi``) and their resolution against a model.

    polygon:X1,Y1;X2,Y2;X3,Y3[;...]      ground polygon, ENU metres
    PATH.geojson | PATH.json | geojson:PATH
                                          GeoJSON file (:func:`brfgs.analysis.polygons.read_geojson_polygons`):
                                          a Polygon or MultiPolygon geometry, a Feature holding one, or a
                                          FeatureCollection / GeometryCollection of them (their union);
                                          coordinates (x, y[, z ignored]) in the scene's local ENU
                                          metres, or WGS 84 lon/lat when its ``crs`` names OGC CRS84 /
                                          EPSG:4326 (a georeferenced scene: transforms.json ``origin``)
    lonlat:PATH                           the same file read as RFC 7946 lon/lat (no ``crs`` member)
    box:VIEW:COL0,ROW0,COL1,ROW1          pixel box (inclusive-exclusive) in training view VIEW
    mask:VIEW:PATH                        boolean mask (.npy, or .png: nonzero = in) in view VIEW
    material:NAME                         material NAME of a simulated scene (truth/materials)

:func:`parse_roi_spec` reads the text (and a GeoJSON file) without a model; :func:`resolve_roi`
turns the spec into an :class:`brfgs.analysis.roi.ROI` for a model (and, for materials, its scene).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from PIL import Image

from brfgs.analysis.options import parse_floats
from brfgs.analysis.polygons import GEOJSON_SUFFIXES, MAX_COORDINATE, is_lonlat_crs, read_geojson_polygons
from brfgs.analysis.roi import ROI, PointSetROI, PolygonROI, material_points, roi_from_view_mask
from brfgs.data.scene import Scene
from brfgs.data.validation import plain_text, read_json_file
from brfgs.errors import UserError
from brfgs.model import TrainedModel, camera_from_intrinsics, render

__all__ = ["ROISpec", "parse_roi_spec", "load_mask", "resolve_roi"]


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
    lonlat: bool = False            # polygon vertices are (lon, lat) degrees (WGS 84), not ENU metres


def _looks_like_geojson_path(text: str) -> bool:
    return text.lower().endswith(GEOJSON_SUFFIXES) or Path(text).is_file()


def parse_roi_spec(text: str, name: str | None = None) -> ROISpec:
    """Parse one ``--roi`` value (see the module docstring); UserError on malformed text.

    A GeoJSON file (``PATH.geojson``, ``PATH.json`` or ``geojson:PATH``) is read here, so a
    bad file fails before any model is loaded.
    """
    text = str(text).strip()
    if name is not None:
        plain_text(str(name), None, "--roi-name")
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    if kind in ("geojson", "lonlat") or (kind not in ("polygon", "box", "mask", "material")
                                         and _looks_like_geojson_path(text)):
        path = Path(rest.strip() if kind in ("geojson", "lonlat") else text)
        if kind in ("geojson", "lonlat") and not rest.strip():
            raise UserError(f"{kind} ROI: expected '{kind}:PATH'", field="--roi")
        polys, fname = read_geojson_polygons(path)
        lonlat = kind == "lonlat" or is_lonlat_crs(read_json_file(path, "GeoJSON file").get("crs"))
        nm = name or fname or path.stem
        return ROISpec("polygon", nm, polygon_xy_m=polys[0][0], polygons=polys, lonlat=lonlat,
                       source={"kind": "geojson", "file": str(path), "n_polygons": len(polys),
                               "coordinates": "lon/lat (WGS 84)" if lonlat else "ENU metres"})
    if kind == "polygon":
        pts = [p for p in rest.split(";") if p.strip()]
        xy = [parse_floats(p, "--roi") for p in pts]
        if len(xy) < 3 or any(len(v) != 2 for v in xy):
            raise UserError("polygon ROI: expected 'polygon:X1,Y1;X2,Y2;X3,Y3[;...]' (ENU metres)", field="--roi")
        if max(abs(c) for v in xy for c in v) > MAX_COORDINATE:
            raise UserError(f"polygon ROI: a coordinate is out of range: vertices are the scene's ENU metres, at most "
                            f"{MAX_COORDINATE:.0e} in size", field="--roi")
        return ROISpec("polygon", name or "polygon", polygon_xy_m=np.array(xy))
    if kind in ("box", "mask"):
        view, _, arg = rest.partition(":")
        if not view or not arg:
            raise UserError(f"{kind} ROI: expected '{kind}:VIEW:{'COL0,ROW0,COL1,ROW1' if kind == 'box' else 'PATH'}'",
                            field="--roi")
        if kind == "box":
            v = parse_floats(arg, "--roi")
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
    raise UserError(f"unknown ROI kind {kind!r}; use polygon:, box:, mask:, material:, a GeoJSON file "
                    "(PATH.geojson) or lonlat:PATH.geojson", field="--roi")


def load_mask(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """Boolean mask [H, W] from .npy or an image file (nonzero = in the ROI)."""
    path = Path(path)
    if not path.is_file():
        raise UserError("ROI mask file not found", file=path)
    if path.suffix.lower() == ".npy":
        m = np.load(path, allow_pickle=False)
    else:
        m = np.asarray(Image.open(path))
        if m.ndim == 3:
            m = m[..., :3].max(-1)
    m = np.asarray(m) != 0
    if m.shape != tuple(shape):
        raise UserError(f"mask is {m.shape[1]}x{m.shape[0]} but the view is {shape[1]}x{shape[0]} pixels", file=path)
    return m


def _check_polygon_over_model(roi: PolygonROI, spec: ROISpec, means: np.ndarray) -> None:
    """UserError when the polygon lies outside the model's horizontal extent (wrong coordinates)."""
    lo, hi = means[:, :2].min(0), means[:, :2].max(0)
    v = roi.all_vertices_xy_m
    if v[:, 0].max() < lo[0] or v[:, 0].min() > hi[0] or v[:, 1].max() < lo[1] or v[:, 1].min() > hi[1]:
        src = (spec.source or {}).get("file")
        raise UserError(f"the polygon (x {v[:, 0].min():.6g}..{v[:, 0].max():.6g}, y {v[:, 1].min():.6g}.."
                        f"{v[:, 1].max():.6g}) lies outside the model (x {lo[0]:.1f}..{hi[0]:.1f}, "
                        f"y {lo[1]:.1f}..{hi[1]:.1f} m); ROI coordinates are the scene's local ENU metres, "
                        "not longitude/latitude or projected map coordinates",
                        file=src, field="coordinates" if src else "--roi")


def _view_roi(spec: ROISpec, tm: TrainedModel, backend: str) -> PointSetROI:
    """A box or mask of a training view, projected onto the surface that view renders."""
    c2w = np.asarray(tm.frame(spec.view)["c2w"], float)
    intr = tm.intrinsics
    rv = render(tm, camera_from_intrinsics(c2w, intr), decode=False, backend=backend)
    if spec.kind == "box":
        c0, r0, c1, r1 = spec.box
        if c0 < 0 or r0 < 0 or c1 > intr.w or r1 > intr.h:
            raise UserError(f"box {spec.box} lies outside the {intr.w}x{intr.h} view {spec.view!r}", field="--roi")
        mask = np.zeros((intr.h, intr.w), bool)
        mask[r0:r1, c0:c1] = True
    else:
        mask = load_mask(spec.mask_path, (intr.h, intr.w))
    mask &= rv.alpha >= 0.5
    return roi_from_view_mask(mask, rv.depth, c2w, intr, name=spec.name,
                              source={"kind": spec.kind, "view": spec.view,
                                      "box": list(spec.box) if spec.box else None,
                                      "mask": str(spec.mask_path) if spec.mask_path else None})


def _lonlat_to_enu(spec: ROISpec, tm: TrainedModel) -> ROISpec:
    """The lon/lat polygon ``spec`` in the scene's ENU metres (its origin, brfgs.data.georef)."""
    mf = tm.map_frame
    if mf is None:
        src = (spec.source or {}).get("file")
        raise UserError("a lon/lat ROI needs a georeferenced scene (transforms.json 'origin'); give the polygon "
                        "in ENU metres instead", file=src, field="crs" if src else "--roi")
    h = mf.origin.altitude_m

    def conv(ring: np.ndarray) -> np.ndarray:
        return mf.lonlat_to_enu(np.c_[ring, np.full(len(ring), h)])[:, :2]

    polys = [[conv(r) for r in poly] for poly in spec.polygons]
    return replace(spec, polygon_xy_m=polys[0][0], polygons=polys, lonlat=False)


def resolve_roi(spec: ROISpec, tm: TrainedModel, scene: Scene | None = None, backend: str = "auto") -> ROI:
    """The ROI of ``spec`` for model ``tm``: a polygon (its height from the Gaussians inside), a
    view's box or mask (projected with the rendered depth of that view) or a simulated scene's
    material (``scene`` with its truth/ folder, seen from its near-nadir frames)."""
    if spec.kind == "polygon":
        if spec.lonlat:
            spec = _lonlat_to_enu(spec, tm)
        roi = PolygonROI(spec.polygon_xy_m, name=spec.name, polygons=spec.polygons, source=spec.source or {})
        means = tm.gaussians.means.detach().double().numpy()
        _check_polygon_over_model(roi, spec, means)
        roi.set_surface_height(means)
        return roi
    if spec.kind in ("box", "mask"):
        return _view_roi(spec, tm, backend)
    if scene is None or scene.truth_dir is None:
        raise UserError("a material ROI needs the simulated scene with its truth/ folder (pass --scene)",
                        field="--roi")
    frames = [f for f in scene.frames if f.view_zenith_deg <= 25.0] or scene.frames
    pts, fp = material_points(scene.truth_dir, spec.material, frames, scene.intrinsics)
    return PointSetROI(pts, tol_xy_m=1.5 * fp, tol_z_m=max(2.0, 4.0 * fp), name=spec.name,
                       source={"kind": "material", "material": spec.material, "frames": [f.name for f in frames]})
