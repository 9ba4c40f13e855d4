"""View geometry of the analysis: arbitrary cameras, hemisphere grids, principal plane, paths.

Angles follow docs/data-format.md: zenith from +z, azimuth clockwise from north of the
direction from the target toward the sensor (view) or the sun; relative azimuth
φ = φ_view − φ_sun, φ = 0 is backscatter; on the principal plane the signed view zenith
is positive on the sun's side.

Everything here is numpy and pure (no model needed).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.cameras import Intrinsics, look_at_c2w
from brfgs.errors import UserError

__all__ = [
    "MAX_VIEW_ZENITH_DEG",
    "check_zenith_deg",
    "check_azimuth_deg",
    "view_camera",
    "hemisphere_grid",
    "principal_plane_directions",
    "orbit_path",
    "zenith_sweep_path",
    "view_angles_from_points",
    "intrinsics_json",
]

MAX_VIEW_ZENITH_DEG = 89.0  # a camera must look at the ground from above the horizon


def _finite_deg(value, field: str, what: str) -> float:
    """``value`` as a finite float (degrees); UserError naming ``field`` otherwise."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UserError(f"expected a number of degrees, got {value!r}", field=field) from None
    if not math.isfinite(v):
        raise UserError(f"{what} must be a finite number of degrees, got {value!r}", field=field)
    return v


def check_zenith_deg(value: float, field: str, *, max_deg: float = MAX_VIEW_ZENITH_DEG) -> float:
    """Validated zenith angle in degrees: finite and in [0, max_deg]; UserError otherwise."""
    v = _finite_deg(value, field, "zenith angle")
    if v < 0.0 or v >= 90.0:
        raise UserError(f"zenith angle must be in [0, 90) degrees (0 = nadir view / sun overhead), got {v:g}",
                        field=field)
    if v > max_deg:
        raise UserError(f"zenith angle {v:g}° is too close to the horizon; the maximum is {max_deg:g}°",
                        field=field)
    return v


def check_azimuth_deg(value: float, field: str) -> float:
    """Validated azimuth in degrees (finite; wrapped to [0, 360))."""
    return _finite_deg(value, field, "azimuth") % 360.0


def view_camera(view_zenith_deg: float, view_azimuth_deg: float, distance_m: float,
                target_m: ArrayLike | None = None, *, size: int | tuple[int, int] = 128, fov_deg: float | None = None,
                half_extent_m: float | None = None) -> tuple[np.ndarray, Intrinsics]:
    """Pinhole camera looking at ``target_m`` [3] from the direction (zenith, azimuth).

    Either ``fov_deg`` (horizontal field of view) or ``half_extent_m`` (radius in metres
    around the target that must fit in the image: fov = 2·atan(half_extent / distance))
    gives the field of view. ``size`` is W (square) or (W, H).
    Returns (c2w OpenGL [4, 4], Intrinsics).
    """
    check_zenith_deg(view_zenith_deg, "view_zenith_deg")
    check_azimuth_deg(view_azimuth_deg, "view_azimuth_deg")
    if not (math.isfinite(float(distance_m)) and distance_m > 0):
        raise UserError(f"camera distance must be a positive number of metres, got {distance_m!r}", field="distance")
    w, h = (int(size), int(size)) if np.isscalar(size) else (int(size[0]), int(size[1]))
    if w < 1 or h < 1 or w > 8192 or h > 8192:
        raise UserError(f"image size must be 1..8192 pixels, got {w}x{h}", field="size")
    if fov_deg is None:
        if half_extent_m is None:
            raise ValueError("view_camera needs fov_deg or half_extent_m")
        fov_deg = 2.0 * math.degrees(math.atan(float(half_extent_m) / float(distance_m)))
    if not (math.isfinite(float(fov_deg)) and 0.01 < fov_deg < 170.0):
        raise UserError(f"field of view must be in (0.01, 170) degrees, got {fov_deg!r}", field="fov")
    target = np.zeros(3) if target_m is None else np.asarray(target_m, float).reshape(3)
    eye = target + float(distance_m) * direction_from_angles_deg(view_zenith_deg, view_azimuth_deg)
    c2w = look_at_c2w(eye, target)
    return c2w, Intrinsics.from_fov(float(fov_deg), w, h)


