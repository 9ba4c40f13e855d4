"""``brfgs simulate``: AIR-BRF-like multi-angle hyperspectral acquisitions of a Mitsuba scene.

Writes a scene folder in the layout of conventions.md (transforms.json, images/, calibration/)
plus truth/ (clean cubes, depth, material ids, material table, σ_b, scene parameters) and
two colour-infrared previews. See :class:`SimConfig` for the options and
:func:`simulate` / :func:`render_views` for the library entry points.

Acquisition (paper §4.1.2): views from :func:`brfgs.data.cameras.paper_view_angles`
(nadir + 12 azimuths × 18/23/38/58°; 13/25/37 views for small presets), 35° field of view,
cameras at ``distance_m`` from the scene centre looking at it; bands evenly spaced over
350–1000 nm with 4 nm FWHM (164 bands by default).

Observation model (snapshot imager): ``obs = clean + N(0, σ_b²) + N(0, k² · max(clean, 0))``
with the dark noise σ_b of :func:`brfgs.sim.spectra.dark_sigma` and shot coefficient k.
Dark frames are ``N(0, σ_b²)``. ``clean`` is Mitsuba's estimate of π·L/E_down with
``spp`` samples per pixel (so it carries a little Monte Carlo noise of its own). The default
low-discrepancy sampler at 64 spp keeps that noise well below the sensor's: on the 128²
testsite its CIR PSNR against a 2048-spp render is 36.7 dB, where 32 independent samples
(the sampler of earlier scenes) gave 29.8 dB — a ceiling on any PSNR measured against truth.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from brfgs.data.cameras import Intrinsics, paper_view_angles, pose_from_view_angles
from brfgs.data.cube_io import write_envi
from brfgs.errors import UserError
from brfgs.sim import spectra as sp
from brfgs.sim.geometry import SCENES, build_geometry
from brfgs.sim.materials import MATERIAL_IDS, MATERIAL_NAMES

VALID_VIEWS = (1, 13, 25, 37, 49)
SAMPLERS = ("ldsampler", "independent")
N_DARK_DEFAULT = 20
# what simulate() writes (and what --overwrite may remove); other files in OUT are left alone
OUTPUT_ENTRIES = ("transforms.json", "images", "calibration", "truth", "preview_cir_nadir.png",
                  "preview_cir_oblique.png", ".simulate_progress.json", ".simulate_progress.json.tmp")


@dataclass
class SimConfig:
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
    max_depth: longest light path; texture_px: resolution of the ground textures (0 = from size).
    """

    scene: str = "testsite"
    size: int = 128
    bands: int = 164
    views: int = 49
    spp: int = 64
    sun_zenith_deg: float = 38.0
    sun_azimuth_deg: float = 150.0
    seed: int = 0
    distance_m: float = 100.0
    fov_deg: float = 35.0
    wavelength_min_nm: float = 350.0
    wavelength_max_nm: float = 1000.0
    fwhm_nm: float = 4.0
    noise_scale: float = 1.0
    shot_coeff: float = 0.01
    n_dark: int = N_DARK_DEFAULT
    max_depth: int = 10
    texture_px: int = 0
    sampler: str = "ldsampler"

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
        return cls(**kw)


def view_name(index: int, zenith_deg: float, azimuth_deg: float) -> str:
    """Frame name ``v<index>_z<zenith>_a<azimuth>`` (e.g. v07_z38_a180)."""
    return f"v{index:02d}_z{int(round(zenith_deg)):02d}_a{int(round(azimuth_deg)) % 360:03d}"


def render_seed(seed: int, zenith_deg: float, azimuth_deg: float) -> int:
    """Monte Carlo seed (uint32) of the view at (zenith, azimuth): a render of the same view
    direction with the same seed reproduces the same samples."""
    key = [int(seed), int(round(zenith_deg * 1000)), int(round((azimuth_deg % 360.0) * 1000))]
    return int(np.random.SeedSequence(key).generate_state(1)[0])


