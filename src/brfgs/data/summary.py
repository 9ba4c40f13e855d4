"""Scene summary for ``brfgs inspect``: acquisition geometry, noise and data quality.

Reads every cube once (streamed, so the pixel-range check covers every full-resolution
pixel) and reports per-band mean reflectance, σ_b and an SNR estimate, NaN/Inf counts
and the angular coverage of the views relative to the sun.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from brfgs.data import atomic
from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.figures import pyplot
from brfgs.data.scene import Scene
from brfgs.data.splits import view_spacing_deg


@dataclass
class SceneSummary:
    name: str
    n_frames: int
    n_train: int
    n_test: int
    n_bands: int
    wavelength_range_nm: tuple[float, float]
    width: int
    height: int
    sun_zenith_deg: float
    sun_azimuth_deg: float
    view_zenith_range_deg: tuple[float, float]
    n_azimuth_sectors: int                      # occupied 30° azimuth sectors of the off-nadir views
    phase_angle_range_deg: tuple[float, float]  # angle between the sun and view directions
    nearest_hotspot_deg: float                  # smallest angle of a view to the hotspot direction
    nearest_specular_deg: float                 # smallest angle of a view to the specular direction
    sigma_source: str
    diffuse_fraction_source: str = "clear-sky default"
    diffuse_fraction: list[float] = field(default_factory=list)  # [B] sky share of the irradiance
    own_sky_frames: int = 0                     # frames with their own diffuse fraction (merged flights)
    own_sky_range: tuple[float, float] | None = None  # the smallest and largest of those frames' fractions
    wavelengths_nm: list[float] = field(default_factory=list)
    sigma: list[float] = field(default_factory=list)
    mean_reflectance: list[float] = field(default_factory=list)
    snr: list[float] = field(default_factory=list)
    invalid_pixels: dict[str, int] = field(default_factory=dict)
    bright_pixels: dict[str, int] = field(default_factory=dict)  # pixels above the plausible range (kept)
    rings: dict[str, list[int]] = field(default_factory=dict)  # view ring -> [n train, n test]
    nearest_train_view_deg: dict[str, float] = field(default_factory=dict)  # held-out view -> angle to training
    ring_spacing_deg: dict[str, float] = field(default_factory=dict)  # view ring -> its views' largest angle to another view
    flight: dict = field(default_factory=dict)  # per-frame suns, times, irradiance scales, cameras, georeference

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def summarize(scene: Scene, progress: bool = True) -> SceneSummary:
    """Summary of ``scene``; reads every frame once."""
    B = scene.n_bands
    s1 = np.zeros(B)
    n = 0
    for i in tqdm(range(len(scene.frames)), desc="reading cubes", unit="frame", disable=not progress):
        img = scene.load_image(i).reshape(-1, B)
        ok = np.isfinite(img).all(1)
        s1 += img[ok].sum(0, dtype=np.float64)
        n += int(ok.sum())
    mean = s1 / max(n, 1)
    sigma = scene.dark_sigma
    snr = np.where(sigma > 0, mean / np.maximum(sigma, 1e-12), np.inf)

    vz = np.array([f.view_zenith_deg for f in scene.frames])
    va = np.array([f.view_azimuth_deg for f in scene.frames])
    views = direction_from_angles_deg(vz, va)                                  # [F, 3]
    sun = direction_from_angles_deg(scene.sun_zenith_deg, scene.sun_azimuth_deg)  # [3]
    spec = direction_from_angles_deg(scene.sun_zenith_deg, scene.sun_azimuth_deg + 180.0)
    phase = np.degrees(np.arccos(np.clip(views @ sun, -1, 1)))
    to_spec = np.degrees(np.arccos(np.clip(views @ spec, -1, 1)))
    off = vz > 1.0
    sectors = np.unique(np.floor(np.remainder(va[off] + 15.0, 360.0) / 30.0)).size if off.any() else 0
    return SceneSummary(
        name=scene.name, n_frames=len(scene.frames), n_train=len(scene.train_indices),
        n_test=len(scene.test_indices), n_bands=B,
        wavelength_range_nm=(float(scene.wavelengths_nm[0]), float(scene.wavelengths_nm[-1])),
        width=scene.width, height=scene.height, sun_zenith_deg=scene.sun_zenith_deg,
        sun_azimuth_deg=scene.sun_azimuth_deg, view_zenith_range_deg=(float(vz.min()), float(vz.max())),
        n_azimuth_sectors=int(sectors), phase_angle_range_deg=(float(phase.min()), float(phase.max())),
        nearest_hotspot_deg=float(phase.min()), nearest_specular_deg=float(to_spec.min()),
        sigma_source=scene.dark_sigma_source, wavelengths_nm=scene.wavelengths_nm.tolist(),
        diffuse_fraction_source=scene.diffuse_fraction_source, diffuse_fraction=scene.diffuse_fraction.tolist(),
        **_own_skies(scene),
        sigma=sigma.tolist(), mean_reflectance=mean.tolist(), snr=snr.tolist(),
        invalid_pixels=dict(scene.invalid_counts), bright_pixels=dict(scene.bright_counts), rings=_ring_counts(scene),
        nearest_train_view_deg=scene.nearest_train_view_deg(), ring_spacing_deg=_ring_spacing(scene, views),
        flight=_flight(scene))


def _ring_spacing(scene: Scene, views: np.ndarray) -> dict[str, float]:
    """{view ring: the largest angle (deg, 0.1) from one of its views [F, 3] to the nearest other view}."""
    spacing = view_spacing_deg(views)                                           # [F]
    rings = scene.rings()
    out: dict[str, float] = {}
    for f, a in zip(scene.frames, spacing):
        if np.isfinite(a):
            out[rings[f.name]] = max(out.get(rings[f.name], 0.0), round(float(a), 1))
    return dict(sorted(out.items(), key=lambda kv: float(kv[0])))


def _spacing_line(spacing: dict[str, float]) -> str:
    """Console line: the layout's angular sampling per view ring (what any split's held-out views get at best)."""
    if not spacing:
        return "view spacing     one view"
    return ("view spacing     " + ", ".join(f"{r} deg: {a:.1f}" for r, a in spacing.items())
            + " (per ring, the largest angle from one of its views to its nearest other view, which no split can "
            "shorten; on the 64^2 testsite the 58 deg ring scores 6.4 dB below the 18 deg ring at 20 deg, 3.1-3.4 dB "
            "at 12.7 and 2.7-2.9 dB at 5: docs/flights.md)")


def _held_out_line(nearest_deg: dict[str, float]) -> str:
    """Console line: how far the held-out views are from the nearest training view."""
    if not nearest_deg:
        return "held-out views   none"
    a = np.array(list(nearest_deg.values()))
    return (f"held-out views   {a.min():.1f}-{a.max():.1f} deg from the nearest training view (median "
            f"{np.median(a):.1f}; farther means extrapolation: expect lower scores there)")


def _flight(scene: Scene) -> dict:
    """What a real flight adds: the frames' sun range and times, irradiance scales, own cameras, origin."""
    z = [f.sun_zenith_deg for f in scene.frames]
    a = [f.sun_azimuth_deg for f in scene.frames]
    times = sorted(f.time_utc for f in scene.frames if f.time_utc)
    scales = [f.irradiance_scale for f in scene.frames]
    own = [f.camera for f in scene.frames if f.camera is not None]
    return {"sun_zenith_range_deg": [float(min(z)), float(max(z))], "sun_azimuth_range_deg": [float(min(a)), float(max(a))],
            "time_range_utc": [times[0], times[-1]] if times else None,
            "irradiance_scale_range": [float(min(scales)), float(max(scales))],
            "frames_resampled": len(own), "distorted": sum(any(c.dist) for c in own),
            "origin": scene.origin.to_json() if scene.origin else None, "crs": scene.crs}