def hemisphere_grid(n_azimuth: int = 60, n_zenith: int = 24, max_zenith_deg: float = 75.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres of a polar grid over the view hemisphere.

    Returns (zenith_deg [n_zenith], azimuth_deg [n_azimuth]): zeniths at the centres of
    ``n_zenith`` equal rings in [0, max_zenith_deg], azimuths at the centres of equal
    sectors of [0, 360) (relative or absolute, as the caller uses them).
    """
    if n_azimuth < 1 or n_zenith < 1:
        raise UserError("polar grid needs at least one azimuth and one zenith", field="grid")
    dz = max_zenith_deg / n_zenith
    da = 360.0 / n_azimuth
    return (np.arange(n_zenith) + 0.5) * dz, (np.arange(n_azimuth) + 0.5) * da


def principal_plane_directions(signed_zenith_deg: ArrayLike,  # [n] deg
                               sun_azimuth_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(view_zenith_deg [n], view_azimuth_deg [n]) for signed zeniths on the principal plane.

    Positive signed zenith: the sensor on the sun's side (azimuth = sun azimuth, backscatter);
    negative: forward-scatter side (azimuth = sun azimuth + 180°). Zero is nadir.
    """
    s = np.asarray(signed_zenith_deg, float)
    az = np.where(s >= 0, sun_azimuth_deg, sun_azimuth_deg + 180.0) % 360.0
    return np.abs(s), az


def orbit_path(view_zenith_deg: float, n_frames: int = 36, start_azimuth_deg: float = 0.0
               ) -> list[tuple[float, float]]:
    """(zenith, azimuth) of an orbit at constant zenith, ``n_frames`` azimuths over 360°."""
    check_zenith_deg(view_zenith_deg, "view_zenith_deg")
    if n_frames < 1:
        raise UserError("a path needs at least one frame", field="frames")
    return [(float(view_zenith_deg), (start_azimuth_deg + 360.0 * k / n_frames) % 360.0) for k in range(n_frames)]


def zenith_sweep_path(view_azimuth_deg: float, max_zenith_deg: float = 60.0, n_frames: int = 25
                      ) -> list[tuple[float, float]]:
    """(zenith, azimuth) of a sweep through nadir in the vertical plane of ``view_azimuth_deg``.

    Signed zenith goes from −max (opposite azimuth) to +max (at ``view_azimuth_deg``).
    """
    check_zenith_deg(max_zenith_deg, "max_zenith_deg")
    if n_frames < 2:
        raise UserError("a sweep needs at least two frames", field="frames")
    s = np.linspace(-max_zenith_deg, max_zenith_deg, n_frames)
    zen, az = principal_plane_directions(s, view_azimuth_deg)
    return [(float(z), float(a)) for z, a in zip(zen, az)]


def view_angles_from_points(camera_centre_m: ArrayLike, target_m: ArrayLike) -> tuple[float, float]:
    """(zenith_deg, azimuth_deg) of the direction from ``target_m`` [3] toward ``camera_centre_m`` [3]."""
    d = np.asarray(camera_centre_m, float) - np.asarray(target_m, float)
    n = float(np.linalg.norm(d))
    if n == 0:
        return 0.0, 0.0
    zen = math.degrees(math.acos(max(-1.0, min(1.0, d[2] / n))))
    az = math.degrees(math.atan2(d[0], d[1])) % 360.0
    return zen, az


def intrinsics_json(intr: Intrinsics) -> dict:
    """The pinhole intrinsics as a JSON object (fl_x, fl_y, cx, cy in px; w, h)."""
    return {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h}