def _make_renderer(cfg: SimConfig, bands=None, spp: int | None = None):
    from brfgs.sim.render import BandTripletRenderer

    geom = build_geometry(cfg.scene, int(cfg.seed), cfg.texture_resolution())
    wl = cfg.wavelengths_nm()
    fw = cfg.fwhm_array_nm()
    if bands is not None:
        wl, fw = wl[list(bands)], fw[list(bands)]
    return geom, BandTripletRenderer(geom, wl, fw, float(cfg.sun_zenith_deg), float(cfg.sun_azimuth_deg),
                                     spp=int(cfg.spp if spp is None else spp), max_depth=int(cfg.max_depth),
                                     sampler=cfg.sampler)


def render_views(cfg: SimConfig, view_angles_deg, size: int | None = None, spp: int | None = None,
                 bands=None, distance_m: float | None = None, target_m=None, progress: bool = False) -> dict:
    """Clean apparent reflectance of the scene ``cfg`` from arbitrary view directions.

    Args:
        view_angles_deg: [(view_zenith_deg, view_azimuth_deg), ...] (conventions: azimuth of the
            direction toward the sensor); cameras look at ``target_m`` (ENU m, default the scene
            centre) from ``distance_m``.
        size, spp, distance_m: override the config's values; ``bands``: band indices (default all).
    Returns a dict: ``reflectance`` [V, H, W, B'] float32, ``depth`` [V, H, W] (m along the optical
    axis), ``material`` [V, H, W] int16, ``c2w`` [V, 4, 4] (OpenGL), ``intrinsics``, ``wavelengths_nm``.
    The Monte Carlo seed depends only on (seed, view direction), so a view of the acquisition is
    reproduced exactly when size, spp and bands match.
    """
    cfg.validate()
    if spp is not None:  # an override must suit the sampler too (ldsampler: a power of 4)
        replace(cfg, spp=int(spp)).validate()
    views = [(float(z), float(a)) for z, a in view_angles_deg]
    for z, _ in views:
        if not 0.0 <= z <= 89.0:
            raise UserError(f"view zenith must be within [0, 89] degrees, got {z}", field="view_zenith_deg")
    _, rend = _make_renderer(cfg, bands, spp)
    intr = cfg.intrinsics(size)
    dist = float(cfg.distance_m if distance_m is None else distance_m)
    refl, depth, mats, c2ws = [], [], [], []
    it = views
    if progress:
        from tqdm import tqdm

        it = tqdm(views, desc="render views", unit="view")
    for z, a in it:
        c2w = pose_from_view_angles(z, a, dist, target_m)
        refl.append(rend.render_cube(c2w, intr, render_seed(cfg.seed, z, a)))
        d, m = rend.raycast(c2w, intr)
        depth.append(d)
        mats.append(m)
        c2ws.append(c2w)
    wl = cfg.wavelengths_nm() if bands is None else cfg.wavelengths_nm()[list(bands)]
    return {"reflectance": np.stack(refl), "depth": np.stack(depth), "material": np.stack(mats),
            "c2w": np.stack(c2ws), "intrinsics": intr, "wavelengths_nm": wl}


def render_scene_views(scene_dir: str | Path, view_angles_deg, **kwargs) -> dict:
    """:func:`render_views` for a simulated scene folder (reads its truth/scene.json)."""
    path = Path(scene_dir) / "truth" / "scene.json"
    if not path.is_file():
        raise UserError("not a simulated scene (truth/scene.json missing)", file=path)
    cfg = SimConfig.from_json(json.loads(path.read_text())["config"])
    return render_views(cfg, view_angles_deg, **kwargs)


