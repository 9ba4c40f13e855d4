"""Time COLMAP exhaustive matching (plain + guided, as `brfgs init --poses sfm` runs it) with one
matching thread against all threads, on one scene, alternating the two settings in one run.

    python benchmarks/sfm_matching_threads.py SCENE [--repeats 3] [--bands 106,109,110]

Prints per-repeat seconds, the median of each setting and their ratio, and whether each setting
gave the same verified matches in every repeat (InitConfig.match_threads = 1 is the default
because with several threads COLMAP's two-view RANSAC depends on thread scheduling).
"""
from __future__ import annotations

import zlib  # noqa: F401  (before pycolmap: see tests/test_init_sfm.py)
import argparse
import json
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from brfgs.data.scene import read_scene
from brfgs.init.api import InitConfig, extract_features, match_features


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--bands", default="106,109,110", help="band indices (default: the EFC top-3 of testsite 128)")
    args = ap.parse_args()
    bands = [int(b) for b in args.bands.split(",")]
    scene = read_scene(args.scene)
    base = InitConfig()
    t0 = time.perf_counter()
    feats, _, _ = extract_features(scene, bands, base, keep_cubes=False)
    print(f"features: {time.perf_counter() - t0:.1f} s for {len(feats)} views")
    times = {1: [], -1: []}
    results = {1: [], -1: []}
    with tempfile.TemporaryDirectory(prefix="brfgs_matchbench_") as tmp:
        for rep in range(args.repeats):
            for threads in (1, -1):
                cfg = replace(base, match_threads=threads)
                work = Path(tmp) / f"r{rep}_t{threads}"
                t1 = time.perf_counter()
                _, _, plain = match_features(scene, feats, work, cfg)
                _, _, guided = match_features(scene, feats, work / "guided", cfg, guided=True)
                dt = time.perf_counter() - t1
                times[threads].append(dt)
                key = (plain.verified_total, guided.verified_total, tuple(int(v) for v in guided.verified_per_image))
                results[threads].append(key)
                print(f"repeat {rep} threads {threads:>2}: {dt:6.1f} s, verified plain {plain.verified_total}, "
                      f"guided {guided.verified_total}", flush=True)
    med = {k: statistics.median(v) for k, v in times.items()}
    summary = {
        "median_s_1_thread": med[1], "median_s_all_threads": med[-1], "ratio_1_over_all": med[1] / med[-1],
        "identical_across_repeats_1_thread": len(set(results[1])) == 1,
        "identical_across_repeats_all_threads": len(set(results[-1])) == 1,
    }
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
