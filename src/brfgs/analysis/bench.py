"""Speed of the analysis: one arbitrary 164-band view, and a polar BRF map of one ROI.

Measured on a trained model (``model``: run folder or model file) or, without one, on a
synthetic model of the same shape as a 128-px testsite run: ``n_gaussians`` Gaussians
over a 120 m × 120 m undulating surface with tree-like clusters, latent d = 16, a
164-band spectral autoencoder (untrained weights: the cost does not depend on them).
Reported: the median of ``repeats`` runs after one warm-up (numba loads its compiled
kernels on first use). ``bench view`` also times the same model with a linear spectral basis
(D(z) = W z + b, :mod:`brfgs.spectral.linear_basis`) of the same latent size: fitted to the
autoencoder's decoded spectra of the model's own Gaussians' isotropic latents (random latents for
the synthetic model); a model that has a linear basis is timed against an untrained autoencoder of
the same size (the decoders' cost does not depend on their weights).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import platform
import resource
import statistics
import time
from pathlib import Path
from typing import Callable

import numba
import numpy as np
import torch

from brfgs.analysis.brf import auto_roi_size, polar_map
from brfgs.model.shadows import gaussian_sun_visibility
from brfgs.model.view import sun_visibility_map
from brfgs.analysis.roi import PolygonROI
from brfgs.analysis.threads import torch_threads
from brfgs.analysis.views import intrinsics_json, view_camera
from brfgs.brdf.head import HeadConfig, init_head_params
from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from brfgs.model.gaussians import GaussianModel
from brfgs.render.bench import accelerator_record
from brfgs.spectral.autoencoder import SpectralAutoencoder, spectral_angle_torch
from brfgs.spectral.decoders import is_linear
from brfgs.spectral.fast_decode import reference_decoding
from brfgs.spectral.linear_basis import fit_linear_basis

__all__ = ["synthetic_model", "bench_camera", "bench_analysis", "bench_view"]


def _synthetic_gaussians(n_gaussians: int, latent_dim: int, seed: int) -> tuple[GaussianModel, HeadConfig]:
    """Ground (80 %) on an undulating 120 m square and 40 tree crowns (20 %), hybrid head (all terms)."""
    rng = np.random.default_rng(seed)
    n_ground = int(0.8 * n_gaussians)
    xy = rng.uniform(-60, 60, (n_ground, 2))
    z = 0.3 * np.sin(xy[:, 0] / 9.0) * np.cos(xy[:, 1] / 7.0)
    trees = rng.uniform(-50, 50, (40, 2))
    k = n_gaussians - n_ground
    c = trees[rng.integers(0, 40, k)]
    crown = c + rng.normal(0, 2.0, (k, 2))
    cz = 7.0 + rng.normal(0, 1.5, k)
    means = np.concatenate([np.c_[xy, z], np.c_[crown, cz]]).astype(np.float32)
    n = len(means)
    scales = np.concatenate([np.tile([0.45, 0.45, 0.05], (n_ground, 1)), np.full((k, 3), 0.3)]).astype(np.float32)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q[:n_ground] = [1, 0, 0, 0]
    cfg = HeadConfig(kind="hybrid")
    g = torch.Generator().manual_seed(seed)
    head = init_head_params(cfg, n, latent_dim, z_init=torch.randn(n, latent_dim, generator=g))
    for key in ("z_vol", "z_geo", "z_spec"):
        head[key] = 0.1 * torch.randn(n, latent_dim, generator=g)
    params = {"means": torch.from_numpy(means), "log_scales": torch.from_numpy(np.log(scales)),
              "quats": torch.from_numpy(q), "opacity_logits": torch.full((n,), 3.0), "colors": torch.zeros(n, 3)}
    params.update(head)
    gm = GaussianModel(params, "brf", latent_dim, 3)
    for v in gm.params.values():
        v.requires_grad_(False)
    return gm, cfg


def synthetic_model(n_gaussians: int = 50_000, n_bands: int = 164, latent_dim: int = 16, seed: int = 0
                    ) -> TrainedModel:
    """A deterministic synthetic BRF-GS model (hybrid head with all four terms) for timing."""
    gm, cfg = _synthetic_gaussians(n_gaussians, latent_dim, seed)
    torch.manual_seed(seed)
    ae = SpectralAutoencoder(n_bands, latent_dim).eval()
    intr = Intrinsics.from_fov(35.0, 128, 128)
    frames = [{"name": f"v{i}", "split": "train", "c2w": pose_from_view_angles(z_, a_, 190.0).tolist(),
               "view_zenith_deg": z_, "view_azimuth_deg": a_}
              for i, (z_, a_) in enumerate([(0.0, 0.0), (38.0, 0.0), (38.0, 180.0)])]
    scene = {"name": "synthetic", "root": None, "wavelengths_nm": np.linspace(350.0, 1000.0, n_bands).tolist(),
             "fwhm_nm": None, "sun_zenith_deg": 35.0, "sun_azimuth_deg": 150.0,
             "intrinsics": intrinsics_json(intr),
             "frames": frames}
    extra = {"bg_latent": torch.zeros(latent_dim), "bg_colors": torch.zeros(gm.n_colors)}  # zero backgrounds
    return TrainedModel(gaussians=gm, head_cfg=cfg, decoder=ae, scene=scene, config={"variant": "brf"}, extra=extra,
                        meta={"cir_indices": [123, 76, 50], "cir_scale": [1.0, 1.0, 1.0]})


def bench_camera(tm: TrainedModel, size: int):
    """The benchmarks' arbitrary view: zenith 37°, azimuth 65°, at the training cameras' typical distance
    with their horizontal field of view, ``size``² pixels. Returns (c2w [4, 4], Intrinsics)."""
    fov_deg = 2 * math.degrees(math.atan(0.5 * tm.intrinsics.w / tm.intrinsics.fl_x))
    return view_camera(37.0, 65.0, tm.typical_distance_m(), tm.scene_centre_m(), size=size, fov_deg=fov_deg)


def _timed(fn: Callable[[], object], repeats: int) -> tuple[list[float], list[float]]:
    """(wall seconds, CPU seconds of this process) of ``repeats`` calls of ``fn``."""
    ts, cs = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return ts, cs


def machine_record(backend: str, load_before: tuple[float, float, float]) -> dict:
    """Machine, threads, backend and load averages before and after a benchmark (its JSON record)."""
    return {"platform": platform.platform(), "processor": platform.processor(), "cpu_count": os.cpu_count(),
            **accelerator_record(),
            "torch_threads": torch.get_num_threads(), "numba_threads": numba.get_num_threads(), "backend": backend,
            "openmp_env": {k: os.environ[k] for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT") if k in os.environ},
            "load_average_1_5_15_before": list(load_before), "load_average_1_5_15_after": list(os.getloadavg())}


def bench_analysis(
    model: str | Path | None = None,
    *,
    n_gaussians: int = 50_000,
    size: int = 128,
    repeats: int = 5,
    polar_azimuths: int = 60,
    polar_zeniths: int = 24,
    polar_repeats: int = 1,
    roi_half_m: float = 5.0,
    roi_size_px: int | None = None,
    bands: tuple[float, ...] = (480.0, 680.0, 760.0, 860.0),
    backend: str = "cpu",
    loop_threads: int = 1,
) -> dict:
    """Time one arbitrary view (decoded, all bands), its shadow map (:mod:`brfgs.model.shadows`, the sun
    visibility included) and one polar map (4 bands); returns a dict."""
    tm = TrainedModel.load(model) if model is not None else synthetic_model(n_gaussians)
    c2w, intr = bench_camera(tm, size)
    cam = camera_from_intrinsics(c2w, intr)
    load_before = os.getloadavg()
    def view():  # the view as `brfgs render` makes it: cube, CIR, depth and normals
        return render(tm, cam, normals=True, backend=backend)

    view()  # warm-up: numba loads its compiled kernels
    all_, cpu = _timed(view, repeats)
    rv = view()
    view_threads = {"torch": torch.get_num_threads(), "numba": numba.get_num_threads()}
    orders = {}  # the same view in both decode orders (docs/method.md), same run
    if tm.spectral:
        for order in ("pixel", "gaussian"):
            t, _ = _timed(lambda o=order: render(tm, cam, normals=True, backend=backend, decode_order=o), repeats)
            orders[order] = statistics.median(t)
        orders["gaussian_over_pixel"] = orders["gaussian"] / orders["pixel"]
    shadow_s, _ = _timed(lambda: sun_visibility_map(tm, cam, gaussian_sun_visibility(tm, tm.sun_zenith_deg,
                         tm.sun_azimuth_deg, backend=backend), backend=backend), repeats)  # `brfgs render`'s shadow map
    c = tm.scene_centre_m()
    h = roi_half_m
    roi = PolygonROI(np.array([[c[0] - h, c[1] - h], [c[0] + h, c[1] - h], [c[0] + h, c[1] + h], [c[0] - h, c[1] + h]]))
    bi = tm.band_indices(bands)

    def pm():
        with torch_threads(loop_threads or None):
            polar_map(tm, roi, bi, n_azimuth=polar_azimuths, n_zenith=polar_zeniths, size=roi_size_px,
                      backend=backend)

    pts, pcs = _timed(pm, polar_repeats)
    return {
        "machine": {**machine_record(backend, load_before), "torch_threads": view_threads["torch"],
                    "numba_threads": view_threads["numba"]},
        "model": "synthetic" if model is None else str(model), "n_gaussians": tm.n_gaussians,
        "bands": len(tm.wavelengths_nm), "latent_dim": tm.gaussians.latent_dim,
        "render": {"size": [intr.w, intr.h], "median_s": statistics.median(all_), "all_s": all_, "cpu_s": cpu,
                   "median_cpu_s": statistics.median(cpu), "repeats": repeats, "split_s": rv.timings_s,
                   "decode_order": tm.render_settings.decode_order, "median_s_by_decode_order": orders},
        "shadow_map": {"median_s": statistics.median(shadow_s), "all_s": shadow_s,
                       "over_view": statistics.median(shadow_s) / statistics.median(all_)},
        "polar_map": {"directions": polar_azimuths * polar_zeniths, "bands": len(bi),
                      "roi_camera_px": roi_size_px or auto_roi_size(tm, 1.1 * roi.radius_m),
                      "median_s": statistics.median(pts), "all_s": pts, "cpu_s": pcs,
                      "median_cpu_s": statistics.median(pcs),
                      "per_direction_ms": 1000 * statistics.median(pts) / (polar_azimuths * polar_zeniths),
                      "torch_threads_in_loop": loop_threads},
    }


def _peak_rss_mib() -> float:
    """Peak resident memory of this process (VmHWM: unlike ru_maxrss, not inherited across exec)."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024.0
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _bases(tm: TrainedModel, seed: int = 0, max_spectra: int = 20_000) -> tuple[TrainedModel, TrainedModel, dict]:
    """(the model with the autoencoder, the model with a linear basis, how the other one was made)."""
    d, n_bands = tm.gaussians.latent_dim, len(tm.wavelengths_nm)
    if is_linear(tm.decoder):
        torch.manual_seed(seed)
        ae = SpectralAutoencoder(n_bands, d).eval().requires_grad_(False)
        return dataclasses.replace(tm, decoder=ae), tm, {"autoencoder": "untrained, same size (cost only)"}
    params = tm.head_params()
    g = torch.Generator().manual_seed(seed)
    if "z_iso" in params:
        z, source = params["z_iso"], "the autoencoder's decoded spectra of the model's Gaussians' z_iso"
        z = z[torch.randperm(z.shape[0], generator=g)[:max_spectra]]
    else:
        z, source = torch.randn(max_spectra, d, generator=g), "the autoencoder's decoded spectra of N(0, 1) latents"
    with torch.no_grad():
        spectra = tm.decoder.decode(z.float())
        basis = fit_linear_basis(spectra.double().numpy(), d).requires_grad_(False)
        sam = spectral_angle_torch(basis(spectra)[0].double(), spectra.double())
    info = {"linear_basis": source, "n_spectra": int(z.shape[0]), "linear_fit_sam_mean_rad": float(sam.mean())}
    return tm, dataclasses.replace(tm, decoder=basis), info


