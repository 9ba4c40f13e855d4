"""``brfgs ablate SCENE OUT --study ...``: the paper's comparison and ablation tables on any scene.

Studies (each run is an ordinary, resumable training run folder ``OUT/<run>``):
- ``kernels`` (Table 3): full BRF-GS, w/o iso, w/o vol, w/o geo, w/o spec, SH-3 baseline.
  All share the stage-1 geometry of the full run (``--from-stage1``), so only the reflectance
  representation differs, as in the paper.
- ``training`` (Table 4): joint optimisation vs decoupled two-stage (full BRF-GS).
- ``bands`` (Table 2): the eight band-selection strategies for stage 1 and initialisation (stage 1
  fits the selected bands only, not also the CIR bands, so that the strategy is what differs);
  geometry columns (detected features per view, matching success rate) from the init report.
- ``baselines`` (Table 1): 3DGS on CIR composites, SH-3 in latent space, neural per-Gaussian
  decoder (MS-Splatting style), BRF-GS.
- ``additions``: brfgs's additions beyond the paper (:data:`brfgs.train.presets.ADDITIONS`): the
  given options ("default"), each addition removed from them ("no_<name>"), the paper's method
  ("paper": every addition off) and each addition added to it ("paper_<name>"). Additions that
  change stage 2 only reuse the stage 1 of "default" / "paper".
Tables are written as ``OUT/table_<study>.md`` and ``.csv`` with the mean and per-view-ring
metrics, and each row's PSNR margin and SAM ratio against its reference run (:func:`reference_run`)
with 95 % intervals from a paired bootstrap over the views (as ``brfgs compare``); they are against
the observed test views and, when the scene has truth/, against the clean truth. With ``--validation``
every run holds out its validation views and the tables ``OUT/table_<study>_validation.*`` score those
(choose settings there, not on the test views).
"""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from brfgs.evaluation.compare import (MIN_VIEWS_FOR_INTERVAL, N_RESAMPLES, compare_block, read_scores,
                                    require_same_views)
from brfgs.evaluation.evaluate import evaluate_run, metrics_file
from brfgs.bands.select import STRATEGY_LABELS, TABLE2_STRATEGIES
from brfgs.data import atomic
from brfgs.data.paths import check_outside
from brfgs.errors import UserError
from brfgs.model import MODEL_FILE
from brfgs.train import TrainConfig, train
from brfgs.train.presets import ADDITIONS, PAPER_METHOD
from brfgs.train.run_folder import STAGE1_CKPT, run_status

STUDIES = ("kernels", "training", "bands", "baselines", "additions")
FULL = ("iso", "vol", "geo", "spec")


def _runs(study: str, base: TrainConfig) -> list[tuple[str, str, TrainConfig, str | None]]:
    """(run folder, label, config, stage-1 source run or None)."""
    full = replace(base, variant="brf", components=FULL, joint=False)
    if study == "kernels":
        out = [("full", "BRF-GS (Full)", full, None)]
        for c in FULL:
            comps = tuple(x for x in FULL if x != c)
            out.append((f"wo_{c}", f"Ours w/o {c.capitalize()}", replace(full, components=comps), "full"))
        out.insert(0, ("sh", "Baseline (spherical harmonics)", replace(full, variant="sh"), "full"))
        return out
    if study == "training":
        return [("joint", "Joint optimization", replace(full, joint=True), None), ("full", "BRF-GS (Full)", full, None)]
    if study == "baselines":
        return [("cir3dgs", "3DGS (CIR composites)", replace(full, variant="cir"), None),
                ("sh", "SH-3 in latent space", replace(full, variant="sh"), "full"),
                ("neural", "Neural decoder (MS-Splatting-style)", replace(full, variant="neural"), "full"),
                ("full", "BRF-GS (Ours)", full, None)]
    if study == "bands":  # stage 1 fits the selected bands only (as the paper), so the strategy is what differs
        return [(f"bands_{s}", STRATEGY_LABELS.get(s, s), replace(full, band_strategy=s, stage1_cir_bands=False), None)
                for s in TABLE2_STRATEGIES]
    if study == "additions":
        return _addition_runs(full)
    raise UserError(f"unknown study {study!r}; choose one of {', '.join(STUDIES)}", field="study")


