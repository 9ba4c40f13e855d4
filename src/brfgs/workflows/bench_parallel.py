"""``brfgs bench parallel``: the same training in 1 and in N data-parallel processes, alternating in
one run, timed per phase and per step, with the all-reduced bytes per step and the largest
difference between the models.

Each round trains ``cfg`` into ``OUT/n<k>_<r>`` for every process count k (same seed, same global
batch ``views_per_step``; ``threads`` 0 shares the cores out among the processes), reads the
phase timings and the all-reduce volume from run.json, and compares the final model with the
first count's. Reported: median seconds per phase and milliseconds per step of each count, the
ratio to one process (same run), bytes all-reduced per step, CIR PSNR / SAM of every run against
truth, and the largest |difference| between the models: bit-identical only when every process runs
the same number of threads; otherwise rounding differs and the runs drift apart like two runs of
different thread counts (tests/test_train_distributed.py checks the identity).
"""

from __future__ import annotations

import json
import os
import statistics
import time
from dataclasses import replace
from pathlib import Path

from brfgs.analysis.bench import machine_record
from brfgs.evaluation.evaluate import evaluate_run
from brfgs.errors import UserError
from brfgs.model.io import load
from brfgs.train import TrainConfig
from brfgs.train.trainer import train_parallel

__all__ = ["bench_parallel"]

PHASES = ("bands", "init", "autoencoder", "stage1", "stage2")


def _one_run(scene: Path, out: Path, cfg: TrainConfig, nproc: int) -> dict:
    """Train into ``out`` (replaced) in ``nproc`` processes and score the test views (against truth
    where the scene has it); wall time, phase timings, all-reduce bytes, CIR PSNR and SAM."""
    t0 = time.perf_counter()
    train_parallel(nproc, scene, out, cfg, overwrite=True, quiet=True)
    wall = time.perf_counter() - t0
    run = json.loads((out / "run.json").read_text())
    res = evaluate_run(out, scene, write_images=False, progress=False)
    against = res["against"].get("truth") or res["against"]["observed"]
    return {"wall_s": wall, "timings_s": {k: run["timings_s"].get(k) for k in PHASES},
            "steps": {"stage1": run["config"]["stage1_steps"], "stage2": run["config"]["stage2_steps"]},
            "allreduce_bytes_per_step": run.get("data_parallel", {}).get("allreduce_bytes_per_step", {}),
            "n_gaussians": run.get("n_gaussians"), "psnr": against["mean"]["psnr"], "sam": against["mean"]["sam"],
            "against": "truth" if "truth" in res["against"] else "observed"}


def _max_difference(a: Path, b: Path) -> float:
    """Largest |difference| between two model files' tensors (inf when their shapes differ)."""
    ta, tb = load(a)[0], load(b)[0]
    worst = 0.0
    for k in ta:
        if k not in tb or ta[k].shape != tb[k].shape:
            return float("inf")
        if ta[k].numel():
            worst = max(worst, float((ta[k].double() - tb[k].double()).abs().max()))
    return worst


def _summary(runs: list[dict]) -> dict:
    steps = runs[0]["steps"]  # the steps used (scaled to the training views)
    med = {k: statistics.median(r["timings_s"][k] for r in runs) for k in PHASES if runs[0]["timings_s"].get(k)}
    return {"median_phase_s": med, "median_wall_s": statistics.median(r["wall_s"] for r in runs),
            "ms_per_step": {k: 1e3 * med[k] / steps[k] for k in steps if k in med and steps[k]},
            "allreduce_bytes_per_step": runs[-1]["allreduce_bytes_per_step"], "n_gaussians": [r["n_gaussians"] for r in runs],
            "psnr": [r["psnr"] for r in runs], "sam": [r["sam"] for r in runs], "against": runs[-1]["against"]}


def bench_parallel(scene: str | Path, out: str | Path, cfg: TrainConfig, nprocs: tuple[int, ...] = (1, 2),
                   repeats: int = 1) -> dict:
    """Train ``cfg`` on ``scene`` in each process count of ``nprocs``, alternating for ``repeats``
    rounds; returns machine, per-count summaries, ratios to the first count and model differences."""
    scene, out = Path(scene), Path(out)
    bad = [n for n in nprocs if n < 1 or cfg.views_per_step % n]
    if bad:
        raise UserError(f"views_per_step ({cfg.views_per_step}) must be a multiple of every process count "
                        f"(not of {bad})", field="views_per_step")
    load_before = os.getloadavg()
    runs: dict[int, list[dict]] = {n: [] for n in nprocs}
    diffs: dict[int, list[float]] = {n: [] for n in nprocs[1:]}
    for r in range(repeats):
        for n in nprocs:
            runs[n].append(_one_run(scene, out / f"n{n}_{r}", replace(cfg), n))
        for n in nprocs[1:]:
            diffs[n].append(_max_difference(out / f"n{nprocs[0]}_{r}" / "model.safetensors",
                                            out / f"n{n}_{r}" / "model.safetensors"))
    summary = {str(n): _summary(runs[n]) for n in nprocs}
    base = summary[str(nprocs[0])]
    ratios = {str(n): {k: base["median_phase_s"][k] / v for k, v in summary[str(n)]["median_phase_s"].items()
                       if v and k in ("stage1", "stage2")} for n in nprocs[1:]}
    return {"scene": str(scene), "config": cfg.to_dict(), "nprocs": list(nprocs), "repeats": repeats,
            "machine": machine_record(cfg.backend, load_before), "runs": {str(n): v for n, v in runs.items()},
            "summary": summary, "speedup_vs_one": ratios,
            "max_abs_model_difference": {str(n): max(v) for n, v in diffs.items()}}
