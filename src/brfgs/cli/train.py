"""``brfgs train`` / ``brfgs evaluate`` / ``brfgs ablate``: two-stage BRF-GS training and its evaluation.

The training options are generated from :class:`brfgs.train.config.TrainConfig` (every field is
an option; ``brfgs train --help`` lists the method's, ``--help-all`` the experimental and expert
ones too), the evaluation's from :class:`brfgs.evaluation.options.EvaluateOptions`. Command bodies
import the library lazily so that ``brfgs --help`` stays fast (no torch or numba at start-up).
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command, read_config_file
from brfgs.errors import UserError
from brfgs.evaluation.options import EvaluateOptions
from brfgs.train.config import TrainConfig
from brfgs.train.options import STUDIES, STUDY_FIELDS, AblateOptions, TrainCommandOptions
from brfgs.train.presets import preset




def build_config(options: dict, config_file: Path | None = None) -> TrainConfig:
    """preset (``--preset``, default fast) < ``config_file`` (a run's config.json) < the other options."""
    options = dict(options)
    name = options.pop(("preset",), None)
    if config_file is None:
        base = preset(name or "fast")
    elif name is not None:
        raise UserError("give either --preset or --config (a config file holds every option)", field="--preset")
    else:
        base = TrainConfig.from_written(read_config_file(config_file), source=str(config_file))
    try:
        return apply_options(base, options).validate()
    except TypeError as exc:  # a value of the wrong type in the file slipped through
        raise UserError(f"invalid options ({exc})", file=config_file) from None
    except UserError as exc:  # a value out of range: name the file unless the command line set it
        given = {".".join(k) for k in options}
        if config_file is None or exc.file is not None or exc.field in given:
            raise
        raise UserError(exc.detail, file=config_file, field=exc.field) from None


def _echo(quiet: bool):
    return (lambda *a: None) if quiet else typer.echo


def _split(options: dict | None) -> tuple[dict, dict]:
    """(the training options given, the command's own) of a command's ``options`` {path: value}."""
    options = dict(options or {})
    return ({k[1:]: v for k, v in options.items() if k[0] == "train"},
            {k: v for k, v in options.items() if k[0] != "train"})


def register(app: typer.Typer) -> None:
    @config_command(app, "train", TrainCommandOptions)
    def train_cmd(
        scene: Path = typer.Argument(..., help="Scene folder (transforms.json + images/)."),
        out: Path = typer.Argument(..., help="Run folder (created; an unfinished run there is resumed)."),
        options: dict | None = None,
    ) -> None:
        """Train BRF-GS (or a baseline) on SCENE into OUT; rerun to resume; Ctrl-C keeps a checkpoint."""
        from brfgs.evaluation.evaluate import evaluate_run, metrics_file, summary_lines
        from brfgs.train.distributed import run_as_rank
        from brfgs.train.trainer import train_parallel, train_rank

        given, own = _split(options)
        o = apply_options(TrainCommandOptions(), own)
        cfg = build_config(given, o.config)
        if o.nproc < 1:
            raise UserError(f"nproc must be >= 1, got {o.nproc}", field="--nproc")
        if o.distributed:
            if o.nproc > 1:
                raise UserError("give either --distributed (under torchrun) or --nproc N", field="--nproc")
            if not run_as_rank(train_rank, (scene, out, cfg, o.overwrite, o.from_stage1, o.quiet), cfg.backend):
                return  # ranks other than 0 leave the evaluation to rank 0
            path = out / "model.safetensors"
        else:
            path = train_parallel(o.nproc, scene, out, cfg, overwrite=o.overwrite, from_stage1=o.from_stage1,
                                  quiet=o.quiet)
        typer.echo(f"model: {path}")
        if o.evaluate:
            for split in ("validation", "test") if cfg.validation else ("test",):
                res = evaluate_run(out, scene, backend=cfg.backend, progress=not o.quiet, split=split)
                for line in summary_lines(res):
                    typer.echo(f"[{split}] {line}" if cfg.validation else line)
                typer.echo(f"metrics: {out / metrics_file(split)}")

    @config_command(app, "evaluate", EvaluateOptions)
    def evaluate_cmd(
        out: Path = typer.Argument(..., help="Run folder of brfgs train."),
        options: dict | None = None,
    ) -> None:
        """Render and score the views of --split (the test views by default), or those of another flight of the
        same site (--scene), each under its own sun; write OUT/metrics.json (per view,
        per view ring and mean, with each held-out view's angle to the nearest training view; on simulated scenes
        also per material, with the rendered opacity and the ray-wise depth spread), ENVI renders and CIR
        comparison PNGs."""
        from brfgs.evaluation.evaluate import evaluate_run, metrics_file, summary_lines

        o = apply_options(EvaluateOptions(), options).validate()
        res = evaluate_run(out, o.scene, backend=o.backend, write_images=o.images, progress=not o.quiet, split=o.split,
                           sun=o.sun)
        for line in summary_lines(res):
            typer.echo(line)
        dest = Path(res["evaluation"]["folder"])
        typer.echo(f"metrics: {dest / metrics_file(o.split)}")
        if o.images and o.split == "test":
            typer.echo(f"renders: {dest / 'eval' / 'renders'}  CIR comparisons: {dest / 'eval' / 'cir'}")

    @config_command(app, "ablate", AblateOptions, skip=tuple("train_" + f for f in STUDY_FIELDS))
    def ablate_cmd(
        scene: Path = typer.Argument(..., help="Scene folder."),
        out: Path = typer.Argument(..., help="Folder for the study's runs and tables."),
        options: dict | None = None,
    ) -> None:
        """Train the variants of one of the paper's tables on SCENE and write OUT/table_<study>.{md,csv}
        (each row's PSNR margin and SAM ratio against its reference run, with 95 % intervals over the views);
        the training options apply to every run (the study sets variant, components, joint, band strategy)."""
        from brfgs.workflows.ablate import ablate

        given, own = _split(options)
        o = apply_options(AblateOptions(study=""), own)
        if o.study not in STUDIES:
            raise UserError(f"study must be one of {', '.join(STUDIES)}, got {o.study!r}", field="--study")
        names = list(o.only) if o.only else None
        res = ablate(scene, out, o.study, build_config(given), progress=not o.quiet, log=_echo(o.quiet), only=names)
        for key in ("paths", "paths_validation"):
            if key in res:
                typer.echo(Path(res[key]["md"]).read_text())
                typer.echo(f"tables: {res[key]['md']}  {res[key]['csv']}")
