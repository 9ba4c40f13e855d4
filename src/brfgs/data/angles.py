"""Angle conventions of docs/data-format.md.

Zenith θ from +z; azimuth φ clockwise from north (+y) toward east (+x), of the
direction from the target toward the sun or the sensor. Unit vector
``d = (sin θ sin φ, sin θ cos φ, cos θ)``. Relative azimuth for the kernels is
``φ_view − φ_sun`` wrapped to [0°, 360°); φ = 0 is backscatter (hotspot side).

Functions accept numpy arrays or torch tensors (anything with ``sin``/``cos`` via
the matching module) and keep the input's type.
"""

from __future__ import annotations

import math
import sys

import numpy as np


def _xp(x):
    """Array module (numpy or torch) for ``x``.

    A torch tensor means torch is loaded: it is taken from ``sys.modules``, so ``brfgs.data`` itself
    never imports torch (reading scenes stays light).
    """
    if type(x).__module__.startswith("torch"):
        return sys.modules["torch"]
    return np


def direction_from_angles(zenith_rad, azimuth_rad):
    """Unit vector(s) [..., 3] (ENU) for zenith/azimuth in radians, shapes broadcast."""
    xp = _xp(zenith_rad) if not isinstance(zenith_rad, (int, float)) else _xp(azimuth_rad)
    if xp is np:
        zenith_rad = np.asarray(zenith_rad, dtype=float)
        azimuth_rad = np.asarray(azimuth_rad, dtype=float)
    st = xp.sin(zenith_rad)
    return xp.stack([st * xp.sin(azimuth_rad), st * xp.cos(azimuth_rad), xp.cos(zenith_rad) + 0 * azimuth_rad], -1)


def direction_from_angles_deg(zenith_deg, azimuth_deg):
    """Unit vector(s) [..., 3] (ENU) for zenith/azimuth in degrees."""
    return direction_from_angles(np.deg2rad(np.asarray(zenith_deg, float)), np.deg2rad(np.asarray(azimuth_deg, float)))


def angles_from_direction(d):
    """(zenith_rad, azimuth_rad) of direction(s) d [..., 3]; azimuth in [0, 2π).

    d need not be normalised. Azimuth of a vertical direction is 0.
    """
    xp = _xp(d)
    norm = xp.sqrt((d * d).sum(-1))
    cz = xp.clip(d[..., 2] / norm, -1.0, 1.0)
    zenith = xp.arccos(cz)
    az = xp.arctan2(d[..., 0], d[..., 1])
    az = xp.remainder(az, 2 * math.pi)
    return zenith, az


def relative_azimuth_deg(view_azimuth_deg, sun_azimuth_deg):
    """φ = φ_view − φ_sun wrapped to [0, 360) degrees; 0 = backscatter."""
    return np.remainder(np.asarray(view_azimuth_deg, float) - np.asarray(sun_azimuth_deg, float), 360.0)


def signed_principal_plane_zenith_deg(view_zenith_deg, relative_azimuth_deg_):
    """Signed view zenith on the principal plane: + on the sun's side (φ≈0), − forward (φ≈180)."""
    phi = np.remainder(np.asarray(relative_azimuth_deg_, float), 360.0)
    sign = np.where(np.cos(np.deg2rad(phi)) >= 0, 1.0, -1.0)
    return sign * np.asarray(view_zenith_deg, float)
