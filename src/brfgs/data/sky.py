"""The diffuse (sky) share of the downwelling irradiance, per band.

Under a clear sky the downwelling irradiance E = E_direct + E_diffuse; the diffuse fraction
f_b = E_diffuse / E in band b sets how dark a cast shadow is (only the sky lights it: ρ f_b
instead of ρ). A scene gives it in ``transforms.json`` as ``diffuse_fraction`` (one number for
every band, or one per band: a diffuse/global irradiance sensor or a radiative-transfer run), and a
frame may give its own (``frames[k].diffuse_fraction``: flights flown at other hours, merged into one
scene, keep each its sky). Without it the clear-sky default :func:`clear_sky_diffuse_fraction`
applies, at each frame's own sun: the sky's share grows as the sun sinks (a longer path through the
atmosphere scatters more of the direct beam).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from brfgs.data import validation as V

__all__ = ["clear_sky_diffuse_fraction", "read_diffuse_fraction", "read_frame_diffuse_fraction", "diffuse_fraction_value",
           "MAX_DIFFUSE_FRACTION", "CLEAR_SKY"]

MAX_DIFFUSE_FRACTION = 0.9    # above this a "shadow" is no darker than the light: the split means nothing
MAX_SKY_ZENITH_DEG = 85.0     # the default's sun zenith is clipped here (SPECTRL2's air mass diverges at 90°)
# The default clear atmosphere of SPECTRL2 (Bird & Riordan 1986): rural aerosol of optical depth 0.1 at
# 500 nm, 1.42 cm precipitable water and 0.344 atm-cm ozone (the US standard atmosphere's).
CLEAR_SKY = {"aerosol_turbidity_500nm": 0.1, "precipitable_water": 1.42, "ozone": 0.344}


def clear_sky_diffuse_fraction(wavelengths_nm: np.ndarray, sun_zenith_deg: float,
                               altitude_m: float = 0.0) -> np.ndarray:  # [B] in [0, 0.9]
    """Clear-sky diffuse fraction [B] on a horizontal surface for the sun at ``sun_zenith_deg`` (deg,
    clipped to 85°): DHI / (DNI cos θ_s + DHI) of Bird & Riordan's SPECTRL2 spectral model (pvlib) in
    :data:`CLEAR_SKY`'s atmosphere at the pressure of ``altitude_m`` (m), interpolated to the band
    centres and clipped to [0, 0.9]. About 0.25 at 450 nm, 0.15 at 550 nm and 0.06 at 860 nm with the
    sun at 35°; 0.32, 0.20 and 0.08 at 55°."""
    z = round(float(np.clip(sun_zenith_deg, 0.0, MAX_SKY_ZENITH_DEG)), 4)
    wl_grid, frac = _spectrl2_fraction(z, round(float(altitude_m), 1))
    out = np.interp(np.asarray(wavelengths_nm, float), wl_grid, frac)
    return np.clip(out, 0.0, MAX_DIFFUSE_FRACTION)


@lru_cache(maxsize=256)
def _spectrl2_fraction(sun_zenith_deg: float, altitude_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths [W] nm, diffuse fraction [W]) of SPECTRL2 for a horizontal surface."""
    import pvlib  # lazy: pvlib and pandas take ~0.6 s to import

    am = float(pvlib.atmosphere.get_relative_airmass(sun_zenith_deg))
    r = pvlib.spectrum.spectrl2(apparent_zenith=sun_zenith_deg, aoi=sun_zenith_deg, surface_tilt=0.0,
                                ground_albedo=0.2, surface_pressure=float(pvlib.atmosphere.alt2pres(altitude_m)),
                                relative_airmass=am, dayofyear=172, **CLEAR_SKY)
    dni, dhi = np.ravel(r["dni"]), np.ravel(r["dhi"])
    glob = dni * np.cos(np.radians(sun_zenith_deg)) + dhi
    return np.asarray(r["wavelength"], float), np.where(glob > 0, dhi / np.maximum(glob, 1e-30), 1.0)


def read_diffuse_fraction(meta: dict, tf: Path, wavelengths_nm: np.ndarray, sun_zenith_deg: float,
                          altitude_m: float = 0.0) -> tuple[np.ndarray, str]:
    """The scene's diffuse fraction [B] (one per band of the file) and its source ("transforms.json"
    or "clear-sky default", then at the sun ``sun_zenith_deg`` and ``altitude_m``); UserError naming
    ``diffuse_fraction`` when it is not a number or a list of one number per band in [0, 0.9]."""
    value = meta.get("diffuse_fraction")
    if value is None:
        return clear_sky_diffuse_fraction(wavelengths_nm, sun_zenith_deg, altitude_m), "clear-sky default"
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


def read_frame_diffuse_fraction(frame: dict, k: int, tf: Path, n_bands: int, band_idx) -> np.ndarray | None:
    """Frame ``k``'s own diffuse fraction in the bands ``band_idx`` (of the file's ``n_bands``), or None;
    UserError naming ``frames[k].diffuse_fraction`` when it is malformed."""
    value = frame.get("diffuse_fraction")
    if value is None:
        return None
    return diffuse_fraction_value(value, tf, f"frames[{k}].diffuse_fraction", n_bands)[band_idx]
