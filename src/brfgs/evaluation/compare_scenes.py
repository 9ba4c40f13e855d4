"""A setting compared over several scenes at once: per-scene margins and their mean over scenes.

A default is chosen over several scenes at once (one default for all of them, not per-scene
tuning). ``brfgs compare A1,A2,... B1,B2,... --scenes`` pairs the runs by position, one
pair per scene (A_i and B_i trained on scene i with the same split), and reports:

- each scene's PSNR margin and SAM ratio with its paired-bootstrap interval
  (:func:`brfgs.evaluation.compare.compare_block`: what ``brfgs compare A_i B_i --seed SEED+i`` prints);
- the pooled margin, the mean over scenes of the per-scene margins (each scene weighs the same,
  whatever its number of views), and the pooled SAM ratio, the geometric mean over scenes of the
  per-scene ratios;
- a 95 % interval of each pooled statistic from a stratified bootstrap: each resample draws every
  scene's views with replacement (scene i from seed ``seed + i``, the draw its own row uses) and
  recomputes the per-scene statistics and their pool. It answers "how much would other held-out
  views move the pooled number?" — not "how much would another set of scenes move it"; the per-scene
  rows, and how many of them gain or lose beyond their views' noise, say that;
- the same pooled statistics per view ring, over the rings every scene has; an interval only where
  every scene has at least 2 views in the ring (one view has no spread to resample).

Several pairs of one scene (the same scene folder) are training seeds of both settings: each side's
per-view scores are averaged over them (:func:`brfgs.evaluation.compare.seed_mean`, as ``brfgs compare
A1,A2 B1,B2`` does) and the scene counts once, so a scene with more seeds weighs no more, and its
views' bootstrap draw is shared by its seeds.
"""

from __future__ import annotations

import numpy as np

from brfgs.evaluation.compare import (
    MIN_VIEWS_FOR_INTERVAL,
    N_RESAMPLES,
    TABLE_HEAD,
    Scores,
    bootstrap_indices,
    compare_block,
    interval,
    margin,
    require_same_views,
    ring_order,
    sam_ratio,
    seed_mean,
    table_row,
)
from brfgs.errors import UserError, require

MIN_VIEWS_PER_SCENE = 2  # a pooled interval needs every scene to contribute some spread


def pooled_block(parts: list[tuple[Scores, Scores, np.ndarray]], n_resamples: int, seed: int) -> dict:
    """Mean-over-scenes margin and geometric-mean SAM ratio of the views ``sel`` [v_i] of each scene.

    ``parts``: (A, B, sel) per scene. Returns the pooled estimates, the mean over scenes of each side's
    scores, and, when every scene has ≥ 2 selected views and there are ≥ 3 in all, 95 % intervals
    from the stratified bootstrap (scene i resampled with ``bootstrap_indices(v_i, R, seed + i)``).
    """
    margins = np.array([margin(a.psnr_db[s], b.psnr_db[s]) for a, b, s in parts])     # [S]
    log_ratios = np.log([sam_ratio(a.sam_rad[s], b.sam_rad[s]) for a, b, s in parts])  # [S]
    n_views = [len(s) for _, _, s in parts]
    out = {"n_scenes": len(parts), "n_views": int(sum(n_views)),
           "margin_db": float(margins.mean()), "sam_ratio": float(np.exp(log_ratios.mean()))}
    for side, k in (("a", 0), ("b", 1)):  # each side's mean over scenes of its per-scene mean scores
        out[f"psnr_{side}_db"] = float(np.mean([p[k].psnr_db[p[2]].mean() for p in parts]))
        out[f"sam_{side}_rad"] = float(np.mean([p[k].sam_rad[p[2]].mean() for p in parts]))
    if min(n_views) >= MIN_VIEWS_PER_SCENE and sum(n_views) >= MIN_VIEWS_FOR_INTERVAL:
        m_r = np.zeros(n_resamples)   # [R] sum over scenes of the resampled margins
        lr_r = np.zeros(n_resamples)  # [R] sum over scenes of the resampled log SAM ratios
        for i, (a, b, s) in enumerate(parts):
            idx = s[bootstrap_indices(len(s), n_resamples, seed + i)]  # [R, v_i] view indices of scene i
            m_r += margin(a.psnr_db[idx], b.psnr_db[idx])
            lr_r += np.log(sam_ratio(a.sam_rad[idx], b.sam_rad[idx]))
        out["margin_db_ci95"] = interval(m_r / len(parts))
        out["sam_ratio_ci95"] = interval(np.exp(lr_r / len(parts)))
    return out


def _beyond_noise(ci: tuple[float, float] | None, null: float) -> int:
    """+1 where a 95 % interval lies above ``null``, −1 where below, 0 where it spans it or is missing."""
    if not ci:
        return 0
    return 1 if ci[0] > null else -1 if ci[1] < null else 0