def _addition_runs(base: TrainConfig) -> list[tuple[str, str, TrainConfig, str | None]]:
    """The additions study: base, base minus each addition, the paper's method, paper plus each."""
    paper = replace(base, **PAPER_METHOD)
    out = [("default", "brfgs (given options, every addition on)", base, None)]
    for name, a in ADDITIONS.items():
        out.append((f"no_{name}", f"default without {name}", replace(base, **a.paper), "default" if a.stage == 2 else None))
    out.append(("paper", "paper's method (every addition off)", paper, None))
    for name, a in ADDITIONS.items():
        back = {k: getattr(base, k) for k in a.paper}
        out.append((f"paper_{name}", f"paper + {name}", replace(paper, **back), "paper" if a.stage == 2 else None))
    # runs equal to another (an addition already off in the given options) are dropped
    seen, unique = {}, []
    for r in out:
        key = r[2].to_json()
        if key not in seen:
            seen[key] = r[0]
            unique.append(r)
    return unique


def reference_run(study: str, name: str, names: set[str]) -> str | None:
    """The run a table row is compared with: the full model (kernels, training, baselines), the paper's
    EFC top-3 strategy (bands), or the run it differs from by one addition (additions: "no_X" and
    "paper" against "default", "paper_X" against "paper"). None for the reference itself or when that
    run is not in the study."""
    if study == "additions":
        ref = "paper" if name.startswith("paper_") else "default"
    elif study == "bands":
        ref = "bands_efc-top3"
    else:
        ref = "full"
    return ref if ref in names and ref != name else None


def versus(out: Path, name: str, ref: str | None, split: str, against: list[str]) -> dict:
    """Row fields: the PSNR margin (dB) and SAM ratio of run ``name`` against run ``ref`` on the same held-out
    views of ``split``, with 95 % paired-bootstrap intervals over the views (:mod:`brfgs.evaluation.compare`)."""
    if ref is None:
        return {}
    row: dict = {"vs": ref}
    for ag in against:
        a, b = read_scores(out / name, split, ag), read_scores(out / ref, split, ag)
        require_same_views(b, a)
        blk = compare_block(a, b, np.arange(len(a.views)), N_RESAMPLES, seed=0)
        row[f"dpsnr_{ag}"], row[f"sam_ratio_{ag}"] = blk["margin_db"], blk["sam_ratio"]
        for key, col in (("margin_db", f"dpsnr_{ag}"), ("sam_ratio", f"sam_ratio_{ag}")):
            lo, hi = blk.get(f"{key}_ci95", (None, None))
            row[f"{col}_ci95_lo"], row[f"{col}_ci95_hi"] = lo, hi
    return row


def _fmt(v, fmt):
    return "–" if v is None else format(v, fmt)


def ablate(scene_path, out_dir, study: str, base: TrainConfig, progress: bool = True, log=print,
           only: list[str] | None = None) -> dict:
    """Run (or resume) every run of ``study`` and write its tables; returns {"rows": [...], "paths": {...}}
    (with ``base.validation``: also "rows_validation" / "paths_validation")."""
    out = Path(out_dir)
    check_outside(out, scene_path)
    out.mkdir(parents=True, exist_ok=True)
    runs = _runs(study, base)
    unknown = sorted(set(only or ()) - {r[0] for r in runs})
    if unknown:
        raise UserError(f"no run(s) {unknown} in study {study!r}; its runs are {', '.join(r[0] for r in runs)}",
                        field="--only")
    splits = ("test", "validation") if base.validation else ("test",)
    # runs that others start from go first
    order = sorted(runs, key=lambda r: 0 if any(o[3] == r[0] for o in runs) else 1)
    results: dict[str, dict[str, dict]] = {s: {} for s in splits}
    for name, label, cfg, src in order:
        rdir = out / name
        if only and name not in only:  # not asked for now: read after this call's runs (below)
            continue
        if run_status(rdir) != "finished":
            log(f"[{study}] training {name}: {label}")
            from_stage1 = out / src / STAGE1_CKPT if src else None
            if from_stage1 is not None and not from_stage1.is_file():
                raise UserError(f"run {src} has no stage-1 checkpoint", file=from_stage1)
            train(scene_path, rdir, cfg, progress=progress, from_stage1=from_stage1, log=log)
        for split in splits:
            mfile = rdir / metrics_file(split)
            if not mfile.is_file() or mfile.stat().st_mtime < (rdir / MODEL_FILE).stat().st_mtime:
                evaluate_run(rdir, scene_path, backend=cfg.backend, progress=progress, split=split)
            results[split][name] = json.loads(mfile.read_text())
    for name, *_ in runs:  # in the tables if another call finished it, before or while this one trained
        rdir = out / name
        if only and name not in only and run_status(rdir) == "finished":
            for split in splits:
                mfile = rdir / metrics_file(split)
                if mfile.is_file():
                    results[split][name] = json.loads(mfile.read_text())
    res: dict = {}
    for split in splits:
        done = set(results[split])
        rows = [_row(study, out, name, label, results[split][name])
                | versus(out, name, reference_run(study, name, done), split, list(results[split][name]["against"]))
                for name, label, _, _ in runs if name in done]
        key = "" if split == "test" else "_validation"
        res["rows" + key] = rows
        res["paths" + key] = write_tables(out, study + key, rows, scene_path)
    return res