def observe(clean: np.ndarray, sigma_b: np.ndarray, shot_coeff: float, rng: np.random.Generator) -> np.ndarray:
    """Noisy observation [H, W, B] float32 of a clean cube: dark noise σ_b [B] + shot noise k·sqrt(ρ)."""
    clean = np.asarray(clean, np.float32)
    noise = rng.standard_normal(clean.shape, dtype=np.float32) * np.asarray(sigma_b, np.float32)
    if shot_coeff > 0:
        noise += rng.standard_normal(clean.shape, dtype=np.float32) * (
            np.float32(shot_coeff) * np.sqrt(np.maximum(clean, 0.0)))
    return clean + noise


def _cir_png(path: Path, cube: np.ndarray, wavelengths_nm: np.ndarray) -> None:
    """Colour-infrared preview: bands nearest 850/650/550 nm as R/G/B, each over its 99th percentile."""
    from PIL import Image

    idx = [int(np.argmin(np.abs(wavelengths_nm - w))) for w in (850.0, 650.0, 550.0)]
    rgb = np.empty(cube.shape[:2] + (3,), np.float64)
    for c, i in enumerate(idx):
        band = np.nan_to_num(cube[..., i].astype(np.float64))
        p99 = np.percentile(band, 99)
        rgb[..., c] = band / p99 if p99 > 0 else 0.0
    img = (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)
    Image.fromarray(img, "RGB").save(path, format="PNG")


def _json_dump(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=1, sort_keys=False) + "\n")


PROGRESS_FILE = ".simulate_progress.json"


def _write_progress(out: Path, cfg: SimConfig, done: list[str]) -> None:
    """Record the finished views (atomic replace) so an interrupted run can resume."""
    tmp = out / (PROGRESS_FILE + ".tmp")
    tmp.write_text(json.dumps({"config": cfg.to_json(), "done": done}))
    tmp.replace(out / PROGRESS_FILE)


def _prepare_out(out: Path, overwrite: bool, resume: bool, cfg: SimConfig) -> list[str]:
    """Check/prepare the output folder; returns the views already finished (resume) or []."""
    if out.exists() and not out.is_dir():
        raise UserError("output path exists and is not a folder", file=out)
    if resume and (out / PROGRESS_FILE).is_file():
        state = json.loads((out / PROGRESS_FILE).read_text())
        if SimConfig.from_json(state["config"]) != cfg:
            raise UserError("cannot resume: the folder holds a simulation with other options "
                            f"({state['config']})", file=out / PROGRESS_FILE)
        return list(state["done"])
    if resume and (out / "transforms.json").is_file():
        raise UserError("nothing to resume: the simulation in this folder is complete", file=out)
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise UserError("output folder exists and is not empty; pass --overwrite to replace the "
                            "simulation in it", file=out)
        present = [out / e for e in OUTPUT_ENTRIES if (out / e).exists()]
        others = [p for p in out.iterdir() if p.name not in OUTPUT_ENTRIES]
        if not present and others:
            raise UserError("output folder holds files that a simulation does not write; refusing to "
                            "overwrite it (choose an empty or new folder)", file=out)
        for p in present:
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    out.mkdir(parents=True, exist_ok=True)
    _write_progress(out, cfg, [])
    return []


