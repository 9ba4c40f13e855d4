"""Georeferenced map products: a north-up nadir grid in the scene's map CRS, Cloud-Optimized GeoTIFF
(rasterio) and ENVI ``map info``.

:func:`map_camera` turns the products' nadir camera about the vertical so that image rows run along
map east and columns along map north (the grid convergence of :meth:`MapFrame.north_azimuth_deg`),
and :func:`map_grid` gives the affine geotransform of its pixels at the reference height (the
camera's target): pixel (col, row) corner ↦ (E0 + col·p, N0 − row·p), p = ground sampling × the
CRS's scale factor. Points above or below the reference height are displaced radially by their
height × (distance from the centre / camera distance) (a near-orthographic camera keeps this small).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
from pyproj import CRS
from pyproj.enums import WktVersion
from rasterio.transform import Affine

from brfgs.data import atomic
from brfgs.data.cameras import Intrinsics
from brfgs.data.georef import MapFrame

__all__ = ["MapGrid", "map_camera", "map_grid", "write_geotiff", "envi_map_info"]


@dataclass(frozen=True)
class MapGrid:
    """A north-up raster grid: CRS, pixel size (map units) and upper-left corner (map units)."""

    crs: str
    pixel_size: float
    upper_left: tuple[float, float]
    width: int
    height: int
    max_affine_residual_m: float

    @property
    def transform(self) -> tuple[float, ...]:
        """GDAL geotransform (E0, p, 0, N0, 0, −p)."""
        return (self.upper_left[0], self.pixel_size, 0.0, self.upper_left[1], 0.0, -self.pixel_size)

    def describe(self, mf: MapFrame) -> dict:
        return {"crs": self.crs, "geotransform": list(self.transform), "width": self.width, "height": self.height,
                "origin": mf.origin.to_json(), "max_affine_residual_m": self.max_affine_residual_m}


def map_camera(mf: MapFrame, c2w: np.ndarray, half_extent_m: float) -> np.ndarray:
    """The nadir camera ``c2w`` [4, 4] (looking straight down, image up = ENU north) turned about
    the vertical through its position so that image up is map north; returns the new c2w."""
    az, _ = mf.north_azimuth_deg(c2w[:3, 3], half_extent_m)
    t = math.radians(-az)                                   # rotate +y (north) clockwise by az
    rz = np.array([[math.cos(t), -math.sin(t), 0.0], [math.sin(t), math.cos(t), 0.0], [0.0, 0.0, 1.0]])
    out = np.array(c2w, float)
    out[:3, :3] = rz @ out[:3, :3]
    return out


def map_grid(mf: MapFrame, c2w: np.ndarray, intr: Intrinsics, target_m: np.ndarray) -> MapGrid:
    """The geotransform of a :func:`map_camera` image at the height of ``target_m`` [3]."""
    eye = np.asarray(c2w[:3, 3], float)
    dist = float(np.linalg.norm(eye - target_m))
    gsd = dist / intr.fl_x                                  # metres per pixel at the target
    x_dir, y_dir = c2w[:3, 0], c2w[:3, 1]                   # image right, image up (OpenGL camera axes)
    centre = eye + (np.asarray(target_m, float)[2] - eye[2]) * np.array([0.0, 0.0, 1.0])
    corner = centre - intr.cx * gsd * x_dir + intr.cy * gsd * y_dir
    half = 0.5 * gsd * max(intr.w, intr.h)
    _, resid = mf.enu_to_map_affine(centre, half)
    _, scale = mf.north_azimuth_deg(centre, half)
    e0, n0 = mf.enu_to_map(corner[None])[0]
    return MapGrid(crs=mf.crs, pixel_size=gsd * scale, upper_left=(float(e0), float(n0)), width=intr.w,
                   height=intr.h, max_affine_residual_m=resid)


def write_geotiff(path: Path, cube: np.ndarray, grid: MapGrid, wavelengths_nm: np.ndarray | None,
                  description: str) -> Path:
    """``cube`` [H, W, B] as a float32 Cloud-Optimized GeoTIFF (deflate, NaN = no data) with the
    grid's CRS and geotransform; band descriptions "<wavelength> nm"."""
    cube = np.asarray(cube, np.float32)
    if cube.ndim == 2:
        cube = cube[..., None]
    h, w, b = cube.shape
    with atomic.atomic_path(path) as tmp:
        with rasterio.open(tmp, "w", driver="COG", width=w, height=h, count=b, dtype="float32", crs=grid.crs,
                           transform=Affine.from_gdal(*grid.transform), nodata=float("nan"), compress="deflate") as ds:
            ds.write(np.moveaxis(cube, -1, 0))
            ds.update_tags(DESCRIPTION=description, SOFTWARE="brfgs")
            if wavelengths_nm is not None and len(wavelengths_nm) == b:
                for i, wl in enumerate(wavelengths_nm):
                    ds.set_band_description(i + 1, f"{float(wl):.1f} nm")
    return path


WGS84_DATUM = "World Geodetic System 1984"  # PROJ 9.x names it "World Geodetic System 1984 ensemble"


def utm_zone_of(crs) -> tuple[int, str] | None:
    """(zone, "North" | "South") of a WGS 84 UTM CRS, else None: from its EPSG code (326zz / 327zz) when
    it has one, else from its UTM zone and a datum whose name starts with WGS 84's, whatever suffix a
    PROJ version gives it."""
    epsg = crs.to_epsg()
    if epsg is not None and (32601 <= epsg <= 32660 or 32701 <= epsg <= 32760):
        return epsg % 100, "North" if epsg < 32700 else "South"
    utm = crs.utm_zone
    if utm and crs.datum is not None and crs.datum.name.startswith(WGS84_DATUM):
        return int(utm[:-1]), "North" if utm[-1].upper() == "N" else "South"
    return None


def envi_map_info(grid: MapGrid) -> dict:
    """ENVI header fields ``map info`` (UTM with its zone and hemisphere for a WGS 84 UTM CRS, else
    Arbitrary) and ``coordinate system string`` (ESRI WKT) for the grid."""
    crs = CRS.from_user_input(grid.crs)
    e0, n0 = grid.upper_left
    p = f"{grid.pixel_size:.10g}"
    utm = utm_zone_of(crs)
    if utm is not None:
        info = ["UTM", "1", "1", f"{e0:.4f}", f"{n0:.4f}", p, p, str(utm[0]), utm[1], "WGS-84", "units=Meters"]
    else:
        info = ["Arbitrary", "1", "1", f"{e0:.4f}", f"{n0:.4f}", p, p, "0", "units=Meters"]
    return {"map info": info, "coordinate system string": "{" + crs.to_wkt(WktVersion.WKT1_ESRI) + "}"}
