"""``brfgs compare A B``: two evaluated models on the same held-out views, with bootstrap intervals.

The library side is :mod:`brfgs.evaluation.compare`; the body imports it lazily.
"""

from __future__ import annotations

from pathlib import Path

import typer


def _runs(text: str) -> list[Path]:
    return [Path(x.strip()) for x in text.split(",") if x.strip()]


def register(app: typer.Typer) -> None:
    @app.command("compare")
    def compare_cmd(
        a: str = typer.Argument(..., metavar="A", help="Run folder of model A (or several, comma-separated: seeds of one "
                                "configuration, or with --scenes one run per scene), evaluated by brfgs train/evaluate."),
        b: str = typer.Argument(..., metavar="B", help="Run folder(s) of model B, the reference (same scene and split; "
                                "seeds, or with --scenes scenes, paired with A's in the order given)."),
        split: str = typer.Option("test", "--split", help="test (metrics.json), validation "
                                  "(metrics_validation.json) or train (metrics_train.json)."),
        against: str = typer.Option("truth", "--against", help="truth (simulated scenes) or observed."),
        resamples: int = typer.Option(10000, "--resamples", help="Bootstrap resamples of the views."),
        seed: int = typer.Option(0, "--seed", help="Seed of the bootstrap."),
        json_out: Path = typer.Option(None, "--json", help="Also write the comparison to this JSON file."),
        scenes: bool = typer.Option(False, "--scenes", help="A and B list runs of several scenes, paired in the order "
                                    "given: each scene's row, and the mean over scenes of the margins (geometric "
                                    "mean of the SAM ratios) with a bootstrap of every scene's views, overall and "
                                    "per ring (a setting chosen over several scenes at once). Several pairs of one "
                                    "scene are its training seeds: averaged per view, the scene counts once."),
    ) -> None:
        """CIR PSNR margin (A − B, dB) and SAM ratio (A / B) over all views and per view ring, with 95 %
        intervals from a paired bootstrap over the views, and the range over seed pairs when several runs
        are given per side; with --scenes, per scene and pooled over the scenes."""
        from brfgs.evaluation import compare as C
        from brfgs.evaluation import compare_scenes as CS
        from brfgs.data.atomic import write_json

        runs_a = [C.read_scores(r, split, against) for r in _runs(a)]
        runs_b = [C.read_scores(r, split, against) for r in _runs(b)]
        run, report = (CS.compare_scenes, CS.report_lines) if scenes else (C.compare, C.report_lines)
        res = run(runs_a, runs_b, n_resamples=resamples, seed=seed)
        res.update(split=split, against=against)
        for line in report(res):
            typer.echo(line)
        if json_out is not None:
            typer.echo(f"comparison: {write_json(json_out, res)}")
