"""Georeferencing: the scene's ENU frame on the Earth (pyproj), and north-up map grids for products.

A scene may give its ``origin`` in ``transforms.json``::

    "origin": {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0},   # WGS 84, ellipsoidal height
    "crs": "EPSG:32632"                                                            # optional map CRS

The scene's frame (x east, y north, z up, metres; docs/data-format.md) is then the local tangent plane
(topocentric ENU) at that point of the WGS 84 ellipsoid. Map products are written in ``crs``, by
default the UTM zone of the origin (WGS 84 / UTM, EPSG 326zz north, 327zz south).

ENU ↔ geodetic uses PROJ's ``topocentric`` and ``cart`` operations (pyproj); geodetic ↔ map CRS a
pyproj ``Transformer``. Over a flight's extent the ENU → map mapping is affine to well below a
millimetre (checked in :func:`enu_to_map_affine`): products are rendered on a nadir grid rotated by
the grid convergence so that their rows run along map east and columns along map north.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from brfgs.errors import UserError

__all__ = ["Origin", "read_georef", "default_crs", "MapFrame", "origin_distance_m", "check_same_origin"]


@dataclass(frozen=True)
class Origin:
    """The ENU frame's origin: WGS 84 latitude/longitude (deg) and ellipsoidal height (m)."""

    latitude_deg: float
    longitude_deg: float
    altitude_m: float = 0.0

    def to_json(self) -> dict:
        return {"latitude_deg": self.latitude_deg, "longitude_deg": self.longitude_deg, "altitude_m": self.altitude_m}


def origin_distance_m(a: dict, b: dict) -> float:
    """Distance (m) between two origins given as JSON objects (latitude_deg, longitude_deg, altitude_m):
    the local tangent-plane approximation, exact to < 1 mm over the metres that co-registration checks."""
    lat = math.radians(float(a["latitude_deg"]))
    north = 6378137.0 * math.radians(float(b["latitude_deg"]) - float(a["latitude_deg"]))
    east = 6378137.0 * math.cos(lat) * math.radians(float(b["longitude_deg"]) - float(a["longitude_deg"]))
    up = float(b.get("altitude_m", 0.0) or 0.0) - float(a.get("altitude_m", 0.0) or 0.0)
    return math.sqrt(north * north + east * east + up * up)


def check_same_origin(reference: dict | None, other: dict | None, tf: Path | None, tolerance_m: float = 0.01) -> None:
    """Co-registered scenes: both without an origin, or both at the same origin (within ``tolerance_m``);
    UserError naming ``tf``'s ``origin`` otherwise."""
    if (reference is None) != (other is None):
        raise UserError("only one of the scenes is georeferenced: co-registered flights share one ENU origin",
                        file=tf, field="origin")
    if reference is not None and origin_distance_m(reference, other) > tolerance_m:
        raise UserError(f"the origin is {origin_distance_m(reference, other):.2f} m from the reference scene's: "
                        "co-registered flights share one ENU origin", file=tf, field="origin")


def _number(v, tf: Path | None, field: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)) or not lo <= v <= hi:
        raise UserError(f"expected a number in [{lo:g}, {hi:g}], got {v!r}", file=tf, field=field)
    return float(v)


def read_georef(meta: dict, tf: Path | None = None) -> tuple[Origin | None, str | None]:
    """(origin, CRS as 'AUTHORITY:CODE' or WKT) from a ``transforms.json`` dict or a model's scene
    description; (None, None) without an origin. UserError naming the field for bad values."""
    o = meta.get("origin")
    if o is None:
        if meta.get("crs") is not None:
            raise UserError("a map CRS needs the scene's 'origin' (latitude_deg, longitude_deg)", file=tf, field="crs")
        return None, None
    if not isinstance(o, dict):
        raise UserError(f"expected an object with latitude_deg, longitude_deg, altitude_m, got {o!r}", file=tf,
                        field="origin")
    unknown = set(o) - {"latitude_deg", "longitude_deg", "altitude_m"}
    if unknown:
        raise UserError(f"unknown keys {sorted(unknown)} (expected latitude_deg, longitude_deg, altitude_m)",
                        file=tf, field="origin")
    for k in ("latitude_deg", "longitude_deg"):
        if k not in o:
            raise UserError("missing", file=tf, field=f"origin.{k}")
    origin = Origin(_number(o["latitude_deg"], tf, "origin.latitude_deg", -89.9, 89.9),
                    _number(o["longitude_deg"], tf, "origin.longitude_deg", -180.0, 180.0),
                    _number(o.get("altitude_m", 0.0), tf, "origin.altitude_m", -1000.0, 20000.0))
    crs = meta.get("crs")
    if crs is None:
        return origin, None
    from pyproj import CRS  # lazy: only georeferenced scenes and products need PROJ (pyproj)
    from pyproj.exceptions import CRSError  # lazy: as CRS

    try:
        parsed = CRS.from_user_input(crs) if isinstance(crs, str) else None
    except CRSError as exc:
        raise UserError(f"not a coordinate reference system PROJ knows ({exc})", file=tf, field="crs") from None
    if parsed is None or not parsed.is_projected:
        raise UserError(f"expected a projected CRS in metres such as 'EPSG:32632', got {crs!r}", file=tf, field="crs")
    return origin, crs


