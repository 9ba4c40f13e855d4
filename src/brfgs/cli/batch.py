"""``brfgs batch MANIFEST``: train → evaluate → products for a list of scenes, as Ray tasks.

The manifest's schema is in :mod:`brfgs.workflows.manifest`; the options of where and how the
scenes run are generated from :class:`brfgs.workflows.options.BatchConfig`. The body imports the
library lazily so that ``brfgs --help`` stays fast (no torch, no Ray).
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.data.lock import folder_lock
from brfgs.workflows.options import BatchConfig


def register(app: typer.Typer) -> None:
    @config_command(app, "batch", BatchConfig)
    def batch_cmd(
        manifest: Path = typer.Argument(..., help="TOML, JSON or YAML list of scenes with their options "
                                        "(docs/scaling.md).", show_default=False),
        options: dict | None = None,
    ) -> None:
        """Run train -> evaluate -> products for every scene of MANIFEST as Ray tasks (locally, or on a cluster
        with --address); finished scenes are skipped, a failed one is retried (unless its input is at fault)
        and reported; writes OUT/summary.md, .csv and .json. Exit status 2 if any scene failed (with --dry-run:
        would fail)."""
        from brfgs.workflows.batch_plan import dry_run

        bc = apply_options(BatchConfig(), options)
        if bc.dry_run:
            plan = dry_run(manifest, bc)
            typer.echo("\n".join(plan.lines))
            for line in plan.warnings:
                typer.echo(f"brfgs: {line}", err=True)
            for line in plan.failures:
                typer.echo(f"brfgs: error: {line}", err=True)
            if plan.failing:
                typer.echo(f"brfgs: error: {plan.failing} of {plan.total} scenes would fail",
                           err=True)
                raise typer.Exit(2)
            return
        from brfgs.workflows.batch import run_batch
        from brfgs.workflows.manifest import read_manifest

        m = read_manifest(manifest, bc.out)
        with folder_lock(m.out, "brfgs batch"):  # one batch per output root
            res = run_batch(m, bc, say=(lambda *a: None) if bc.quiet else typer.echo)
        typer.echo(res.markdown)
        typer.echo(f"summary: {res.paths['md']}  {res.paths['csv']}  {res.paths['json']}")
        for line in res.failures:
            typer.echo(f"brfgs: error: {line}", err=True)
        if res.failures:
            raise typer.Exit(2)
