"""The options of a simulated acquisition (the fields of :class:`brfgs.sim.config.SimConfig`), light
so that the command line builds ``brfgs simulate``'s options from them at start-up."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

N_DARK_DEFAULT = 20
LAYOUTS = ("native", "colmap")


def _f(default, help: str, **meta):
    return field(default=default, metadata={"help": help, **meta})


@dataclass
class SimOptions:
    """What is simulated: scene, sensor, view layout, sun, noise, a real flight's conditions."""

    scene: str = _f("testsite", "Scene: testsite, forest or flat.")
    size: int = _f(128, "Image width = height in pixels (>= 8).")
    bands: int = _f(164, "Number of bands over 350-1000 nm.")
    views: int = _f(49, "Views: 1, 13, 25, 37 or 49 (the AIR-BRF layout: nadir + 12 azimuths x 18/23/38/58 deg).")
    rings_deg: Optional[tuple[float, ...]] = _f(None, "Another layout: nadir + --azimuths views on each of these "
                                                "view-zenith rings (deg), instead of --views.", flag="--rings",
                                                metavar="Z1,Z2,...")
    n_azimuths: int = _f(12, "Views per ring of --rings, evenly spaced from 0 deg.", flag="--azimuths")
    spp: int = _f(64, "Samples per pixel: a power of 4 for ldsampler, a power of two for independent.")
    sampler: str = _f("ldsampler", "Monte Carlo sampler: ldsampler (low discrepancy) or independent.")
    sun_zenith_deg: float = _f(38.0, "Sun zenith (deg, 0-89).", flag="--sun-zenith")
    sun_azimuth_deg: float = _f(150.0, "Sun azimuth (deg clockwise from north).", flag="--sun-azimuth")
    seed: int = _f(0, "Seed of every random choice (geometry, textures, Monte Carlo, noise).")
    distance_m: float = _f(100.0, "Camera distance from the scene centre (m).", flag="--distance")
    fov_deg: float = _f(35.0, "Horizontal field of view (deg).", flag="--fov")
    origin: Optional[tuple[float, ...]] = _f(None, "WGS 84 latitude, longitude (deg) and height (m) of the scene "
                                             "centre: the scene is georeferenced.", metavar="LAT,LON[,ALT]")
    start_time: Optional[str] = _f(None, "UTC time of the first view (ISO 8601; needs --origin): each view gets "
                                   "its time and that time's sun.")
    duration_min: float = _f(0.0, "Minutes from the first to the last view.")
    irradiance_drift: float = _f(0.0, "Amplitude d of a smooth per-view irradiance drift (factor in [1-d, 1+d]).")
    distortion: Optional[tuple[float, ...]] = _f(None, "OPENCV lens distortion of the camera.", metavar="K1,K2,P1,P2")
    noise_scale: float = _f(1.0, "Multiplies the dark noise sigma_b (0 = noise-free).")
    shot_coeff: float = _f(0.01, "Signal-dependent noise k (var = k^2 rho).")
    n_dark: int = _f(N_DARK_DEFAULT, "Number of dark frames in calibration/.", flag="--dark-frames")
    max_depth: int = _f(10, "Longest light path (bounces).")
    wavelength_min_nm: float = _f(350.0, "Shortest band centre (nm).", expert=True)
    wavelength_max_nm: float = _f(1000.0, "Longest band centre (nm).", expert=True)
    fwhm_nm: float = _f(4.0, "Band width (nm).", expert=True)
    texture_px: int = _f(0, "Resolution of the ground textures (0 = from --size).", expert=True)


@dataclass
class SimulateOptions:
    """Options of ``brfgs simulate``: the acquisition and how it is written."""

    sim: SimOptions = field(default_factory=SimOptions, metadata={"flatten": True})
    layout: str = _f("native", "native (transforms.json + ENVI cubes) or colmap (a COLMAP project with TIFF cubes and "
                     "a spectral sidecar, for brfgs import colmap).")
    overwrite: bool = _f(False, "Replace a simulation already in OUT.")
    resume: bool = _f(False, "Continue an interrupted simulation in OUT.")
    quiet: bool = _f(False, "No progress bar.", aliases=("-q",))
