"""Ground polygons: point-in-polygon tests and polygons read from GeoJSON files.

Coordinates are the scene's local ENU metres (x east, y north). A polygon is a list of rings
[V, 2], the exterior first, then its holes (GeoJSON layout); an ROI may be the union of several.

GeoJSON files (:func:`read_geojson_polygons`): a Polygon or MultiPolygon geometry, a Feature
holding one, or a FeatureCollection / GeometryCollection of them (their union); coordinates
(x, y[, z ignored]) in the scene's local ENU metres, NOT longitude/latitude; a ``crs`` member
other than a local/ENU one is refused.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from brfgs.data.validation import finite_number, plain_text, read_json_file
from brfgs.errors import UserError

__all__ = ["points_in_polygon", "points_in_polygons", "ring_area", "GEOJSON_SUFFIXES", "read_geojson_polygons",
           "is_lonlat_crs"]


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


def points_in_polygons(xy: np.ndarray, polygons: list[list[np.ndarray]]) -> np.ndarray:
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


GEOJSON_SUFFIXES = (".geojson", ".json")
# |x|, |y| of an ROI vertex: ENU metres (or lon/lat degrees). No polygon beyond 10,000 km can lie over a
# scene (its cameras are within 100 km of the origin), and areas of larger coordinates overflow.
MAX_COORDINATE = 1.0e7
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


def is_lonlat_crs(crs) -> bool:
    """True for a GeoJSON ``crs`` member naming WGS 84 longitude/latitude (OGC CRS84, EPSG:4326/4979)."""
    if not isinstance(crs, dict) or crs.get("type") != "name" or not isinstance(crs.get("properties"), dict):
        return False
    name = str(crs["properties"].get("name", "")).upper().replace("::", ":")
    return name.endswith(("CRS84", "EPSG:4326", "EPSG:4979")) or name in ("WGS84", "WGS 84")


def _check_crs(obj: dict, path: Path, where: str) -> None:
    if "crs" in obj and not _is_local_crs(obj["crs"]) and not is_lonlat_crs(obj["crs"]):
        raise UserError(f"coordinate reference system {_short(obj['crs'])} is not supported: the scene frame is "
                        "local ENU metres (x east, y north, around the scene centre), so the polygon must be "
                        "given in it; transform the coordinates into that frame and remove the 'crs' member "
                        "(or name a local one, e.g. {\"type\": \"name\", \"properties\": {\"name\": \"local-ENU\"}})",
                        file=path, field=f"{where}crs" if where else "crs")


def _short(value) -> str:
    """A JSON value for a message: at most 80 characters (a hostile value may be huge)."""
    try:
        text = json.dumps(value)
    except (ValueError, RecursionError):
        text = repr(type(value))
    return text if len(text) <= 80 else text[:77] + "..."


def _geojson_ring(ring, path: Path, where: str) -> np.ndarray:
    if not isinstance(ring, list):
        raise UserError("a linear ring must be a list of positions [x, y]", file=path, field=where)
    pts = []
    for k, pos in enumerate(ring):
        if (not isinstance(pos, list) or not 2 <= len(pos) <= 3
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in pos)):
            raise UserError(f"a position must be [x, y] or [x, y, z] numbers (ENU metres), got {_short(pos)}",
                            file=path, field=f"{where}[{k}]")
        xy = [finite_number(c) for c in pos[:2]]
        if None in xy:
            raise UserError(f"non-finite or out-of-range coordinate {_short(pos)}", file=path, field=f"{where}[{k}]")
        if max(abs(xy[0]), abs(xy[1])) > MAX_COORDINATE:
            raise UserError(f"coordinate {_short(pos)} out of range: ROI coordinates are the scene's ENU metres (or "
                            f"lon/lat degrees), at most {MAX_COORDINATE:.0e} in size", file=path,
                            field=f"{where}[{k}]")
        pts.append((xy[0], xy[1]))
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
    coordinate is ignored), unless the top-level ``crs`` names WGS 84 longitude/latitude (OGC
    CRS84, EPSG:4326) or the ROI is given as ``lonlat:PATH``: then they are (lon, lat) degrees,
    converted with the scene's origin when the ROI is resolved (:func:`is_lonlat_crs`). A ``crs``
    member must otherwise be null or name a local/ENU frame (e.g. ``"local-ENU"``); any other CRS
    is refused. ``name`` is ``properties.name`` of the only
    Feature, if any. Every problem raises UserError naming the file and the JSON field.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError("ROI GeoJSON file not found", file=path, field="--roi")
    data = read_json_file(path, "GeoJSON file")
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
            name, where = feats[0]["properties"].get("name"), "features[0].properties.name"
    elif t == "Feature":
        if data.get("geometry") is None:
            raise UserError("the Feature has no geometry", file=path, field="geometry")
        polys = _geojson_geometry(data["geometry"], path, "geometry.")
        if isinstance(data.get("properties"), dict):
            name, where = data["properties"].get("name"), "properties.name"
    else:
        polys = _geojson_geometry(data, path, "")
    if name in (None, ""):
        return polys, None
    return polys, plain_text(name if isinstance(name, str) else json.dumps(name)[:200], path, where)