def _sky_line(s: SceneSummary) -> str:
    """The inspect line of the diffuse fraction: its range, where it comes from, frames with their own."""
    src = s.diffuse_fraction_source
    if src == "clear-sky default":
        src += " at the reference sun, each frame at its own"
    own = (f"; {s.own_sky_frames} frame(s) with their own, {s.own_sky_range[0]:.3f}-{s.own_sky_range[1]:.3f}"
           if s.own_sky_frames else "")
    return (f"diffuse fraction {min(s.diffuse_fraction):.3f}-{max(s.diffuse_fraction):.3f} of the irradiance from the "
            f"sky ({src}; how dark shadows are with brfgs train --shadows){own}")


def _own_skies(scene) -> dict:
    """The number of frames with their own diffuse fraction and the range of their values."""
    own = [f.diffuse_fraction for f in scene.frames if f.diffuse_fraction is not None]
    if not own:
        return {}
    return {"own_sky_frames": len(own), "own_sky_range": (float(np.min(own)), float(np.max(own)))}


def _ring_counts(scene: Scene) -> dict[str, list[int]]:
    """{view ring: [n train, n test]} of the split (rings: brfgs.data.splits)."""
    rings = scene.rings()
    out: dict[str, list[int]] = {}
    for f in scene.frames:
        c = out.setdefault(rings[f.name], [0, 0])
        c[f.split == "test"] += 1
    return dict(sorted(out.items(), key=lambda kv: float(kv[0])))


def _flight_lines(fl: dict) -> list[str]:
    """Lines of the summary for a flight's moving sun, drift, cameras and georeference (if any)."""
    out = []
    if fl and fl["sun_zenith_range_deg"][1] - fl["sun_zenith_range_deg"][0] + fl["sun_azimuth_range_deg"][1] \
            - fl["sun_azimuth_range_deg"][0] > 1e-6:
        t = fl["time_range_utc"]
        out.append(f"frame suns       zenith {fl['sun_zenith_range_deg'][0]:.1f}-{fl['sun_zenith_range_deg'][1]:.1f} "
                   f"deg, azimuth {fl['sun_azimuth_range_deg'][0]:.1f}-{fl['sun_azimuth_range_deg'][1]:.1f} deg"
                   + (f" ({t[0]} to {t[1]})" if t else "") + "; the line above is the reference sun")
    if fl and fl["irradiance_scale_range"] != [1.0, 1.0]:
        out.append(f"irradiance scale {fl['irradiance_scale_range'][0]:.3f}-{fl['irradiance_scale_range'][1]:.3f} "
                   "(each frame divided by its own)")
    if fl and fl["frames_resampled"]:
        out.append(f"cameras          {fl['frames_resampled']} frame(s) with their own camera ({fl['distorted']} "
                   "distorted), resampled onto the pinhole camera on reading")
    if fl and fl["origin"]:
        o = fl["origin"]
        out.append(f"origin           {o['latitude_deg']:.6f}, {o['longitude_deg']:.6f}, {o['altitude_m']:.1f} m "
                   f"(WGS 84); map CRS {fl['crs'] or 'UTM zone of the origin'}")
    return out


