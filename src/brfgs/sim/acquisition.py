"""``brfgs simulate``: AIR-BRF-like multi-angle hyperspectral acquisitions of a Mitsuba scene.

Writes a scene folder in the layout of docs/data-format.md (transforms.json, images/, calibration/)
plus truth/ (clean cubes, depth, material ids, material table, σ_b, scene parameters) and
two colour-infrared previews. See :class:`SimConfig` for the options and
:func:`simulate` / :func:`render_views` for the library entry points.

Acquisition (paper §4.1.2): views from :func:`brfgs.data.cameras.paper_view_angles`
(nadir + 12 azimuths × 18/23/38/58°; 13/25/37 views for small presets) or another layout of
rings (``SimConfig.rings_deg``, ``n_azimuths``), 35° field of view,
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
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

from brfgs.data.lock import LOCK_NAME
from brfgs.data import atomic
from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.cameras import pose_from_view_angles
from brfgs.data.cube_io import write_envi
from brfgs.errors import UserError
from brfgs.sim.config import N_DARK_DEFAULT, SAMPLERS, VALID_VIEWS, SimConfig  # noqa: F401  (re-exported)
from brfgs.sim.geometry import build_geometry
from brfgs.sim.materials import MATERIAL_IDS, MATERIAL_NAMES
from brfgs.sim.distort import render_grid, to_distorted
from brfgs.sim.render import BandTripletRenderer
from brfgs.sim import spectra as sp

# what simulate() writes (and what --overwrite may remove); other files in OUT are left alone
OUTPUT_ENTRIES = ("transforms.json", "images", "calibration", "truth", "preview_cir_nadir.png",
                  "preview_cir_oblique.png", ".simulate_progress.json", ".simulate_progress.json.tmp")


def view_name(index: int, zenith_deg: float, azimuth_deg: float) -> str:
    """Frame name ``v<index>_z<zenith>_a<azimuth>`` (e.g. v07_z38_a180)."""
    return f"v{index:02d}_z{int(round(zenith_deg)):02d}_a{int(round(azimuth_deg)) % 360:03d}"


def render_seed(seed: int, zenith_deg: float, azimuth_deg: float) -> int:
    """Monte Carlo seed (uint32) of the view at (zenith, azimuth): a render of the same view
    direction with the same seed reproduces the same samples."""
    key = [int(seed), int(round(zenith_deg * 1000)), int(round((azimuth_deg % 360.0) * 1000))]
    return int(np.random.SeedSequence(key).generate_state(1)[0])


def _make_renderer(cfg: SimConfig, bands=None, spp: int | None = None):
    """The scene's geometry and its Mitsuba renderer (all bands, or ``bands``)."""
    geom = build_geometry(cfg.scene, int(cfg.seed), cfg.texture_resolution())
    wl = cfg.wavelengths_nm()
    fw = cfg.fwhm_array_nm()
    if bands is not None:
        wl, fw = wl[list(bands)], fw[list(bands)]
    ref = _reference_sun(cfg)                      # the fixed sun, or the middle view's of a timed flight
    return geom, BandTripletRenderer(geom, wl, fw, ref["sun_zenith_deg"], ref["sun_azimuth_deg"],
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
    axis), ``material`` [V, H, W] int16, ``sun_visibility`` [V, H, W] uint8 (1 lit, 0 shadowed, 255 nothing hit),
    ``c2w`` [V, 4, 4] (OpenGL), ``intrinsics``, ``wavelengths_nm``.
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
    refl, depth, mats, lit, c2ws = [], [], [], [], []
    it = views
    if progress:
        it = tqdm(views, desc="render views", unit="view")
    for z, a in it:
        c2w = pose_from_view_angles(z, a, dist, target_m)
        refl.append(rend.render_cube(c2w, intr, render_seed(cfg.seed, z, a)))
        d, m = rend.raycast(c2w, intr)
        depth.append(d)
        mats.append(m)
        lit.append(rend.sun_visibility(c2w, intr))
        c2ws.append(c2w)
    wl = cfg.wavelengths_nm() if bands is None else cfg.wavelengths_nm()[list(bands)]
    return {"reflectance": np.stack(refl), "depth": np.stack(depth), "material": np.stack(mats),
            "sun_visibility": np.stack(lit), "c2w": np.stack(c2ws), "intrinsics": intr, "wavelengths_nm": wl}


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
    idx = [int(np.argmin(np.abs(wavelengths_nm - w))) for w in (850.0, 650.0, 550.0)]
    rgb = np.empty(cube.shape[:2] + (3,), np.float64)
    for c, i in enumerate(idx):
        band = np.nan_to_num(cube[..., i].astype(np.float64))
        p99 = np.percentile(band, 99)
        rgb[..., c] = band / p99 if p99 > 0 else 0.0
    img = (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)
    with atomic.atomic_path(path) as tmp:
        Image.fromarray(img, "RGB").save(tmp, format="PNG")


