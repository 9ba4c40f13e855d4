"""Paired comparison of two models on the same held-out views, with a bootstrap over the views.

Margins between models (e.g. BRF-GS against SH-3 in CIR PSNR and SAM) are often decided on a handful
of held-out views (7 test views of a 49-view flight, 2 of them at 58°).
``brfgs compare A B`` reads the per-view scores that ``brfgs evaluate`` wrote for both runs
(docs/data-format.md, ``metrics.json``) and reports, overall and per view ring:

- the PSNR margin, mean_v(PSNR_A) − mean_v(PSNR_B) in dB (means over views, as metrics.json's "mean");
- the SAM ratio, mean_v(SAM_A) / mean_v(SAM_B);
- for each, a 95 % percentile interval from a paired bootstrap over the views: resample the views
  with replacement (the same draw for A and B), recompute the statistic; seeded, so the same command
  gives the same interval. It answers "how much would another choice of held-out views move this?";
- with several runs per side (seeds of the same configuration, paired in the order given), each
  pair's statistics and their range ("how much does the training seed move it?"); the intervals are
  then computed on the seed-mean score of each view.

Pure functions on arrays; reading and checking the files is :func:`read_scores`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brfgs.analysis.output import SPLITS, metrics_file
from brfgs.errors import UserError, require

AGAINST = ("truth", "observed")
MIN_VIEWS_FOR_INTERVAL = 3  # fewer views than this: the estimate only (a bootstrap of 1-2 views says nothing)
N_RESAMPLES = 10000  # bootstrap resamples of the views (brfgs compare's default; brfgs ablate's rows)


@dataclass
class Scores:
    """Per-view scores of one run, or the per-view mean over several runs (seeds)."""

    label: str            # the run folder(s)
    views: list[str]      # [V] view names, sorted
    rings: list[str]      # [V] view ring of each view ("18", "58", ...; "all" when the file has none)
    psnr_db: np.ndarray   # [V] CIR PSNR (dB)
    sam_rad: np.ndarray   # [V] mean spectral angle (rad)
    scene: str = ""       # the scene's name in the metrics file ("" where it has none)
    scene_root: str = ""  # the scene folder it was evaluated on ("" where the file has none)


def metrics_path(run: Path, split: str) -> Path:
    """The metrics file of ``split`` in a run folder (a .json file is taken as it is)."""
    if run.suffix == ".json":
        return run
    return run / metrics_file(split)


def _ring_of_views(data: dict, path: Path) -> dict[str, str]:
    rings = (data.get("split") or {}).get("rings")
    if rings is None:
        return {}
    require(isinstance(rings, dict), "expected {ring: {split: [view names]}}", file=path, field="split.rings")
    out = {}
    for ring, parts in rings.items():
        require(isinstance(parts, dict), "expected {split: [view names]}", file=path, field=f"split.rings.{ring}")
        for names in parts.values():
            for name in names or []:
                out[str(name)] = str(ring)
    return out


def _view_value(view: dict, key: str, path: Path, field: str) -> float:
    value = view.get(key)
    if value is None:
        reason = view.get(f"{key}_reason")
        raise UserError(f"no value{f' ({reason})' if reason else ''}", file=path, field=field)
    require(isinstance(value, (int, float)) and math.isfinite(value), f"expected a finite number, got {value!r}",
            file=path, field=field)
    return float(value)


def read_scores(run: str | Path, split: str = "test", against: str = "truth") -> Scores:
    """Per-view CIR PSNR and SAM of one evaluated run; every problem is a UserError naming file and field."""
    require(split in SPLITS, f"expected one of {', '.join(SPLITS)}, got {split!r}", field="--split")
    require(against in AGAINST, f"expected one of {', '.join(AGAINST)}, got {against!r}", field="--against")
    path = metrics_path(Path(run), split)
    if not path.is_file():
        hint = f" (run `brfgs evaluate RUN --split {split}`)" if split != "test" else ""
        raise UserError(f"no metrics file; evaluate the run first{hint}", file=path)
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"not valid JSON ({exc})", file=path) from None
    require(isinstance(data, dict), "expected a JSON object", file=path)
    block = (data.get("against") or {}).get(against)
    field = f"against.{against}.views"
    if block is None and against == "truth":
        raise UserError("no scores against truth (a scene without truth: use --against observed)", file=path,
                        field=f"against.{against}")
    views = (block or {}).get("views")
    require(isinstance(views, list) and len(views) > 0, "expected a non-empty list of per-view scores",
            file=path, field=field)
    ring_of = _ring_of_views(data, path)
    rows = []
    for i, view in enumerate(views):
        require(isinstance(view, dict) and isinstance(view.get("name"), str), "expected {name, psnr, sam, ...}",
                file=path, field=f"{field}[{i}]")
        rows.append((view["name"], ring_of.get(view["name"], "all"),
                     _view_value(view, "psnr", path, f"{field}[{i}].psnr"),
                     _view_value(view, "sam", path, f"{field}[{i}].sam")))
    names = [r[0] for r in rows]
    require(len(set(names)) == len(names), "a view is listed twice", file=path, field=field)
    rows.sort(key=lambda r: r[0])
    scene, root = data.get("scene"), data.get("scene_root")
    return Scores(str(Path(run)), [r[0] for r in rows], [r[1] for r in rows], np.array([r[2] for r in rows]),
                  np.array([r[3] for r in rows]), scene if isinstance(scene, str) else "",
                  root if isinstance(root, str) else "")


def require_same_views(a: Scores, b: Scores) -> None:
    """Both runs must have scored the same views (the same split of the same scene). The simulator
    names views alike in every scene, so the scenes' names are compared too where both files give one."""
    if a.scene and b.scene and a.scene != b.scene:
        raise UserError(f"the runs were scored on different scenes ({a.label}: {a.scene!r}; {b.label}: "
                        f"{b.scene!r}); compare runs of the same scene", file=b.label, field="scene")
    if a.views != b.views:
        only_a = sorted(set(a.views) - set(b.views))[:3]
        only_b = sorted(set(b.views) - set(a.views))[:3]
        raise UserError(f"the runs were scored on different views (only in {a.label}: {only_a or '-'}; only in "
                        f"{b.label}: {only_b or '-'}); compare runs of the same scene, split and split seed",
                        file=b.label, field="split")