def by_scene(pairs: list[tuple[Scores, Scores]]) -> list[tuple[Scores, Scores, int]]:
    """The pairs grouped by scene (its folder, else its name; a pair with neither is a scene of its own),
    in the order first given: (seed mean of A, seed mean of B, number of seeds) per scene."""
    groups: dict[str, list[tuple[Scores, Scores]]] = {}
    for k, (a, b) in enumerate(pairs):
        groups.setdefault(a.scene_root or a.scene or f"pair {k + 1}", []).append((a, b))
    out = []
    for key, grp in groups.items():
        for side in (0, 1):
            labels = [p[side].label for p in grp]
            dup = sorted({x for x in labels if labels.count(x) > 1})
            if dup:
                raise UserError(f"run {dup[0]} is given twice for scene {key}; the pairs of one scene are its "
                                "training seeds, each run once", field="RUNS")
        out.append((seed_mean([a for a, _ in grp]), seed_mean([b for _, b in grp]), len(grp)))
    return out


def compare_scenes(runs_a: list[Scores], runs_b: list[Scores], n_resamples: int = N_RESAMPLES, seed: int = 0) -> dict:
    """Each scene's comparison (A_i against B_i; seeds of one scene averaged) and the pooled one, overall
    and per view ring common to all."""
    require(len(runs_a) == len(runs_b), "--scenes pairs the runs in the order given: give as many runs for A as "
            f"for B (got {len(runs_a)} and {len(runs_b)})", field="RUNS")
    require(n_resamples >= 100, f"expected at least 100, got {n_resamples}", field="--resamples")
    for a, b in zip(runs_a, runs_b):
        require_same_views(a, b)
    grouped = by_scene(list(zip(runs_a, runs_b)))
    require(len(grouped) >= 2, f"--scenes pools two or more scenes, got {len(grouped)} (the pairs of one scene are its "
            "seeds: compare them without --scenes)", field="RUNS")
    pairs = [(a, b) for a, b, _ in grouped]
    scenes = []
    for i, (a, b, n_seeds) in enumerate(grouped):
        blk = compare_block(a, b, np.arange(len(a.views)), n_resamples, seed + i)
        scenes.append({"scene": a.scene, "a": a.label, "b": b.label, "n_seeds": n_seeds, **blk,  # +1: A better
                       "psnr_verdict": _beyond_noise(blk.get("margin_db_ci95"), 0.0),
                       "sam_verdict": -_beyond_noise(blk.get("sam_ratio_ci95"), 1.0)})
    res = {"scenes": scenes, "n_resamples": n_resamples, "seed": seed,
           "all": pooled_block([(a, b, np.arange(len(a.views))) for a, b in pairs], n_resamples, seed),
           "rings": {}}
    common = set.intersection(*(set(a.rings) for a, _ in pairs)) - {"all"}
    for ring in sorted(common, key=ring_order):
        parts = [(a, b, np.flatnonzero(np.array(a.rings) == ring)) for a, b in pairs]
        res["rings"][ring] = pooled_block(parts, n_resamples, seed)
    return res


def report_lines(res: dict) -> list[str]:
    """Per-scene rows, the pooled row and the pooled per-ring rows as one markdown table, and a tally."""
    lines = [TABLE_HEAD[0].format(first="scene (A vs B)"), TABLE_HEAD[1]]
    for s in res["scenes"]:
        name = f"{s['scene']}: " if s.get("scene") else ""
        lines.append(table_row(f"{name}{s['a']} vs {s['b']}", s))
    lines.append(table_row(f"**mean of {res['all']['n_scenes']} scenes**", res["all"]))
    for ring, blk in res["rings"].items():
        lines.append(table_row(f"mean, {ring}° ring", blk))
    tally = {}
    for key in ("psnr_verdict", "sam_verdict"):
        v = [s[key] for s in res["scenes"]]
        tally[key] = (v.count(1), v.count(-1), v.count(0))
    lines += ["", f"Pooled: mean over scenes of the margins, geometric mean of the SAM ratios; intervals from a "
              f"bootstrap of each scene's views ({res['n_resamples']} resamples, scene i seed {res['seed']} + i; "
              f"none for fewer than {MIN_VIEWS_FOR_INTERVAL} views in a scene's row, or fewer than "
              f"{MIN_VIEWS_PER_SCENE} per scene in a pooled row); the pairs of one scene are its seeds, averaged per view.",
              "Beyond the views' noise (interval excluding 0 dB / 1×), A is better / worse / undecided in "
              f"PSNR on {'/'.join(map(str, tally['psnr_verdict']))} scenes and in SAM on "
              f"{'/'.join(map(str, tally['sam_verdict']))} scenes."]
    return lines
