"""What one arbitrary view of each of two trained models costs, alternated in one run (a ratio, not a time).

Each model renders at its own sampling (``supersample`` in its metadata: a ``--preset fine`` model
rasterizes 2 × 2 sub-pixels per pixel). One view at 37° zenith / 65° azimuth, every band decoded and
normals drawn, as the viewer, ``brfgs render`` and the products do.

    python scripts/view_cost.py RUN_A RUN_B [--size 128] [--repeats 9] [--threads 2]

Prints per model the median ms, its rasterization and decode parts, and the ratio B / A.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numba
import torch

from brfgs.analysis.bench import bench_camera
from brfgs.model import TrainedModel, camera_from_intrinsics, render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_a")
    ap.add_argument("run_b")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    numba.set_num_threads(args.threads)
    torch.set_num_threads(args.threads)
    runs = (args.run_a, args.run_b)
    models = {r: TrainedModel.load(r) for r in runs}
    cams = {r: camera_from_intrinsics(*bench_camera(models[r], args.size)) for r in runs}
    for r in runs:  # warm-up (numba compilation, allocator)
        for _ in range(2):
            render(models[r], cams[r], normals=True, backend="cpu")
    total = {r: [] for r in runs}
    parts = {r: [] for r in runs}
    for _ in range(args.repeats):
        for r in runs:
            t0 = time.perf_counter()
            out = render(models[r], cams[r], normals=True, backend="cpu")
            total[r].append(time.perf_counter() - t0)
            parts[r].append(out.timings_s)
    print(f"{args.size}² view, {args.threads} thread(s), median of {args.repeats}; load {os.getloadavg()[0]:.2f}")
    for r in runs:
        ras = statistics.median(p["rasterize_s"] for p in parts[r]) * 1e3
        dec = statistics.median(p["decode_s"] for p in parts[r]) * 1e3
        print(f"{r}: supersample {models[r].render_settings.supersample}, {models[r].n_gaussians} Gaussians: "
              f"{statistics.median(total[r]) * 1e3:.1f} ms (rasterize {ras:.1f}, decode {dec:.1f})")
    print(f"ratio B / A: {statistics.median(total[runs[1]]) / statistics.median(total[runs[0]]):.2f}")


if __name__ == "__main__":
    main()
