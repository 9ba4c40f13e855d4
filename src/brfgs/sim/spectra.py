"""Spectra of the simulated scenes: materials, illumination and sensor noise.

All spectra are first built on a 1 nm grid from 350 to 1000 nm (``GRID_NM``) and then
integrated over each sensor band with a Gaussian spectral response of width ``fwhm_nm``
(:func:`band_average`).

Sources
-------
* Leaves, needles, straw: PROSPECT-D (``prosail.run_prospect``, Féret et al. 2017),
  400–2500 nm. Below 400 nm (outside PROSPECT's range) leaf reflectance is held at its
  400 nm value (UV reflectance of leaves is flat and low, ~4–6 %) and transmittance decays
  to zero with a 15 nm e-folding length (epidermal UV screening).
* Grass and dry-grass ground covers: SAIL bi-hemispherical reflectance (``prosail.run_prosail``,
  factor "BHR") of a PROSPECT-D canopy over the prosail soil, i.e. the Lambertian albedo of
  a turf; extended below 400 nm like the leaves.
* Soils: the two soil spectra of ``prosail`` (dry ``rsoil1``, wet ``rsoil2``), mixed as in
  PROSAIL: ``rho = brightness * (moisture_mix * dry + (1 - moisture_mix) * wet)``. Below
  400 nm they are extended by the power law ``R(400) * (λ/400)^p`` whose exponent is fitted
  on 400–450 nm (clipped to [0.5, 4]); soils darken smoothly toward the UV.
* Concrete, bitumen roof, bark, water body and car paints are analytic curves documented
  in their functions below (shapes after the USGS/ECOSTRESS spectral libraries).
* Illumination: the downwelling irradiance on a horizontal plane is normalised to 1 in every
  band (only the sun/sky ratio matters for apparent reflectance). The sky's share of it
  (diffuse fraction) follows a Rayleigh-like power law ``0.1 (550/λ)^2.5`` (0.31 at 350 nm,
  0.1 at 550 nm, 0.022 at 1000 nm) for a clear sky.
* Noise: dark noise σ_b of a snapshot imager (:func:`dark_sigma`) plus a signal-dependent
  (shot) term with variance ``shot_coeff² · ρ``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

GRID_NM = np.arange(350.0, 1001.0, 1.0)  # [651] nm, 1 nm grid used for all material spectra


def default_wavelengths_nm(n_bands: int = 164, start_nm: float = 350.0, stop_nm: float = 1000.0) -> np.ndarray:
    """Band centres [n_bands] (nm), evenly spaced from ``start_nm`` to ``stop_nm`` (164 → 4 nm steps)."""
    if n_bands == 1:
        return np.array([0.5 * (start_nm + stop_nm)])
    return np.linspace(start_nm, stop_nm, int(n_bands))


def band_average(spectrum_grid: np.ndarray, wavelengths_nm: np.ndarray, fwhm_nm: np.ndarray) -> np.ndarray:
    """Band values [..., B] of a spectrum [..., 651] on ``GRID_NM`` with Gaussian band responses."""
    wl = np.asarray(wavelengths_nm, float)[:, None]  # [B, 1]
    sig = np.asarray(fwhm_nm, float)[:, None] / 2.354820045
    w = np.exp(-0.5 * ((GRID_NM[None, :] - wl) / sig) ** 2)  # [B, 651]
    w /= w.sum(1, keepdims=True)
    return np.asarray(spectrum_grid, float) @ w.T


def _extend_below_400_flat(values_400_1000: np.ndarray) -> np.ndarray:
    """[601] values on 400..1000 nm → [651] on 350..1000 nm, held constant below 400 nm."""
    out = np.empty(GRID_NM.shape)
    out[50:] = values_400_1000
    out[:50] = values_400_1000[0]
    return out


def _extend_below_400_power(values_400_1000: np.ndarray) -> np.ndarray:
    """Extend below 400 nm with ``R(400) (λ/400)^p``, p fitted on 400–450 nm and clipped to [0.5, 4]."""
    v = np.maximum(values_400_1000, 1e-4)
    p = np.log(v[50] / v[0]) / np.log(450.0 / 400.0)
    p = float(np.clip(p, 0.5, 4.0))
    out = np.empty(GRID_NM.shape)
    out[50:] = values_400_1000
    out[:50] = v[0] * (GRID_NM[:50] / 400.0) ** p
    return out


@lru_cache(maxsize=32)
def prospect_leaf(n: float, cab: float, car: float, cbrown: float, cw: float, cm: float,
                  ant: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """PROSPECT-D leaf (reflectance [651], transmittance [651]) on GRID_NM."""
    import prosail  # lazy: a ~1 s import (it compiles numba code); only the material spectra need it

    wl, r, t = prosail.run_prospect(n, cab, car, cbrown, cw, cm, ant=ant, prospect_version="D")
    sel = (wl >= 400) & (wl <= 1000)
    r = _extend_below_400_flat(np.asarray(r)[sel])
    t_ext = _extend_below_400_flat(np.asarray(t)[sel])
    t_ext[:50] = t_ext[50] * np.exp(-(400.0 - GRID_NM[:50]) / 15.0)
    r.setflags(write=False)
    t_ext.setflags(write=False)
    return r, t_ext


def soil_endmembers() -> tuple[np.ndarray, np.ndarray]:
    """prosail's dry (rsoil1) and wet (rsoil2) soil spectra [651] on GRID_NM."""
    import prosail  # lazy: a ~1 s import (it compiles numba code); only the material spectra need it

    s1 = np.asarray(prosail.spectral_lib.soil.rsoil1, float)[:601]  # 400..1000 nm
    s2 = np.asarray(prosail.spectral_lib.soil.rsoil2, float)[:601]
    return _extend_below_400_power(s1), _extend_below_400_power(s2)


