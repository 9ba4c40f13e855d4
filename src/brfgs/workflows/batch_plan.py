"""What ``brfgs batch`` would do: the plan of each scene (run which steps, skip, or fail and why),
the dry run (``--dry-run``) and its warnings. Light: no Ray, no evaluation or products code, so that a
dry run of a large manifest starts fast."""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path

from brfgs.analysis.output import metrics_file
from brfgs.errors import UserError
from brfgs.model import MODEL_FILE
from brfgs.train.config import TrainConfig
from brfgs.train.run_folder import CONFIG_FILE, run_status
from brfgs.workflows.batch_summary import products_dir
from brfgs.workflows.manifest import BatchScene, Manifest, ManifestCheck, check_manifest
from brfgs.workflows.options import BatchConfig


def eval_splits(validation: bool) -> tuple[str, ...]:
    """The splits a scene's run is evaluated on."""
    return ("test", "validation") if validation else ("test",)


def missing_steps(s: BatchScene, status: str | None = "unknown") -> list[str]:
    """What is missing of the scene's outputs: a subset of ["train", "evaluate", "products"] ([] = finished);
    ``status``: the run's :func:`run_status` when known."""
    status = run_status(s.run) if status == "unknown" else status
    if status != "finished" or not (s.run / MODEL_FILE).is_file():
        return ["train", "evaluate"] + (["products"] if s.products is not None else [])
    evaluated = all((s.run / metrics_file(sp)).is_file() for sp in eval_splits(s.config["validation"]))
    steps = [] if evaluated else ["evaluate"]
    if s.products is not None and not (products_dir(s) / "products.json").is_file():
        steps.append("products")
    return steps


def _config_change(s: BatchScene) -> list[str]:
    """Options (other than threads) in which a finished run in the scene's folder differs from the manifest's."""
    path = s.run / CONFIG_FILE
    if not path.is_file():
        return []
    return TrainConfig.from_run_config(path).changed_options(TrainConfig.from_dict(s.config), ignore=("threads",))


def plan_scene(s: BatchScene) -> tuple[str, str | None]:
    """("skip", None) for a finished scene, ("fail", message) for one that cannot run, else ("run", steps)."""
    try:
        if not (s.scene / "transforms.json").is_file():
            return "fail", str(UserError("scene folder not found (no transforms.json)", file=s.scene))
        status = run_status(s.run)
        steps = missing_steps(s, status)
        changed = _config_change(s) if status == "finished" else []
    except UserError as exc:  # an unreadable config.json
        return "fail", str(exc)
    except ValueError:  # a damaged run.json / config.json (both are written atomically)
        return "fail", str(UserError("run.json or config.json is not valid JSON", file=s.run))
    except OSError as exc:  # a folder that cannot be read, a link loop
        return "fail", str(UserError(f"cannot read ({exc.strerror or exc})", file=exc.filename or s.scene))
    if changed:
        return "fail", str(UserError(f"a finished run with other options ({', '.join(changed)}) is here; it is "
                                     "never overwritten: remove it or give the scene another 'out'", file=s.run))
    return ("skip", None) if not steps else ("run", " -> ".join(steps))


def local_gpus() -> int:
    """CUDA GPUs a local Ray would see: those CUDA_VISIBLE_DEVICES lists when it is set (up to an
    invalid entry, as CUDA reads it), else this machine's /dev/nvidiaN devices."""
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible is None:
        return len(glob.glob("/dev/nvidia[0-9]*"))
    n = 0
    for entry in (e.strip() for e in visible.split(",")):
        if not entry or entry.startswith("-"):
            break
        n += 1
    return n


def resource_warnings(scenes: list[BatchScene], bc: BatchConfig) -> list[str]:
    """One line per resource (CPU, GPU) that some scenes ask for more of than this machine has; none
    with ``bc.address`` (a cluster may have them)."""
    if bc.address:
        return []
    lines = []
    for key, have, want in (("CPUs", bc.local_cpus or os.cpu_count() or 1, lambda s: s.num_cpus),
                            ("GPUs", None, lambda s: s.num_gpus)):
        if have is None:
            if not any(s.num_gpus > 0 for s in scenes):
                continue
            have = local_gpus()
        over = [s for s in scenes if want(s) > have]
        if over:
            shown = ", ".join(f"{s.name} ({want(s):g})" for s in over[:5]) + (f" and {len(over) - 5} more"
                                                                             if len(over) > 5 else "")
            lines.append(f"warning: {len(over)} scene(s) ask for more {key} than this machine has ({have:g}): {shown}; "
                         "a local batch fails them at once, a Ray cluster (--address) may have them")
    return lines


def plan_lines(m: Manifest, bc: BatchConfig, check: ManifestCheck | None = None) -> tuple[list[str], list[tuple]]:
    """What a batch would do (``--dry-run``): where Ray runs and one line per scene (each problem of
    ``check``, a manifest's :func:`check_manifest`, as a FAIL line in the scene's place); and why scenes
    would fail, as (scene index, one line) (index 0: the whole batch)."""
    total = check.total if check else len(m.scenes)
    where = f"the Ray cluster at {bc.address}" if bc.address else f"a local Ray ({bc.local_cpus or os.cpu_count()} CPUs)"
    lines = [f"manifest {m.path}: {total} scenes, outputs in {m.out}, on {where}"]
    problems: dict[int, list[UserError]] = {}
    for i, exc in check.problems if check else ():
        problems.setdefault(i, []).append(exc)
    failures = [(i, str(exc)) for i, exc in check.problems] if check else []
    lines += [f"  FAIL: {exc}" for exc in problems.pop(0, [])]
    by_index = {s.index: s for s in m.scenes}
    for i in sorted(set(by_index) | set(problems)):
        if i in problems:
            lines += [f"  scene[{i}]: FAIL: {exc}" for exc in problems[i]]
            continue
        s = by_index[i]
        action, what = plan_scene(s)
        if action == "fail":
            failures.append((i, f"scene '{s.name}' would fail: {what}"))
        text = {"skip": "skip (finished)", "fail": f"FAIL: {what}", "run": f"run {what}"}[action]
        cfg = s.config
        lines.append(f"  {s.name}: {text}  [{s.num_cpus} CPU, {s.num_gpus:g} GPU; preset {cfg['preset']}, "
                     f"variant {cfg['variant']}, seed {cfg['seed']}; scene {s.scene}; out {s.out}]")
    return lines, failures


@dataclass
class DryRun:
    """What ``brfgs batch --dry-run`` prints: the plan, the warnings, why scenes would fail (one line
    each), how many of the manifest's scenes would fail."""

    lines: list[str]
    warnings: list[str]
    failures: list[str]
    failing: int
    total: int


def dry_run(path: str | Path, bc: BatchConfig) -> DryRun:
    """Check the manifest at ``path`` and plan every scene (nothing is started or written)."""
    check = check_manifest(path, bc.out)
    lines, failures = plan_lines(check.manifest, bc, check)
    failing = {i for i, _ in failures}
    return DryRun(lines, resource_warnings(check.manifest.scenes, bc), [line for _, line in failures],
                  check.total if 0 in failing else len(failing), check.total)