def _view_rounds(tm: TrainedModel, cam, repeats: int, backend: str, linear: TrainedModel | None = None) -> dict:
    """Alternating rounds of the view with the fused decoder, the reference decoder and (``linear``: the
    same model with a linear basis) the linear basis, under the same load; medians of wall time and of
    the render's own split, and their ratios."""
    models = {"fused": tm, "reference": tm} if linear is None else {"fused": tm, "reference": tm, "linear": linear}

    def view(name):
        with reference_decoding() if name == "reference" else contextlib.nullcontext():
            return render(models[name], cam, normals=True, backend=backend)

    first = {name: view(name) for name in models}                 # warm-ups, and the results compared
    times = {name: [] for name in models}
    split = {name: [] for name in models}
    for _ in range(repeats):
        for name in models:
            t0 = time.perf_counter()
            rv = view(name)
            times[name].append(time.perf_counter() - t0)
            split[name].append(rv.timings_s)
    out = {name: {"median_s": statistics.median(t), "all_s": t,
                  "median_rasterize_s": statistics.median(x["rasterize_s"] for x in split[name]),
                  "median_decode_s": statistics.median(x["decode_s"] for x in split[name])}
           for name, t in times.items()}
    out["speedup_vs_reference"] = out["reference"]["median_s"] / out["fused"]["median_s"]
    out["decode_speedup_vs_reference"] = out["reference"]["median_decode_s"] / out["fused"]["median_decode_s"]
    cube = first["fused"].cube
    out["max_abs_diff_vs_reference"] = float(np.abs(cube - first["reference"].cube).max()) if cube is not None else None
    if linear is not None:
        out["linear_speedup_vs_fused"] = out["fused"]["median_s"] / out["linear"]["median_s"]
        out["linear_decode_speedup_vs_fused"] = out["fused"]["median_decode_s"] / out["linear"]["median_decode_s"]
    return out