def soil(brightness: float = 1.0, dry_fraction: float = 0.5) -> np.ndarray:
    """PROSAIL soil mixture ``brightness · (f · dry + (1 − f) · wet)`` [651]."""
    s1, s2 = soil_endmembers()
    return brightness * (dry_fraction * s1 + (1.0 - dry_fraction) * s2)


@lru_cache(maxsize=16)
def sail_bhr(n: float, cab: float, car: float, cbrown: float, cw: float, cm: float, lai: float,
             lidfa: float, soil_brightness: float, soil_dry: float) -> np.ndarray:
    """Bi-hemispherical reflectance [651] of a PROSPECT-D + SAIL turf (Lambertian-equivalent albedo)."""
    import prosail  # lazy: a ~1 s import (it compiles numba code); only the material spectra need it

    bhr = prosail.run_prosail(n, cab, car, cbrown, cw, cm, lai, lidfa, 0.05, 30.0, 0.0, 0.0,
                              prospect_version="D", typelidf=2, factor="BHR",
                              rsoil=soil_brightness, psoil=soil_dry)
    out = _extend_below_400_flat(np.asarray(bhr, float)[:601])
    out.setflags(write=False)
    return out


def concrete() -> np.ndarray:
    """Weathered concrete [651]: grey, 0.20 at 350 nm rising smoothly to 0.36 at 1000 nm.

    ``0.20 + 0.16 (1 − exp(−(λ − 350)/250)) / (1 − exp(−650/250))``, the shape of the
    ECOSTRESS/USGS "concrete" samples (a broad rise from the UV, no absorption features).
    """
    x = GRID_NM - 350.0
    return 0.20 + 0.16 * (1 - np.exp(-x / 250.0)) / (1 - np.exp(-650.0 / 250.0))


def bitumen_roof() -> np.ndarray:
    """Bitumen/tar-paper flat roof [651]: dark, 0.05 at 350 nm rising linearly to 0.10 at 1000 nm."""
    return 0.05 + 0.05 * (GRID_NM - 350.0) / 650.0


