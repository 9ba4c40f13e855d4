"""``brfgs train`` / ``brfgs evaluate`` / ``brfgs ablate``: two-stage BRF-GS training and its evaluation.

The training options are generated from :class:`brfgs.train.config.TrainConfig` (every field is
an option; ``brfgs train --help``). Command bodies import the library lazily so that
``brfgs --help`` stays fast (no torch or numba at start-up).
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command, read_config_file
from brfgs.errors import UserError
from brfgs.train.config import TrainConfig
from brfgs.train.presets import preset

# options an ablation study sets itself for each of its runs
STUDY_FIELDS = ("variant", "components", "joint", "band_strategy")


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


def register(app: typer.Typer) -> None:
    @config_command(app, "train", TrainConfig)
    def train_cmd(
        scene: Path = typer.Argument(..., help="Scene folder (transforms.json + images/)."),
        out: Path = typer.Argument(..., help="Run folder (created; an unfinished run there is resumed)."),
        config: Path = typer.Option(None, "--config", help="A run's config.json: train with exactly its options "
                                    "(options given here override the file; an option the file predates takes "
                                    "its value of then)."),
        from_stage1: Path = typer.Option(None, "--from-stage1", help="Start stage 2 from another run's "
                                         "checkpoints/stage1.safetensors."),
        evaluate: bool = typer.Option(True, "--evaluate/--no-evaluate", help="Evaluate the test views after training."),
        overwrite: bool = typer.Option(False, "--overwrite", help="Replace a finished run in OUT."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
        nproc: int = typer.Option(1, "--nproc", min=1, help="Data-parallel training in this many local processes "
                                  "(gloo; NCCL on GPUs): each renders its share of every step's --views-per-step "
                                  "views (docs/scaling.md)."),
        distributed: bool = typer.Option(False, "--distributed", help="Be one rank of a process group started by "
                                         "torchrun (`torchrun --nproc-per-node N -m brfgs train ... --distributed`)."),
        options: dict | None = None,
    ) -> None:
        """Train BRF-GS (or a baseline) on SCENE into OUT; rerun to resume; Ctrl-C keeps a checkpoint."""
        from brfgs.evaluation.evaluate import evaluate_run, metrics_file, summary_lines
        from brfgs.train.distributed import run_as_rank
        from brfgs.train.trainer import train_parallel, train_rank

        cfg = build_config(options, config)
        if distributed:
            if nproc > 1:
                raise UserError("give either --distributed (under torchrun) or --nproc N", field="--nproc")
            if not run_as_rank(train_rank, (scene, out, cfg, overwrite, from_stage1, quiet), cfg.backend):
                return  # ranks other than 0 leave the evaluation to rank 0
            path = out / "model.safetensors"
        else:
            path = train_parallel(nproc, scene, out, cfg, overwrite=overwrite, from_stage1=from_stage1, quiet=quiet)
        typer.echo(f"model: {path}")
        if evaluate:
            for split in ("validation", "test") if cfg.validation else ("test",):
                res = evaluate_run(out, scene, backend=cfg.backend, progress=not quiet, split=split)
                for line in summary_lines(res):
                    typer.echo(f"[{split}] {line}" if cfg.validation else line)
                typer.echo(f"metrics: {out / metrics_file(split)}")

    @app.command("evaluate")
    def evaluate_cmd(
        out: Path = typer.Argument(..., help="Run folder of brfgs train."),
        scene: Path = typer.Option(None, "--scene", help="Scene folder (default: the one recorded in the model)."),
        backend: str = typer.Option(None, "--backend", help="Rasterizer backend: auto | torch | cpu | cuda "
                                    "(default: the one the model was trained with, so the digits match training's)."),
        images: bool = typer.Option(True, "--images/--no-images", help="Write ENVI renders and CIR PNGs."),
        split: str = typer.Option("test", "--split", help="Views to score: test (metrics.json), validation "
                                  "(metrics_validation.json; runs trained with --validation) or train "
                                  "(metrics_train.json: the fit of the training views, to tell a model that "
                                  "underfits from one that does not generalise)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Render and score the views of --split (the test views by default); write OUT/metrics.json (per view,
        per view ring and mean, with each held-out view's angle to the nearest training view; on simulated scenes
        also per material, with the rendered opacity and the ray-wise depth spread), ENVI renders and CIR
        comparison PNGs."""
        from brfgs.evaluation.evaluate import evaluate_run, metrics_file, summary_lines

        res = evaluate_run(out, scene, backend=backend, write_images=images, progress=not quiet, split=split)
        for line in summary_lines(res):
            typer.echo(line)
        typer.echo(f"metrics: {out / metrics_file(split)}")
        if images and split == "test":
            typer.echo(f"renders: {out / 'eval' / 'renders'}  CIR comparisons: {out / 'eval' / 'cir'}")

    @config_command(app, "ablate", TrainConfig, skip=STUDY_FIELDS)
    def ablate_cmd(
        scene: Path = typer.Argument(..., help="Scene folder."),
        out: Path = typer.Argument(..., help="Folder for the study's runs and tables."),
        study: str = typer.Option(..., "--study", help="kernels (Table 3) | training (Table 4) | bands (Table 2) | "
                                  "baselines (Table 1) | additions (each addition beyond the paper removed from the "
                                  "options, and added to the paper's method)."),
        only: str = typer.Option(None, "--only", help="Comma-separated run names of the study to train now (the "
                                 "tables hold the finished ones), e.g. default,paper,no_lr_spec."),
        quiet: bool = typer.Option(False, "--quiet"),
        options: dict | None = None,
    ) -> None:
        """Train the variants of one of the paper's tables on SCENE and write OUT/table_<study>.{md,csv}
        (each row's PSNR margin and SAM ratio against its reference run, with 95 % intervals over the views);
        the training options apply to every run (the study sets variant, components, joint, band strategy)."""
        from brfgs.workflows.ablate import ablate

        names = [x.strip() for x in only.split(",") if x.strip()] if only else None
        res = ablate(scene, out, study, build_config(options), progress=not quiet, log=_echo(quiet), only=names)
        for key in ("paths", "paths_validation"):
            if key in res:
                typer.echo(Path(res[key]["md"]).read_text())
                typer.echo(f"tables: {res[key]['md']}  {res[key]['csv']}")