def _simulator_view_s(size: int, n_bands: int) -> float:
    """Wall seconds of the project's Mitsuba simulator rendering one view of the testsite at ``size``² and
    ``n_bands`` bands (its default 64 spp), the ray-traced reference of the paper's speed comparison."""
    from brfgs.sim import SimConfig, render_views  # lazy: the simulator loads Mitsuba (optional extra)

    t0 = time.perf_counter()
    render_views(SimConfig(size=size, bands=n_bands), [(37.0, 65.0)])
    return time.perf_counter() - t0


def bench_view(model: str | Path | None = None, *, n_gaussians: int = 50_000, sizes: tuple[int, ...] = (128,),
               repeats: int = 5, backend: str = "cpu", simulator: bool = False) -> dict:
    """Time one arbitrary 164-band view (cube, CIR, depth, normals) per size, with the fused decoder, the
    reference decoder and a linear spectral basis of the same size in alternating rounds of the same run
    (module docstring); optionally the simulator's time for the same view size and bands. Returns a
    JSON-ready dict."""
    tm = TrainedModel.load(model) if model is not None else synthetic_model(n_gaussians)
    load_before = os.getloadavg()
    bases = None
    if tm.spectral:
        ae_model, linear_model, bases = _bases(tm)
    rows = []
    for size in sizes:
        c2w, intr = bench_camera(tm, size)
        cam = camera_from_intrinsics(c2w, intr)
        rounds = _view_rounds(ae_model, cam, repeats, backend, linear_model) if tm.spectral else \
            _view_rounds(tm, cam, repeats, backend)
        row = {"size": [intr.w, intr.h], **rounds}
        if simulator and tm.spectral:
            row["simulator_view_s"] = _simulator_view_s(size, len(tm.wavelengths_nm))
            row["speedup_vs_simulator"] = row["simulator_view_s"] / row["fused"]["median_s"]
        rows.append(row)
    return {"machine": machine_record(backend, load_before), "model": "synthetic" if model is None else str(model),
            "n_gaussians": tm.n_gaussians, "bands": len(tm.wavelengths_nm), "latent_dim": tm.gaussians.latent_dim,
            "repeats": repeats, "bases": bases, "views": rows, "peak_rss_mib": _peak_rss_mib()}
