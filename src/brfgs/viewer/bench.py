"""``brfgs bench viewer``: time the viewer's interaction frame (one display frame, 256² by default)."""

from __future__ import annotations

import math
import os
import statistics
import time
from pathlib import Path

from brfgs.analysis.bench import machine_record, synthetic_model
from brfgs.analysis.views import view_camera
from brfgs.model import TrainedModel
from brfgs.viewer.frames import parse_mode, render_frame

__all__ = ["bench_viewer"]


def bench_viewer(model: str | Path | None = None, *, n_gaussians: int = 50_000, size: int = 256,
                 modes: tuple[str, ...] = ("cir", "depth", "index", "kernel:geo"), repeats: int = 7,
                 backend: str = "cpu") -> dict:
    """Median wall and CPU seconds of one ``size``² display frame per mode (after one warm-up frame),
    from an oblique camera (view zenith 37°, azimuth 65°) at the training cameras' distance with
    their field of view; the model from ``model`` or a synthetic one of ``n_gaussians``."""
    tm = TrainedModel.load(model) if model is not None else synthetic_model(n_gaussians)
    fov_deg = 2 * math.degrees(math.atan(0.5 * tm.intrinsics.w / tm.intrinsics.fl_x))
    c2w, intr = view_camera(37.0, 65.0, tm.typical_distance_m(), tm.scene_centre_m(), size=size, fov_deg=fov_deg)
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
    return {"machine": machine_record(backend, load_before),
            "model": "synthetic" if model is None else str(model), "n_gaussians": tm.n_gaussians,
            "bands": len(tm.wavelengths_nm), "size": [intr.w, intr.h], "repeats": repeats, "modes": rows}