def asphalt() -> np.ndarray:
    """Aged asphalt road [651]: 0.06 at 350 nm rising linearly to 0.13 at 1000 nm (USGS "asphalt" shape)."""
    return 0.06 + 0.07 * (GRID_NM - 350.0) / 650.0


def bark() -> np.ndarray:
    """Tree bark [651]: brown, 0.05 in the blue, a smooth rise through the red to 0.30 in the NIR.

    ``0.05 + 0.25 / (1 + exp(−(λ − 680)/45))`` (shape of ECOSTRESS bark spectra).
    """
    return 0.05 + 0.25 / (1.0 + np.exp(-(GRID_NM - 680.0) / 45.0))


def water_body() -> np.ndarray:
    """Subsurface (water-column) reflectance [651] of a small eutrophic pond, seen through the surface.

    A green peak of 0.035 at 560 nm (``0.030 exp(−((λ−560)/80)²) + 0.005``) on a 0.5 %
    floor, cut off above 700 nm by the absorption of water (``exp(−(λ−700)/25)``),
    so NIR water is black apart from surface reflection.
    """
    r = 0.030 * np.exp(-(((GRID_NM - 560.0) / 80.0) ** 2)) + 0.005
    cut = np.where(GRID_NM > 700.0, np.exp(-(GRID_NM - 700.0) / 25.0), 1.0)
    return r * cut


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def paint(colour: str) -> np.ndarray:
    """Diffuse (pigment) reflectance [651] of a car paint below its clear coat.

    * red: ``0.05 + 0.55 σ((λ−600)/12)`` — pigment absorbs below ~590 nm.
    * white: ``0.82 σ((λ−395)/8) + 0.04`` — TiO2 absorption edge near 400 nm.
    * blue: ``0.05 + 0.30 exp(−((λ−460)/45)²) + 0.40 σ((λ−720)/25)`` — phthalocyanine blue
      is bright in the blue and again in the NIR.
    * silver: ``0.45 + 0.10 (λ−350)/650`` — grey metallic-flake paint.
    """
    lam = GRID_NM
    if colour == "red":
        return 0.05 + 0.55 * _sigmoid((lam - 600.0) / 12.0)
    if colour == "white":
        return 0.04 + 0.82 * _sigmoid((lam - 395.0) / 8.0)
    if colour == "blue":
        return 0.05 + 0.30 * np.exp(-(((lam - 460.0) / 45.0) ** 2)) + 0.40 * _sigmoid((lam - 720.0) / 25.0)
    if colour == "silver":
        return 0.45 + 0.10 * (lam - 350.0) / 650.0
    raise ValueError(f"unknown paint colour {colour!r}")


def sky_fraction(wavelengths_nm: np.ndarray) -> np.ndarray:
    """Diffuse (sky) fraction [B] of the downwelling irradiance, clear sky: ``0.1 (550/λ)^2.5``."""
    return np.clip(0.1 * (550.0 / np.asarray(wavelengths_nm, float)) ** 2.5, 0.0, 0.9)


def dark_sigma(wavelengths_nm: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Per-band dark-noise σ_b [B] (reflectance units) of a silicon snapshot imager.

    ``σ_b = s · (0.003 + 0.05 exp(−(λ−350)/30) + 0.03 exp((λ−1000)/35))``: 0.053 at 350 nm,
    0.0075 at 420 nm, 0.003–0.0035 in 500–850 nm, 0.0072 at 920 nm and 0.033 at 1000 nm
    (low quantum efficiency and weak illumination at both ends of the silicon range).
    """
    lam = np.asarray(wavelengths_nm, float)
    return scale * (0.003 + 0.05 * np.exp(-(lam - 350.0) / 30.0) + 0.03 * np.exp((lam - 1000.0) / 35.0))