def _json_dump(path: Path, obj) -> None:
    atomic.write_text(path, atomic.json_text(obj, indent=1) + "\n")


PROGRESS_FILE = ".simulate_progress.json"


def _write_progress(out: Path, cfg: SimConfig, done: list[str]) -> None:
    """Record the finished views (atomic replace) so an interrupted run can resume."""
    atomic.write_json(out / PROGRESS_FILE, {"config": cfg.to_json(), "done": done}, indent=None)


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
    if out.is_dir() and any(p.name != LOCK_NAME for p in out.iterdir()):
        if not overwrite:
            raise UserError("output folder exists and is not empty; pass --overwrite to replace the "
                            "simulation in it", file=out)
        present = [out / e for e in OUTPUT_ENTRIES if (out / e).exists()]
        others = [p for p in out.iterdir() if p.name not in OUTPUT_ENTRIES and p.name != LOCK_NAME]
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
    frames, preview_of, timings = _acquire_views(out, cfg, rend, done, progress)
    dark_paths = _write_dark_frames(out, cfg)
    _write_truth_tables(out, cfg, geom, rend)
    wl = cfg.wavelengths_nm()
    # previews (observed cubes)
    nadir = next(n for n in preview_of if n.startswith("v00_"))
    _cir_png(out / "preview_cir_nadir.png", preview_of[nadir], wl)
    obl = [n for n in preview_of if n != nadir]
    if obl:
        _cir_png(out / "preview_cir_oblique.png", preview_of[obl[0]], wl)
    _json_dump(out / "transforms.json", _transforms(cfg, frames, dark_paths))
    (out / PROGRESS_FILE).unlink(missing_ok=True)
    simulate.last_timing = {"setup_s": t_setup, "view_s": timings, "total_s": time.perf_counter() - t0,
                            "n_triangles": geom.n_triangles()}
    return out