def simulate(out_dir: str | Path, cfg: SimConfig, overwrite: bool = False, progress: bool = True,
             resume: bool = False) -> Path:
    """Render the acquisition ``cfg`` into the scene folder ``out_dir``; returns its path.

    Raises UserError for bad options or an existing non-empty ``out_dir`` (unless ``overwrite``;
    then only the entries a simulation writes are replaced). Deterministic: the same config
    writes the same bytes. ``transforms.json`` is written last, so a folder without it is an
    interrupted run; ``resume=True`` continues such a run (same config required) and gives the
    same bytes as an uninterrupted one (every view's random numbers depend only on the seed and
    the view).
    """
    cfg.validate()
    out = Path(out_dir)
    done = _prepare_out(out, overwrite, resume, cfg)
    t0 = time.perf_counter()
    geom, rend = _make_renderer(cfg)
    t_setup = time.perf_counter() - t0

    wl = cfg.wavelengths_nm()
    fwhm = cfg.fwhm_array_nm()
    sigma = cfg.sigma_b()
    intr = cfg.intrinsics()
    angles = paper_view_angles(int(cfg.views))

    frames = []
    preview_of: dict[str, np.ndarray] = {}
    timings = []
    it = list(enumerate(angles))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc=f"simulate {cfg.scene}", unit="view")
    for i, (z, a) in it:
        tv = time.perf_counter()
        name = view_name(i, z, a)
        c2w = pose_from_view_angles(z, a, float(cfg.distance_m))
        frames.append({"file_path": f"images/{name}.hdr", "transform_matrix": c2w.tolist(),
                       "view_zenith_deg": float(z), "view_azimuth_deg": float(a),
                       "distance_m": float(cfg.distance_m)})
        is_preview = z == 0.0 or _is_preview_oblique(z, a, angles, cfg)
        if name in done:  # resumed run: this view is complete on disk
            if is_preview:
                preview_of[name] = np.fromfile(out / "images" / f"{name}.img", "<f4").reshape(
                    intr.h, intr.w, len(wl))
            continue
        clean = rend.render_cube(c2w, intr, render_seed(cfg.seed, z, a))
        depth, mat = rend.raycast(c2w, intr)
        rng = np.random.default_rng([int(cfg.seed), 7, i])
        obs = observe(clean, sigma, float(cfg.shot_coeff), rng)
        write_envi(out / "images" / f"{name}.hdr", obs, wl, fwhm)
        write_envi(out / "truth" / "images" / f"{name}.hdr", clean, wl, fwhm)
        (out / "truth" / "depth").mkdir(parents=True, exist_ok=True)
        (out / "truth" / "materials").mkdir(parents=True, exist_ok=True)
        np.save(out / "truth" / "depth" / f"{name}.npy", depth.astype(np.float32))
        np.save(out / "truth" / "materials" / f"{name}.npy", mat.astype(np.int16))
        if is_preview:
            preview_of[name] = obs
        done.append(name)
        _write_progress(out, cfg, done)
        timings.append(time.perf_counter() - tv)

    # dark (black-cover) frames
    dark_paths = []
    for k in range(int(cfg.n_dark)):
        rng = np.random.default_rng([int(cfg.seed), 11, k])
        dark = rng.standard_normal((intr.h, intr.w, len(wl)), dtype=np.float32) * sigma.astype(np.float32)
        rel = f"calibration/dark_{k:02d}.hdr"
        write_envi(out / rel, dark, wl, fwhm)
        dark_paths.append(rel)

    # truth tables
    mats_used = sorted({MATERIAL_IDS[p.material] for p in geom.parts})
    table = {}
    for mid in mats_used:
        name = MATERIAL_NAMES[mid]
        m = rend.materials[name]
        s = rend.band_spectra[name]
        tex_means = [(float(np.mean(e["texture"][0])), float(np.mean(e["texture"][1])))
                     for e in rend._bsdfs if e["material"] == name and e["texture"] is not None]
        if tex_means:  # mean reflectance of the textured material over its first texture
            fm, fn = tex_means[0]
            spectrum = fm * s["end1"] + fn * s["end2"]
        else:
            spectrum = s["end1"]
        entry = {"name": name, "bsdf": m.kind, "spectrum": [round(float(v), 6) for v in spectrum],
                 "description": m.description}
        if s["transmittance"] is not None:
            entry["transmittance"] = [round(float(v), 6) for v in s["transmittance"]]
        if m.kind == "plastic":
            entry["ggx_alpha"] = m.alpha
            entry["ior"] = m.ior
        if tex_means:
            entry["endmember_1"] = [round(float(v), 6) for v in s["end1"]]
            entry["endmember_2"] = [round(float(v), 6) for v in s["end2"]]
            entry["texture"] = "reflectance = brightness(x,y) * (mix(x,y) * endmember_1 + (1 - mix) * endmember_2)"
        table[str(mid)] = entry
    _json_dump(out / "truth" / "materials.json", {
        "wavelengths_nm": [float(w) for w in wl],
        "ids": "material id maps (truth/materials/<name>.npy, int16): id of the surface hit by the ray through "
               "the pixel centre; 0 = nothing hit",
        "materials": table})
    _json_dump(out / "truth" / "sigma.json", {
        "wavelengths_nm": [float(w) for w in wl],
        "dark_sigma": [float(v) for v in sigma],
        "shot_coeff": float(cfg.shot_coeff),
        "model": "observed = clean + N(0, dark_sigma^2) + N(0, shot_coeff^2 * max(clean, 0)); "
                 "dark frames = N(0, dark_sigma^2)"})
    _json_dump(out / "truth" / "scene.json", {
        "config": cfg.to_json(),
        "renderer": {"name": "mitsuba", "version": _mitsuba_version(), "variant": rend.mi.variant(),
                     "integrator": "path", "spp": int(cfg.spp), "sampler": cfg.sampler, "max_depth": int(cfg.max_depth),
                     "reconstruction_filter": "box", "bands_per_pass": 3},
        "illumination": {
            "definition": "reflectance = pi * L / E_down; E_down (horizontal downwelling irradiance) = 1 in "
                          "every band; directional sun + uniform sky over the upper hemisphere",
            "sun_zenith_deg": float(cfg.sun_zenith_deg), "sun_azimuth_deg": float(cfg.sun_azimuth_deg),
            "sky_fraction": [float(v) for v in rend.sky_fraction]},
        "world": "ENU metres, z up, scene centre at the origin; ground extends to +-2000 m",
        "n_triangles": geom.n_triangles(),
        "parts": [{"name": p.name, "material": p.material, "n_triangles": int(len(p.faces))} for p in geom.parts],
        "objects": geom.objects,
        "depth": "truth/depth/<name>.npy: float32 [H, W], metres along the optical axis through the pixel "
                 "centre, NaN where nothing is hit"})

    # previews (observed cubes)
    nadir = next(n for n in preview_of if n.startswith("v00_"))
    _cir_png(out / "preview_cir_nadir.png", preview_of[nadir], wl)
    obl = [n for n in preview_of if n != nadir]
    if obl:
        _cir_png(out / "preview_cir_oblique.png", preview_of[obl[0]], wl)

    transforms = {
        "camera_model": "PINHOLE",
        "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h,
        "wavelengths_nm": [float(w) for w in wl],
        "fwhm_nm": [float(w) for w in fwhm],
        "sun_zenith_deg": float(cfg.sun_zenith_deg),
        "sun_azimuth_deg": float(cfg.sun_azimuth_deg),
        "dark_frames": dark_paths,
        "simulator": {"scene": cfg.scene, "seed": int(cfg.seed), "truth": "truth/"},
        "frames": frames,
    }
    _json_dump(out / "transforms.json", transforms)
    (out / PROGRESS_FILE).unlink(missing_ok=True)
    simulate.last_timing = {"setup_s": t_setup, "view_s": timings, "total_s": time.perf_counter() - t0,
                            "n_triangles": geom.n_triangles()}
    return out


simulate.last_timing = None


def _is_preview_oblique(z: float, a: float, angles, cfg: SimConfig) -> bool:
    """True for the view nearest the sun's specular direction (θ_s, φ_s + 180°) — it shows the glint."""
    from brfgs.data.angles import direction_from_angles_deg

    spec = direction_from_angles_deg(cfg.sun_zenith_deg, cfg.sun_azimuth_deg + 180.0)
    best = max((v for v in angles if v[0] > 0), key=lambda v: float(direction_from_angles_deg(*v) @ spec),
               default=None)
    return best is not None and (z, a) == best


def _mitsuba_version() -> str:
    import mitsuba as mi

    return str(mi.__version__)
