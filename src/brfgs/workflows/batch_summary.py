"""The summary of ``brfgs batch``: one row per scene, written as OUT/summary.md, .csv and .json.

A row holds the scene's status (finished = run by this batch, skipped = finished by an earlier
one, failed), the attempts this batch made, the wall time (seconds over the attempts of the batch
that ran it), the mean CIR PSNR (dB) and SAM (rad) of the test views against the observations and,
on simulated scenes, against the truth (metrics.json's ``against.*.mean``), the number of Gaussians,
and where the outputs are. The metrics are read from the run folders, so the rows of scenes finished
earlier are the same after any rerun. Paths inside the output root are written relative to it.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

from brfgs.analysis.output import metrics_file
from brfgs.data import atomic
from brfgs.model import MODEL_FILE
from brfgs.workflows.manifest import BatchScene

COLUMNS = ("name", "status", "attempts", "wall_s", "psnr_observed", "sam_observed", "psnr_truth", "sam_truth",
           "n_gaussians", "out", "model", "metrics", "products", "error", "error_log")
STATE_FILE = "batch.json"     # in a scene's output folder: its attempts, time and status in the last batch
LOG_FILE = "batch.log"        # its progress lines
ERROR_LOG = "error.log"       # the tracebacks / messages of its failed attempts
STATUS_TEXT = {"skipped": "skipped (finished)"}


def products_dir(s: BatchScene) -> Path:
    """Where `brfgs products` writes the scene's products (its default: RUN/analysis/products)."""
    return s.run / "analysis" / "products"


def read_state(s: BatchScene) -> dict:
    """The scene's batch.json ({} when absent or unreadable)."""
    try:
        return json.loads((s.out / STATE_FILE).read_text())
    except (OSError, ValueError):
        return {}


def _shown(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def _metrics(s: BatchScene) -> dict:
    """Mean test-view metrics of the scene's run (empty when there is no metrics.json)."""
    try:
        m = json.loads((s.run / metrics_file("test")).read_text())
    except (OSError, ValueError):
        return {}
    row = {"n_gaussians": (m.get("settings") or {}).get("n_gaussians")}
    for against in ("observed", "truth"):
        mean = ((m.get("against") or {}).get(against) or {}).get("mean") or {}
        row[f"psnr_{against}"] = mean.get("psnr")
        row[f"sam_{against}"] = mean.get("sam")
    return row


def scene_row(s: BatchScene, status: str, root: Path, result: dict | None = None) -> dict:
    """The summary row of scene ``s`` with ``status`` (finished | skipped | failed | pending | running |
    interrupted); ``result``: what this batch's task reported (attempts, seconds, error, error_log)."""
    result = result or {}
    row = dict.fromkeys(COLUMNS)
    row.update(name=s.name, status=status, out=_shown(s.out, root))
    seconds = read_state(s).get("seconds") if status == "skipped" else result.get("seconds")
    row.update(attempts=0 if status == "skipped" else result.get("attempts", 0),
               wall_s=None if seconds is None else round(seconds, 2))
    if status in ("finished", "skipped"):
        row.update(_metrics(s))
        row.update(model=_shown(s.run / MODEL_FILE, root), metrics=_shown(s.run / metrics_file("test"), root))
        if s.products is not None:
            row["products"] = _shown(products_dir(s), root)
    if result.get("error"):
        row["error"] = result["error"]
        if result.get("error_log"):
            row["error_log"] = _shown(Path(result["error_log"]), root)
    return row


def _fmt(v, spec: str) -> str:
    return "–" if v is None else format(v, spec)


def summary_markdown(rows: list[dict], manifest: Path) -> str:
    """The table of summary.md (and of the command's output), failures listed below it."""
    lines = [f"# Batch {manifest.name}", "",
             "CIR PSNR (dB) and SAM (rad): means over the test views; 'obs' against the observations, 'truth' "
             "against the simulator's clean cubes. Time: seconds of the batch that ran the scene.", "",
             "| scene | status | attempts | time (s) | PSNR obs | SAM obs | PSNR truth | SAM truth | Gaussians | outputs |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append("| " + " | ".join([r["name"], STATUS_TEXT.get(r["status"], r["status"]), str(r["attempts"]),
                                          _fmt(r["wall_s"], ".0f"), _fmt(r["psnr_observed"], ".2f"),
                                          _fmt(r["sam_observed"], ".4f"), _fmt(r["psnr_truth"], ".2f"),
                                          _fmt(r["sam_truth"], ".4f"), _fmt(r["n_gaussians"], "d"), r["out"]]) + " |")
    failed = failure_lines(rows)
    if failed:
        lines += ["", "## Failures", ""] + [f"- {line}" for line in failed]
    return "\n".join(lines) + "\n"


def failure_lines(rows: list[dict]) -> list[str]:
    """One line per failed scene: its name, the error and where the traceback is."""
    return [f"scene '{r['name']}' failed" + (f" after {r['attempts']} attempts" if (r["attempts"] or 0) > 1 else "")
            + f": {r['error']}" + (f" (log: {r['error_log']})" if r["error_log"] else "")
            for r in rows if r["status"] == "failed"]


def write_summary(root: Path, rows: list[dict], manifest: Path) -> dict[str, Path]:
    """Write OUT/summary.md, summary.csv (the columns of :data:`COLUMNS`) and summary.json atomically."""
    paths = {"md": root / "summary.md", "csv": root / "summary.csv", "json": root / "summary.json"}
    atomic.write_text(paths["md"], summary_markdown(rows, manifest))
    with atomic.open_text(paths["csv"], newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows({k: ("" if r[k] is None else r[k]) for k in COLUMNS} for r in rows)
    counts = {k: sum(r["status"] == k for r in rows) for k in ("finished", "skipped", "failed")}
    atomic.write_json(paths["json"], {"manifest": str(manifest), "out": str(root),
                                      "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "counts": counts,
                                      "columns": list(COLUMNS), "scenes": rows})
    return paths