def _acquire_views(out: Path, cfg: SimConfig, rend, done: list[str], progress: bool):
    """Render, observe and write every view not in ``done`` (appended to as views finish, with the
    progress file). Returns (frames of transforms.json, {name: observed cube} of the preview views,
    seconds per rendered view)."""
    wl = cfg.wavelengths_nm()
    fwhm = cfg.fwhm_array_nm()
    sigma = cfg.sigma_b()
    intr = cfg.intrinsics()
    angles = cfg.view_angles()
    sun_z, sun_a = cfg.view_suns()                       # the sun may move over the flight
    times = cfg.view_times()
    scales = cfg.irradiance_scales()                     # downwelling irradiance drift
    grid, maps = (intr, None) if cfg.distortion is None else render_grid(intr, cfg.distortion)
    frames = []
    preview_of: dict[str, np.ndarray] = {}
    timings = []
    it = list(enumerate(angles))
    if progress:
        it = tqdm(it, desc=f"simulate {cfg.scene}", unit="view")
    for i, (z, a) in it:
        tv = time.perf_counter()
        name = view_name(i, z, a)
        c2w = pose_from_view_angles(z, a, float(cfg.distance_m))
        frames.append({"file_path": f"images/{name}.hdr", "transform_matrix": c2w.tolist(),
                       "view_zenith_deg": float(z), "view_azimuth_deg": float(a),
                       "distance_m": float(cfg.distance_m),
                       **({"time": times[i]} if times else {}),
                       **({"irradiance_scale": float(scales[i])} if cfg.irradiance_drift > 0 else {})})
        is_preview = z == 0.0 or _is_preview_oblique(z, a, angles, cfg)
        if name in done:  # resumed run: this view is complete on disk
            if is_preview:
                preview_of[name] = np.fromfile(out / "images" / f"{name}.img", "<f4").reshape(
                    intr.h, intr.w, len(wl))
            continue
        rend.set_sun(float(sun_z[i]), float(sun_a[i]))
        clean = rend.render_cube(c2w, grid, render_seed(cfg.seed, z, a))
        depth, mat = rend.raycast(c2w, grid)
        lit = rend.sun_visibility(c2w, grid)
        if maps is not None:                             # an OPENCV lens: the pinhole render resampled
            clean, depth = to_distorted(clean, maps), to_distorted(depth.astype(np.float32), maps)
            mat = to_distorted(mat.astype(np.float32), maps, nearest=True).astype(np.int16)
            lit = np.nan_to_num(to_distorted(lit.astype(np.float32), maps, nearest=True), nan=255).astype(np.uint8)
        rng = np.random.default_rng([int(cfg.seed), 7, i])
        obs = observe(clean * np.float32(scales[i]), sigma, float(cfg.shot_coeff), rng)
        write_envi(out / "images" / f"{name}.hdr", obs, wl, fwhm)
        write_envi(out / "truth" / "images" / f"{name}.hdr", clean, wl, fwhm)
        (out / "truth" / "depth").mkdir(parents=True, exist_ok=True)
        (out / "truth" / "materials").mkdir(parents=True, exist_ok=True)
        atomic.save_npy(out / "truth" / "depth" / f"{name}.npy", depth.astype(np.float32))
        atomic.save_npy(out / "truth" / "materials" / f"{name}.npy", mat.astype(np.int16))
        (out / "truth" / "sun_visibility").mkdir(parents=True, exist_ok=True)
        atomic.save_npy(out / "truth" / "sun_visibility" / f"{name}.npy", lit)
        if is_preview:
            preview_of[name] = obs
        done.append(name)
        _write_progress(out, cfg, done)
        timings.append(time.perf_counter() - tv)
    return frames, preview_of, timings


def _write_dark_frames(out: Path, cfg: SimConfig) -> list[str]:
    """Dark (black-cover) frames N(0, σ_b²); returns their paths relative to ``out``."""
    wl = cfg.wavelengths_nm()
    fwhm = cfg.fwhm_array_nm()
    sigma = cfg.sigma_b()
    intr = cfg.intrinsics()
    dark_paths = []
    for k in range(int(cfg.n_dark)):
        rng = np.random.default_rng([int(cfg.seed), 11, k])
        dark = rng.standard_normal((intr.h, intr.w, len(wl)), dtype=np.float32) * sigma.astype(np.float32)
        rel = f"calibration/dark_{k:02d}.hdr"
        write_envi(out / rel, dark, wl, fwhm)
        dark_paths.append(rel)
    return dark_paths


def _material_table(geom, rend) -> dict:
    """truth/materials.json "materials": BSDF, band spectra and texture model of each material used."""
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
    return table