def _row(study: str, out: Path, name: str, label: str, r: dict) -> dict:
    """One table row: mean and per-ring metrics against observed (and truth), timings, Table 2 geometry."""
    row = {"run": name, "setting": label}
    for against in ("observed", "truth"):
        if against in r["against"]:
            block = r["against"][against]
            for k in ("psnr", "ssim", "lpips", "sam", "psnr_spectral"):
                row[f"{k}_{against}"] = block["mean"].get(k)
            for ring, m in (block.get("rings") or {}).items():
                row[f"psnr_{against}_ring{ring}"] = m.get("psnr")
                row[f"sam_{against}_ring{ring}"] = m.get("sam")
    if study == "bands":
        rep_path = out / name / "init" / "init_report.json"
        if rep_path.is_file():
            g = json.loads(rep_path.read_text()).get("geometry", {})
            row["detected_features_per_view"] = g.get("mean_detected_features_per_view")
            row["matching_success_rate"] = g.get("matching_success_rate")
    timing = json.loads((out / name / "run.json").read_text()).get("timings_s", {})
    row["train_seconds"] = sum(v for k, v in timing.items() if k != "total_this_session")
    return row


def _rings(rows: list[dict], against: str) -> list[str]:
    """View rings with a PSNR column for ``against``, in zenith order."""
    pre = f"psnr_{against}_ring"
    return sorted({k[len(pre):] for r in rows for k in r if k.startswith(pre)}, key=float)


def _with_ci(r: dict, col: str, fmt: str) -> str:
    """'+0.12 [−0.30, +0.51]': a row's estimate against its reference and the 95 % interval."""
    if r.get(col) is None:
        return "–"
    lo, hi = r.get(f"{col}_ci95_lo"), r.get(f"{col}_ci95_hi")
    ci = "" if lo is None else f" [{format(lo, fmt)}, {format(hi, fmt)}]"
    return format(r[col], fmt) + ci


def write_tables(out: Path, study: str, rows: list[dict], scene_path) -> dict:
    """OUT/table_<study>.csv (every column) and .md (the paper's columns and PSNR per view ring)."""
    cols = sorted({k for r in rows for k in r}, key=lambda k: (k not in ("run", "setting"), k))
    csv_path = out / f"table_{study}.csv"
    with atomic.atomic_path(csv_path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in cols})
    has_truth = any("psnr_truth" in r for r in rows)
    refs = ["observed"] + (["truth"] if has_truth else [])
    lines = [f"# Study '{study}' on {Path(scene_path).name}", "",
             "PSNR/SSIM on CIR composites (dB, data range 1); SAM in radians over all bands; "
             "'observed' = the noisy held-out images, 'truth' = the clean simulated cubes; "
             "'PSNR z°' = mean CIR PSNR of the held-out views of the view ring at zenith z; "
             "'ΔPSNR' (dB) and 'SAM ×' = the row against the run named in 'vs' on the same views, with 95 % "
             "intervals from a paired bootstrap over the views (as `brfgs compare`; none for fewer than "
             f"{MIN_VIEWS_FOR_INTERVAL} views).",
             ""]
    for against in refs:
        rings = _rings(rows, against)
        head = ["Model setting", "PSNR↑", "SSIM↑", "SAM↓"] + [f"PSNR {r}°" for r in rings] + [
            "vs", "ΔPSNR [95 %]", "SAM × [95 %]"]
        if study == "bands":
            head += ["Detected feature points ↑", "Matching success rate ↑"]
        lines += [f"## Against {against}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in rows:
            cells = [r["setting"], _fmt(r.get(f"psnr_{against}"), ".2f"), _fmt(r.get(f"ssim_{against}"), ".3f"),
                     _fmt(r.get(f"sam_{against}"), ".4f")]
            cells += [_fmt(r.get(f"psnr_{against}_ring{g}"), ".2f") for g in rings]
            cells += [r.get("vs", "–"), _with_ci(r, f"dpsnr_{against}", "+.2f"), _with_ci(r, f"sam_ratio_{against}", ".3f")]
            if study == "bands":
                cells += [_fmt(r.get("detected_features_per_view"), ".0f"),
                          "–" if r.get("matching_success_rate") is None else f"{100 * r['matching_success_rate']:.1f}%"]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    md_path = out / f"table_{study}.md"
    atomic.write_text(md_path, "\n".join(lines))
    return {"csv": str(csv_path), "md": str(md_path)}
