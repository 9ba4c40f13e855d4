"""Options of a simulated acquisition (:class:`SimConfig`), as ``brfgs simulate`` exposes them."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np
import pandas as pd

from brfgs.data.cameras import Intrinsics, paper_view_angles, ring_view_angles
from brfgs.data.georef import Origin
from brfgs.data.sun import solar_position
from brfgs.errors import UserError
from brfgs.sim import spectra as sp
from brfgs.sim.geometry import SCENES
from brfgs.sim.options import N_DARK_DEFAULT, SimOptions

__all__ = ["SimConfig", "VALID_VIEWS", "SAMPLERS", "N_DARK_DEFAULT"]

VALID_VIEWS = (1, 13, 25, 37, 49)
SAMPLERS = ("ldsampler", "independent")


@dataclass
class SimConfig(SimOptions):
    """Options of a simulated acquisition (the CLI exposes each one).

    scene: "testsite" | "forest" | "flat"; size: image width = height (px); bands: number of
    bands over [wavelength_min_nm, wavelength_max_nm]; views: 1, 13, 25, 37 or 49; spp: samples
    per pixel (a power of 4 for the default low-discrepancy sampler, a power of two for
    "independent"); sampler: "ldsampler" (Mitsuba's low-discrepancy sampler, default) or
    "independent" (plain random samples; scenes written before the sampler option); sun angles in degrees (conventions: azimuth clockwise from north,
    toward the sun); seed: all random choices (geometry, textures, Monte Carlo, noise);
    distance_m: camera distance from the scene centre; fov_deg: horizontal field of view;
    fwhm_nm: band width; noise_scale: multiplies σ_b (0 = noise-free observations);
    shot_coeff: signal-dependent noise k (σ² = k²·ρ); n_dark: dark frames;
    max_depth: longest light path; texture_px: resolution of the ground textures (0 = from size);
    rings_deg, n_azimuths: another view layout, nadir + ``n_azimuths`` azimuths (from 0°, evenly
    spaced) on each ring of ``rings_deg`` (view zeniths in degrees), instead of the paper's ``views``.
    """

    def texture_resolution(self) -> int:
        """Ground-texture resolution (texels over the 120 m core): ``texture_px`` or, when 0, the power
        of two ≥ 4·size (texels at most ~1/4 of a nadir pixel), between 64 and 2048."""
        if int(self.texture_px) > 0:
            return int(self.texture_px)
        return int(min(2048, max(64, 2 ** math.ceil(math.log2(4 * int(self.size))))))

    @classmethod
    def tiny(cls, scene: str = "testsite", **overrides) -> "SimConfig":
        """Small preset for tests and quick looks: 32², 16 bands, 13 views, 16 spp, 4 dark frames."""
        base = dict(scene=scene, size=32, bands=16, views=13, spp=16, n_dark=4)
        base.update(overrides)
        return cls(**base)

    @classmethod
    def small(cls, scene: str = "testsite", **overrides) -> "SimConfig":
        """Small preset with enough pixels for SIFT/SfM: 64², 16 bands, 13 views, 16 spp."""
        base = dict(scene=scene, size=64, bands=16, views=13, spp=16, n_dark=8)
        base.update(overrides)
        return cls(**base)

    def validate(self) -> None:
        """Raise UserError for impossible options."""
        def req(cond, msg, field):
            if not cond:
                raise UserError(msg, field=field)
        req(self.scene in SCENES, f"unknown scene {self.scene!r}; choose one of {', '.join(SCENES)}", "scene")
        req(int(self.size) >= 8, f"size must be at least 8 pixels, got {self.size}", "size")
        req(int(self.bands) >= 1, f"bands must be at least 1, got {self.bands}", "bands")
        req(int(self.views) in VALID_VIEWS, f"views must be one of {VALID_VIEWS}, got {self.views}", "views")
        if self.rings_deg is not None:
            r = [float(v) for v in self.rings_deg]
            req(len(r) >= 1 and all(math.isfinite(v) and 0.0 < v <= 75.0 for v in r) and len(set(r)) == len(r),
                f"rings must be distinct view zeniths in (0, 75] degrees, got {r}", "rings_deg")
            req(1 <= int(self.n_azimuths) <= 72, f"azimuths per ring must be 1-72, got {self.n_azimuths}",
                "n_azimuths")
        spp = int(self.spp)
        req(self.sampler in SAMPLERS, f"sampler must be one of {', '.join(SAMPLERS)}, got {self.sampler!r}",
            "sampler")
        req(spp >= 1 and spp & (spp - 1) == 0, f"spp must be a power of two (1, 2, 4, ...), got {self.spp}", "spp")
        # Mitsuba's ldsampler needs a square power of two (it would silently round up otherwise)
        req(self.sampler != "ldsampler" or (spp.bit_length() - 1) % 2 == 0,
            f"spp must be a power of 4 (1, 4, 16, 64, 256, ...) for the ldsampler sampler, got {self.spp}", "spp")
        req(0.0 <= float(self.sun_zenith_deg) <= 89.0,
            f"sun zenith must be within [0, 89] degrees, got {self.sun_zenith_deg}", "sun_zenith_deg")
        req(math.isfinite(float(self.sun_azimuth_deg)), "sun azimuth must be a finite number", "sun_azimuth_deg")
        req(float(self.distance_m) > 20.0, f"distance must exceed 20 m, got {self.distance_m}", "distance_m")
        req(1.0 <= float(self.fov_deg) <= 120.0, f"field of view must be in [1, 120] degrees, got {self.fov_deg}",
            "fov_deg")
        req(300.0 <= self.wavelength_min_nm < self.wavelength_max_nm <= 1000.0,
            "wavelength range must lie within 350-1000 nm (min < max)", "wavelength_min_nm")
        req(self.wavelength_min_nm >= 350.0, "material spectra start at 350 nm", "wavelength_min_nm")
        req(self.fwhm_nm > 0, "fwhm must be positive", "fwhm_nm")
        req(self.noise_scale >= 0 and self.shot_coeff >= 0, "noise parameters must be non-negative", "noise_scale")
        req(int(self.n_dark) >= 0, "n_dark must be non-negative", "n_dark")
        req(int(self.max_depth) >= 1, "max_depth must be at least 1", "max_depth")
        req(int(self.texture_px) == 0 or int(self.texture_px) >= 16, "texture_px must be 0 (auto) or >= 16",
            "texture_px")
        if self.origin is not None:
            o = list(self.origin)
            req(len(o) in (2, 3) and all(math.isfinite(float(v)) for v in o) and abs(float(o[0])) < 89.9
                and abs(float(o[1])) <= 180.0, f"origin must be LAT,LON[,ALT] in degrees (and metres), got {o}", "origin")

        if self.start_time is not None:
            req(self.origin is not None, "a start time needs the origin (where the sun is computed)", "start_time")
            req(0.0 <= float(self.duration_min) <= 600.0, "duration must be 0-600 minutes", "duration_min")
        req(0.0 <= float(self.irradiance_drift) < 0.9, "irradiance drift must be in [0, 0.9)", "irradiance_drift")
        if self.distortion is not None:
            d = list(self.distortion)
            req(len(d) == 4 and all(math.isfinite(float(v)) and abs(float(v)) < 1.0 for v in d),
                f"distortion must be k1,k2,p1,p2 with |value| < 1, got {d}", "distortion")

    def view_angles(self) -> list[tuple[float, float]]:
        """(view_zenith_deg, view_azimuth_deg) of every view, nadir first, ring by ring (ascending)."""
        if self.rings_deg is None:
            return paper_view_angles(int(self.views))
        return ring_view_angles(self.rings_deg, self.n_azimuths)

    def n_views(self) -> int:
        """Number of views of the layout (``views``, or nadir + rings × azimuths)."""
        return len(self.view_angles())

    def view_times(self) -> list[str] | None:
        """UTC ISO time of every view (acquisition order), or None without a start time."""
        if self.start_time is None:
            return None
        t0 = pd.Timestamp(self.start_time)
        if t0.tzinfo is None:
            raise UserError(f"start time needs a UTC offset (e.g. 'Z'), got {self.start_time!r}", field="start_time")
        n = self.n_views()
        step = pd.Timedelta(minutes=float(self.duration_min) / max(n - 1, 1))
        return [(t0 + k * step).tz_convert("UTC").isoformat() for k in range(n)]

    def irradiance_scales(self) -> np.ndarray:
        """Per-view factor [V] of the downwelling irradiance (a smooth drift of amplitude
        ``irradiance_drift`` over the flight, phase from the seed): 1 everywhere without drift."""
        n = self.n_views()
        if self.irradiance_drift <= 0:
            return np.ones(n)
        phase = np.random.default_rng([int(self.seed), 11]).uniform(0, 2 * np.pi)
        t = np.arange(n) / max(n - 1, 1)
        return 1.0 + float(self.irradiance_drift) * np.sin(2 * np.pi * 1.5 * t + phase)

    def view_suns(self) -> tuple[np.ndarray, np.ndarray]:
        """(zenith, azimuth) deg [V] of the sun at every view: from the view times at the origin
        (pvlib's NREL SPA, brfgs.data.sun) or the fixed ``sun_zenith_deg``/``sun_azimuth_deg``."""
        times = self.view_times()
        if times is None:
            n = self.n_views()
            return np.full(n, float(self.sun_zenith_deg)), np.full(n, float(self.sun_azimuth_deg))
        o = self.origin_json()
        return solar_position(times, Origin(o["latitude_deg"], o["longitude_deg"], o["altitude_m"]))

    def origin_json(self) -> dict | None:
        """The ``origin`` entry of transforms.json (brfgs.data.georef), or None."""
        if self.origin is None:
            return None
        o = [float(v) for v in self.origin]
        return {"latitude_deg": o[0], "longitude_deg": o[1], "altitude_m": o[2] if len(o) > 2 else 0.0}

    # derived quantities
    def wavelengths_nm(self) -> np.ndarray:
        return sp.default_wavelengths_nm(int(self.bands), self.wavelength_min_nm, self.wavelength_max_nm)

    def fwhm_array_nm(self) -> np.ndarray:
        return np.full(int(self.bands), float(self.fwhm_nm))

    def intrinsics(self, size: int | None = None) -> Intrinsics:
        n = int(self.size if size is None else size)
        return Intrinsics.from_fov(float(self.fov_deg), n, n)

    def sigma_b(self) -> np.ndarray:
        """Configured per-band dark noise σ_b [B] (reflectance units)."""
        return sp.dark_sigma(self.wavelengths_nm(), self.noise_scale)

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> "SimConfig":
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in d.items() if k in names}
        kw.setdefault("sampler", "independent")  # scenes written before the sampler option
        for key in ("origin", "distortion", "rings_deg"):
            if kw.get(key) is not None:
                kw[key] = tuple(kw[key])
        return cls(**kw)