def _write_truth_tables(out: Path, cfg: SimConfig, geom, rend) -> None:
    """truth/materials.json, truth/sigma.json and truth/scene.json."""
    wl = cfg.wavelengths_nm()
    sigma = cfg.sigma_b()
    _json_dump(out / "truth" / "materials.json", {
        "wavelengths_nm": [float(w) for w in wl],
        "ids": "material id maps (truth/materials/<name>.npy, int16): id of the surface hit by the ray through "
               "the pixel centre; 0 = nothing hit",
        "materials": _material_table(geom, rend)})
    _json_dump(out / "truth" / "sigma.json", {
        "wavelengths_nm": [float(w) for w in wl],
        "dark_sigma": [float(v) for v in sigma],
        "shot_coeff": float(cfg.shot_coeff),
        "model": "observed = clean + N(0, dark_sigma^2) + N(0, shot_coeff^2 * max(clean, 0)); "
                 "dark frames = N(0, dark_sigma^2)"})
    _json_dump(out / "truth" / "scene.json", {
        "config": cfg.to_json(),
        "renderer": {"name": "mitsuba", "version": str(rend.mi.__version__), "variant": rend.mi.variant(),
                     "integrator": "path", "spp": int(cfg.spp), "sampler": cfg.sampler, "max_depth": int(cfg.max_depth),
                     "reconstruction_filter": "box", "bands_per_pass": 3},
        "illumination": {
            "definition": "reflectance = pi * L / E_down; E_down (horizontal downwelling irradiance) = 1 in "
                          "every band; directional sun + uniform sky over the upper hemisphere",
            **_reference_sun(cfg),
            "view_suns_deg": [[float(z), float(a)] for z, a in zip(*cfg.view_suns())],
            "irradiance_scales": [float(v) for v in cfg.irradiance_scales()],
            "sky_fraction": [float(v) for v in rend.sky_fraction]},
        "world": "ENU metres, z up, scene centre at the origin; ground extends to +-2000 m",
        "n_triangles": geom.n_triangles(),
        "parts": [{"name": p.name, "material": p.material, "n_triangles": int(len(p.faces))} for p in geom.parts],
        "objects": geom.objects,
        "depth": "truth/depth/<name>.npy: float32 [H, W], metres along the optical axis through the pixel "
                 "centre, NaN where nothing is hit",
        "sun_visibility": "truth/sun_visibility/<name>.npy: uint8 [H, W], direct sun at the surface through the "
                          "pixel centre under that view's sun: 1 lit, 0 shadowed by the scene's geometry (leaves "
                          "block it entirely), 255 where nothing is hit"})


def _reference_sun(cfg: SimConfig) -> dict:
    """The top-level sun of transforms.json: the fixed sun, or the middle view's when it moves."""
    z, a = cfg.view_suns()
    k = len(z) // 2 if cfg.start_time is not None else 0
    return {"sun_zenith_deg": float(z[k]), "sun_azimuth_deg": float(a[k])}


def _transforms(cfg: SimConfig, frames: list[dict], dark_paths: list[str]) -> dict:
    """Content of transforms.json (docs/data-format.md)."""
    intr = cfg.intrinsics()
    return {
        "camera_model": "PINHOLE" if cfg.distortion is None else "OPENCV",
        **({} if cfg.distortion is None else dict(zip(("k1", "k2", "p1", "p2"), map(float, cfg.distortion)))),
        "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h,
        "wavelengths_nm": [float(w) for w in cfg.wavelengths_nm()],
        "fwhm_nm": [float(w) for w in cfg.fwhm_array_nm()],
        **_reference_sun(cfg),
        "dark_frames": dark_paths,
        "diffuse_fraction": [round(float(v), 6) for v in sp.sky_fraction(cfg.wavelengths_nm())],
        **({"origin": cfg.origin_json()} if cfg.origin is not None else {}),
        "simulator": {"scene": cfg.scene, "seed": int(cfg.seed), "truth": "truth/"},
        "frames": frames,
    }


simulate.last_timing = None


def _is_preview_oblique(z: float, a: float, angles, cfg: SimConfig) -> bool:
    """True for the view nearest the sun's specular direction (θ_s, φ_s + 180°) — it shows the glint."""
    spec = direction_from_angles_deg(cfg.sun_zenith_deg, cfg.sun_azimuth_deg + 180.0)
    best = max((v for v in angles if v[0] > 0), key=lambda v: float(direction_from_angles_deg(*v) @ spec),
               default=None)
    return best is not None and (z, a) == best
