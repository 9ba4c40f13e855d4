"""``brfgs bench viewer``: time the viewer's interaction frame (one display frame, 256² by default)."""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from brfgs.analysis.bench import bench_camera, machine_record, synthetic_model
from brfgs.model import TrainedModel
from brfgs.model import camera_from_intrinsics, render
from brfgs.spectral.band_decode import decode_bands
from brfgs.viewer.frames import DisplayMode, mode_bands, parse_mode, render_frame

__all__ = ["bench_viewer"]


def _decode_times(tm: TrainedModel, c2w, intr, mode: DisplayMode, backend: str, repeats: int) -> dict:
    """The mode's band decoding alone on the frame's latents, alternating with the reference (the full
    decode, then the bands taken): median seconds of both, their ratio and the largest difference."""
    z = torch.as_tensor(render(tm, camera_from_intrinsics(np.asarray(c2w, float), intr), decode=False,
                               backend=backend).latent)
    bands = mode_bands(tm, mode)
    fast, ref = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        a = decode_bands(tm.decoder, z, bands)
        t1 = time.perf_counter()
        with torch.no_grad():
            b = tm.decoder.decode(z)[..., bands]
        fast.append(t1 - t0)
        ref.append(time.perf_counter() - t1)
    return {"bands": bands, "median_s": statistics.median(fast), "reference_median_s": statistics.median(ref),
            "speedup_vs_reference": statistics.median(ref) / statistics.median(fast),
            "max_abs_difference": float((a - b).abs().max())}


def bench_viewer(model: str | Path | None = None, *, n_gaussians: int = 50_000, size: int = 256,
                 modes: tuple[str, ...] = ("cir", "depth", "index", "kernel:geo"), repeats: int = 7,
                 backend: str = "cpu") -> dict:
    """Median wall and CPU seconds of one ``size``² display frame per mode (after one warm-up frame)
    and, for the spectral modes, of their band decoding against the full decode (same run),
    from an oblique camera (view zenith 37°, azimuth 65°) at the training cameras' distance with
    their field of view; the model from ``model`` or a synthetic one of ``n_gaussians``."""
    tm = TrainedModel.load(model) if model is not None else synthetic_model(n_gaussians)
    c2w, intr = bench_camera(tm, size)
    load_before = os.getloadavg()
    rows = {}
    for text in modes:
        mode = parse_mode(text)
        render_frame(tm, c2w, intr, mode, backend=backend)  # warm-up: numba loads its kernels
        wall, cpu = [], []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            render_frame(tm, c2w, intr, mode, backend=backend)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        rows[text] = {"median_s": statistics.median(wall), "all_s": wall, "median_cpu_s": statistics.median(cpu)}
        if mode.needs_cube and tm.spectral and tm.render_settings.decode_order != "gaussian":
            rows[text]["decode"] = _decode_times(tm, c2w, intr, mode, backend, repeats)
    return {"machine": machine_record(backend, load_before),
            "model": "synthetic" if model is None else str(model), "n_gaussians": tm.n_gaussians,
            "bands": len(tm.wavelengths_nm), "size": [intr.w, intr.h], "repeats": repeats, "modes": rows}