def default_crs(origin: Origin) -> str:
    """'EPSG:326zz' / 'EPSG:327zz': the WGS 84 / UTM zone of the origin (pyproj's database)."""
    from pyproj.aoi import AreaOfInterest  # lazy: as in read_georef
    from pyproj.database import query_utm_crs_info  # lazy: as in read_georef

    lon, lat = origin.longitude_deg, origin.latitude_deg
    info = query_utm_crs_info(datum_name="WGS 84", area_of_interest=AreaOfInterest(lon, lat, lon, lat))
    north = [i for i in info if (i.code.startswith("326") if lat >= 0 else i.code.startswith("327"))]
    best = (north or info)[0]
    return f"{best.auth_name}:{best.code}"


@dataclass(frozen=True)
class MapFrame:
    """ENU (scene metres) ↔ lon/lat ↔ map coordinates of one origin and CRS."""

    origin: Origin
    crs: str

    @cached_property
    def _enu(self):
        from pyproj import Transformer  # lazy: as in read_georef

        o = self.origin
        return Transformer.from_pipeline(
            "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=cart +ellps=WGS84 "
            f"+step +proj=topocentric +ellps=WGS84 +lat_0={o.latitude_deg!r} +lon_0={o.longitude_deg!r} "
            f"+h_0={o.altitude_m!r}")

    @cached_property
    def _map(self):
        from pyproj import Transformer  # lazy: as in read_georef

        return Transformer.from_crs("EPSG:4979", self.crs, always_xy=True)

    def enu_to_lonlat(self, xyz_m: ArrayLike) -> np.ndarray:  # [N, 3] m -> [N, 3] (lon deg, lat deg, h m)
        p = np.atleast_2d(np.asarray(xyz_m, float))
        lon, lat, h = self._enu.transform(p[:, 0], p[:, 1], p[:, 2], direction="INVERSE")
        return np.stack([lon, lat, h], 1)

    def lonlat_to_enu(self, lonlath: ArrayLike) -> np.ndarray:  # [N, 3] (lon deg, lat deg, h m) -> [N, 3] m
        p = np.atleast_2d(np.asarray(lonlath, float))
        x, y, z = self._enu.transform(p[:, 0], p[:, 1], p[:, 2])
        return np.stack([x, y, z], 1)

    def lonlat_to_map(self, lonlat: ArrayLike) -> np.ndarray:  # [N, 2+] -> [N, 2] map metres
        p = np.atleast_2d(np.asarray(lonlat, float))
        e, n = self._map.transform(p[:, 0], p[:, 1])
        return np.stack([e, n], 1)

    def enu_to_map(self, xyz_m: ArrayLike) -> np.ndarray:  # [N, 3] -> [N, 2]
        return self.lonlat_to_map(self.enu_to_lonlat(xyz_m))

    def enu_to_map_affine(self, centre_m: ArrayLike, half_extent_m: float) -> tuple[np.ndarray, float]:
        """(A [2, 3], max residual m): map ≈ A @ (x, y, 1) over the square ``centre ± half_extent``
        at the centre's height, fitted on a 9 × 9 grid."""
        c = np.asarray(centre_m, float).reshape(3)
        g = np.linspace(-half_extent_m, half_extent_m, 9)
        gx, gy = np.meshgrid(g, g)
        pts = np.stack([c[0] + gx.ravel(), c[1] + gy.ravel(), np.full(gx.size, c[2])], 1)
        m = self.enu_to_map(pts)
        design = np.c_[pts[:, :2], np.ones(len(pts))]
        a, *_ = np.linalg.lstsq(design, m, rcond=None)                   # [3, 2]
        return a.T, float(np.abs(design @ a - m).max())

    def north_azimuth_deg(self, centre_m: ArrayLike, half_extent_m: float) -> tuple[float, float]:
        """(azimuth in ENU of the map's +northing axis, clockwise from ENU north (deg); map metres per
        ENU metre): the grid convergence and scale factor at the centre."""
        a, _ = self.enu_to_map_affine(centre_m, half_extent_m)
        inv = np.linalg.inv(a[:, :2])                                      # map → ENU (linear part)
        d_north = inv[:, 1]                                               # ENU vector of +1 m northing
        return math.degrees(math.atan2(d_north[0], d_north[1])), 1.0 / float(np.linalg.norm(d_north))
