"""The diffuse (sky) share of the downwelling irradiance, per band.

Under a clear sky the downwelling irradiance E = E_direct + E_diffuse; the diffuse fraction
f_b = E_diffuse / E in band b sets how dark a cast shadow is (only the sky lights it: ρ f_b
instead of ρ). A scene gives it in ``transforms.json`` as ``diffuse_fraction`` (one number for
every band, or one per band: a diffuse/global irradiance sensor or a radiative-transfer run), and a
frame may give its own (``frames[k].diffuse_fraction``: flights flown at other hours, merged into one
scene, keep each its sky); without it the clear-sky default :func:`clear_sky_diffuse_fraction` applies.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from brfgs.data import validation as V

__all__ = ["clear_sky_diffuse_fraction", "read_diffuse_fraction", "diffuse_fraction_value", "MAX_DIFFUSE_FRACTION"]

MAX_DIFFUSE_FRACTION = 0.9    # above this a "shadow" is no darker than the light: the split means nothing


def clear_sky_diffuse_fraction(wavelengths_nm: np.ndarray) -> np.ndarray:  # [B] in [0, 0.9]
    """Clear-sky diffuse fraction [B] at mid sun elevations: 0.1 (550/λ)^2.5 (a Rayleigh-like power
    law: 0.31 at 350 nm, 0.17 at 450 nm, 0.1 at 550 nm, 0.034 at 850 nm), clipped to [0, 0.9]."""
    lam = np.asarray(wavelengths_nm, float)
    return np.clip(0.1 * (550.0 / lam) ** 2.5, 0.0, MAX_DIFFUSE_FRACTION)


def read_diffuse_fraction(meta: dict, tf: Path, wavelengths_nm: np.ndarray) -> tuple[np.ndarray, str]:
    """The scene's diffuse fraction [B] (one per band of the file) and its source ("transforms.json"
    or "clear-sky default"); UserError naming ``diffuse_fraction`` when it is not a number or a list
    of one number per band in [0, 0.9]."""
    value = meta.get("diffuse_fraction")
    if value is None:
        return clear_sky_diffuse_fraction(wavelengths_nm), "clear-sky default"
    return diffuse_fraction_value(value, tf, "diffuse_fraction", len(wavelengths_nm)), "transforms.json"


def diffuse_fraction_value(value, tf: Path, field: str, n_bands: int) -> np.ndarray:  # [n_bands] float64
    """A ``diffuse_fraction`` field's value (``field`` names it in errors, e.g. ``frames[3].diffuse_fraction``):
    one number for every band or one per band, each in [0, 0.9]."""
    if isinstance(value, (list, tuple)):
        f = V.number_list(value, tf, field, length=n_bands)
        for i, v in enumerate(f):
            V.number(float(v), tf, f"{field}[{i}]", lo=0.0, hi=MAX_DIFFUSE_FRACTION)
    else:
        f = np.full(n_bands, V.number(value, tf, field, lo=0.0, hi=MAX_DIFFUSE_FRACTION))
    return f.astype(np.float64)