def format_summary(s: SceneSummary, max_band_rows: int = 12) -> str:
    """Human-readable table of a summary."""
    lines = [
        f"scene            {s.name}",
        f"frames           {s.n_frames} ({s.n_train} train / {s.n_test} test)",
        "view rings       " + ", ".join(f"{r} deg: {a}/{b}" for r, (a, b) in s.rings.items()) + " (train/test)",
        _held_out_line(s.nearest_train_view_deg),
        _spacing_line(s.ring_spacing_deg),
        f"bands            {s.n_bands}, {s.wavelength_range_nm[0]:.1f}-{s.wavelength_range_nm[1]:.1f} nm",
        f"image size       {s.width} x {s.height} px",
        f"sun              zenith {s.sun_zenith_deg:.1f} deg, azimuth {s.sun_azimuth_deg:.1f} deg",
        f"view zenith      {s.view_zenith_range_deg[0]:.1f}-{s.view_zenith_range_deg[1]:.1f} deg, "
        f"{s.n_azimuth_sectors}/12 azimuth sectors of 30 deg",
        f"phase angle      {s.phase_angle_range_deg[0]:.1f}-{s.phase_angle_range_deg[1]:.1f} deg "
        f"(nearest view to hotspot {s.nearest_hotspot_deg:.1f} deg, to specular {s.nearest_specular_deg:.1f} deg)",
        f"noise sigma      from {s.sigma_source}",
        _sky_line(s),
    ]
    lines += _flight_lines(s.flight)
    n_bad = sum(s.invalid_pixels.values())
    bad_frames = {k: v for k, v in s.invalid_pixels.items() if v}
    lines.append(f"NaN/Inf pixels   {n_bad} in {len(bad_frames)} frame(s)"
                 + (": " + ", ".join(f"{k}={v}" for k, v in list(bad_frames.items())[:6]) if bad_frames else "")
                 + (" (masked out of every loss and metric)" if n_bad else ""))
    bright = {k: v for k, v in s.bright_pixels.items() if v}
    if bright:
        lines.append(f"above the range  {sum(bright.values())} pixel(s) in {len(bright)} frame(s): "
                     + ", ".join(f"{k}={v}" for k, v in list(bright.items())[:6])
                     + " (kept: specular glints; at most 5 % of a frame's pixels)")
    lines.append("")
    lines.append(f"{'band':>5} {'wavelength_nm':>14} {'mean_refl':>10} {'sigma':>10} {'snr':>9}")
    idx = np.unique(np.linspace(0, s.n_bands - 1, min(max_band_rows, s.n_bands)).round().astype(int))
    for i in idx:
        lines.append(f"{i:>5} {s.wavelengths_nm[i]:>14.1f} {s.mean_reflectance[i]:>10.4f} "
                     f"{s.sigma[i]:>10.5f} {s.snr[i]:>9.1f}")
    if len(idx) < s.n_bands:
        lines.append(f"({len(idx)} of {s.n_bands} bands shown; all bands in summary.json)")
    return "\n".join(lines)


def plot_views(scene: Scene, path) -> None:
    """Polar plot of the view directions (zenith as radius, azimuth clockwise from north), sun marked."""
    plt = pyplot()
    fig = plt.figure(figsize=(6.5, 5.5))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    for f in scene.frames:
        marker, color = ("o", "tab:blue") if f.split == "train" else ("s", "tab:orange")
        ax.plot(np.radians(f.view_azimuth_deg), f.view_zenith_deg, marker, color=color, ms=6)
    ax.plot([], [], "o", color="tab:blue", label="train view")
    ax.plot([], [], "s", color="tab:orange", label="test view")
    ax.plot(np.radians(scene.sun_azimuth_deg), scene.sun_zenith_deg, "*", color="red", ms=16, label="sun")
    ax.plot(np.radians(scene.sun_azimuth_deg + 180), scene.sun_zenith_deg, "x", color="red", ms=9,
            label="specular direction")
    rmax = max(60.0, max(f.view_zenith_deg for f in scene.frames) + 5, scene.sun_zenith_deg + 5)
    ax.set_rlim(0, rmax)
    ax.set_title(f"{scene.name}: view directions\n(zenith deg radial, azimuth clockwise from north)", fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(0.82, 1.12), fontsize=8)
    fig.tight_layout()
    atomic.save_figure(fig, path, dpi=120)
    plt.close(fig)

