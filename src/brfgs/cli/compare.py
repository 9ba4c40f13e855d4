"""``brfgs compare A B``: two evaluated models on the same held-out views, with bootstrap intervals.

The library side is :mod:`brfgs.evaluation.compare`; the body imports it lazily.
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.evaluation.options import CompareOptions


def _runs(text: str) -> list[Path]:
    return [Path(x.strip()) for x in text.split(",") if x.strip()]


def register(app: typer.Typer) -> None:
    @config_command(app, "compare", CompareOptions)
    def compare_cmd(
        a: str = typer.Argument(..., metavar="A", help="Run folder of model A (or several, comma-separated: seeds of one "
                                "configuration, or with --scenes one run per scene), evaluated by brfgs train/evaluate."),
        b: str = typer.Argument(..., metavar="B", help="Run folder(s) of model B, the reference (same scene and split; "
                                "seeds, or with --scenes scenes, paired with A's in the order given)."),
        options: dict | None = None,
    ) -> None:
        """CIR PSNR margin (A − B, dB) and SAM ratio (A / B) over all views and per view ring, with 95 %
        intervals from a paired bootstrap over the views, and the range over seed pairs when several runs
        are given per side; with --scenes, per scene and pooled over the scenes."""
        from brfgs.data.atomic import write_json
        from brfgs.evaluation import compare as C
        from brfgs.evaluation import compare_scenes as CS

        o = apply_options(CompareOptions(), options).validate()
        runs_a = [C.read_scores(r, o.split, o.against) for r in _runs(a)]
        runs_b = [C.read_scores(r, o.split, o.against) for r in _runs(b)]
        run, report = (CS.compare_scenes, CS.report_lines) if o.scenes else (C.compare, C.report_lines)
        res = run(runs_a, runs_b, n_resamples=o.resamples, seed=o.seed)
        res.update(split=o.split, against=o.against)
        for line in report(res):
            typer.echo(line)
        if o.json is not None:
            typer.echo(f"comparison: {write_json(o.json, res)}")