def seed_mean(runs: list[Scores]) -> Scores:
    """The per-view mean over runs of one configuration (seeds); all must have scored the same views."""
    for other in runs[1:]:
        require_same_views(runs[0], other)
    return Scores(",".join(r.label for r in runs), runs[0].views, runs[0].rings,
                  np.mean([r.psnr_db for r in runs], axis=0), np.mean([r.sam_rad for r in runs], axis=0),
                  runs[0].scene, runs[0].scene_root)


def bootstrap_indices(n_views: int, n_resamples: int, seed: int) -> np.ndarray:
    """[R, V] view indices drawn with replacement (numpy PCG64 seeded with ``seed``)."""
    rng = np.random.Generator(np.random.PCG64(seed))
    return rng.integers(0, n_views, size=(n_resamples, n_views))


def margin(psnr_a: np.ndarray, psnr_b: np.ndarray) -> np.ndarray:
    """PSNR margin in dB, mean over the last axis of A minus that of B. [..., V] -> [...]."""
    return psnr_a.mean(axis=-1) - psnr_b.mean(axis=-1)


def sam_ratio(sam_a: np.ndarray, sam_b: np.ndarray) -> np.ndarray:
    """SAM ratio, mean over the last axis of A divided by that of B. [..., V] -> [...]."""
    return sam_a.mean(axis=-1) / sam_b.mean(axis=-1)


