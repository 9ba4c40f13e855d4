"""``brfgs bench manifest``: the time of ``brfgs batch MANIFEST --dry-run`` for a manifest of many scenes.

The synthetic manifest lists N scene folders (each holds a transforms.json, all a dry run reads of
a scene), with the options a real campaign gives: defaults for every scene, a seed per scene, every
tenth scene its own step counts, every hundredth its own output folder outside the output root and
a table of densification options. The dry run (:func:`brfgs.workflows.batch_plan.dry_run`: read, check
every option and path, plan every scene) is timed in this process, without the interpreter's start.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

from brfgs.workflows.batch_plan import dry_run
from brfgs.workflows.options import BatchConfig

DEFAULTS = """out = "runs"

[defaults]
preset = "fast"
poses = "known"
num_cpus = 1
[defaults.products]
size = 64
mcd43 = false
"""


def write_manifest(folder: Path, n: int) -> Path:
    """``folder``/manifest.toml listing ``n`` scene folders ``folder``/scenes/sNNNNNN (created)."""
    parts = [DEFAULTS]
    for i in range(n):
        scene = folder / "scenes" / f"s{i:06d}"
        scene.mkdir(parents=True)
        (scene / "transforms.json").write_text('{"frames": []}\n')
        parts.append(f'\n[[scene]]\nscene = "scenes/s{i:06d}"\nseed = {i}\n')
        if i % 10 == 3:
            parts.append(f"stage1_steps = {1000 + i % 7}\nstage2_steps = {500 + i % 5}\n")
        if i % 100 == 7:
            parts.append(f'out = "elsewhere/s{i:06d}"\n[scene.densify]\nrefine_every = {50 + i % 3}\n')
    path = folder / "manifest.toml"
    path.write_text("".join(parts))
    return path


def bench_manifest(n_scenes: int, repeats: int) -> dict:
    """Median seconds of the dry run of a synthetic manifest of ``n_scenes`` scenes (written to a
    temporary folder, removed at the end), with each round's time and the load average."""
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="brfgs-bench-manifest-") as tmp:
        t0 = time.perf_counter()
        path = write_manifest(Path(tmp), n_scenes)
        write_s = time.perf_counter() - t0
        rounds = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            plan = dry_run(path, BatchConfig(dry_run=True))
            rounds.append(time.perf_counter() - t0)
        if plan.failing or len(plan.lines) != n_scenes + 1:
            raise RuntimeError(f"the synthetic manifest's dry run failed: {plan.lines[:3]}")
    return {"scenes": n_scenes, "repeats": repeats, "median_s": statistics.median(rounds), "rounds_s": rounds,
            "per_scene_us": statistics.median(rounds) / n_scenes * 1e6, "write_s": write_s,
            "machine": {"cpu_count": os.cpu_count(), "load_average_1_5_15_before": list(load_before),
                        "load_average_1_5_15_after": list(os.getloadavg())}}