def interval(stat: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Percentile interval of bootstrap statistics [R] at ``level`` (linear interpolation)."""
    lo, hi = np.percentile(stat, [50 * (1 - level), 50 * (1 + level)])
    return float(lo), float(hi)


def compare_block(a: Scores, b: Scores, sel: np.ndarray, n_resamples: int, seed: int) -> dict:
    """Estimates and bootstrap intervals of the margin and the SAM ratio over the views ``sel`` [v]."""
    pa, pb, sa, sb = a.psnr_db[sel], b.psnr_db[sel], a.sam_rad[sel], b.sam_rad[sel]
    out = {"n_views": int(len(sel)), "psnr_a_db": float(pa.mean()), "psnr_b_db": float(pb.mean()),
           "sam_a_rad": float(sa.mean()), "sam_b_rad": float(sb.mean()),
           "margin_db": float(margin(pa, pb)), "sam_ratio": float(sam_ratio(sa, sb))}
    if len(sel) >= MIN_VIEWS_FOR_INTERVAL:
        idx = bootstrap_indices(len(sel), n_resamples, seed)  # [R, v]
        out["margin_db_ci95"] = interval(margin(pa[idx], pb[idx]))
        out["sam_ratio_ci95"] = interval(sam_ratio(sa[idx], sb[idx]))
    return out


def ring_order(ring: str) -> tuple[int, float, str]:
    """Numeric rings by zenith, then named ones, then "all" (views the file puts in no ring)."""
    try:
        return (0, float(ring), ring)
    except ValueError:
        return (2 if ring == "all" else 1, 0.0, ring)


def compare(runs_a: list[Scores], runs_b: list[Scores], n_resamples: int = N_RESAMPLES, seed: int = 0) -> dict:
    """Overall and per-ring comparison of A and B (seed means), and each seed pair's overall statistics."""
    require(len(runs_a) > 0 and len(runs_b) > 0, "give at least one run on each side", field="RUNS")
    require(n_resamples >= 100, f"expected at least 100, got {n_resamples}", field="--resamples")
    a, b = seed_mean(runs_a), seed_mean(runs_b)
    require_same_views(a, b)
    rings = np.array(a.rings)
    res = {"a": a.label, "b": b.label, "n_resamples": n_resamples, "seed": seed,
           "all": compare_block(a, b, np.arange(len(a.views)), n_resamples, seed), "rings": {}}
    if set(a.rings) != {"all"}:  # a file without view rings: the "all" row says it all
        for ring in sorted(set(a.rings), key=ring_order):
            res["rings"][ring] = compare_block(a, b, np.flatnonzero(rings == ring), n_resamples, seed)
    if len(runs_a) > 1 or len(runs_b) > 1:
        require(len(runs_a) == len(runs_b), "seeds are paired in the order given: give as many runs for A as "
                f"for B (got {len(runs_a)} and {len(runs_b)})", field="RUNS")
        res["seed_pairs"] = [{"a": ra.label, "b": rb.label, "margin_db": float(margin(ra.psnr_db, rb.psnr_db)),
                              "sam_ratio": float(sam_ratio(ra.sam_rad, rb.sam_rad))}
                             for ra, rb in zip(runs_a, runs_b)]
    return res


def ci_text(block: dict, key: str, fmt: str) -> str:
    """A block's 95 % interval of ``key`` as "[lo, hi]", or "–" where it has none."""
    ci = block.get(f"{key}_ci95")
    return f"[{format(ci[0], fmt)}, {format(ci[1], fmt)}]" if ci else "–"


TABLE_HEAD = ["| {first} | n | A PSNR (dB) / SAM (rad) | B PSNR (dB) / SAM (rad) | margin A − B (dB) | 95 % interval "
              "| SAM ratio A / B | 95 % interval |", "|---|---|---|---|---|---|---|---|"]


def table_row(name: str, blk: dict) -> str:
    """One markdown row of a comparison block (compare_block's keys)."""
    return (f"| {name} | {blk['n_views']} | {blk['psnr_a_db']:.2f} / {blk['sam_a_rad']:.4f} "
            f"| {blk['psnr_b_db']:.2f} / {blk['sam_b_rad']:.4f} | {blk['margin_db']:+.2f} "
            f"| {ci_text(blk, 'margin_db', '+.2f')} | {blk['sam_ratio']:.3f} | {ci_text(blk, 'sam_ratio', '.3f')} |")


def report_lines(res: dict) -> list[str]:
    """The comparison as a markdown table (one row for all views, one per ring) and the seed pairs."""
    lines = [f"A: {res['a']}", f"B: {res['b']}", "", TABLE_HEAD[0].format(first="views"), TABLE_HEAD[1]]
    rows = [("all", res["all"])] + [(f"{r}°" if r != "all" else r, blk) for r, blk in res["rings"].items()]
    lines += [table_row(name, blk) for name, blk in rows]
    lines += ["", f"Intervals: paired bootstrap over the views ({res['n_resamples']} resamples, seed {res['seed']}; "
              f"none for fewer than {MIN_VIEWS_FOR_INTERVAL} views)."]
    for i, pair in enumerate(res.get("seed_pairs", [])):
        lines.append(f"seed pair {i + 1}: margin {pair['margin_db']:+.2f} dB, SAM ratio {pair['sam_ratio']:.3f} "
                     f"({pair['a']} vs {pair['b']})")
    if res.get("seed_pairs"):
        m = [p["margin_db"] for p in res["seed_pairs"]]
        s = [p["sam_ratio"] for p in res["seed_pairs"]]
        lines.append(f"over the seed pairs: margin {min(m):+.2f} to {max(m):+.2f} dB, SAM ratio {min(s):.3f} to "
                     f"{max(s):.3f}")
    return lines
