"""``brfgs demo [OUT]``: simulate a small scene, run the whole pipeline, evaluate, report.

Options are generated from :class:`brfgs.workflows.demo.DemoConfig`; the body imports the
library lazily so that ``brfgs --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.workflows.options import DemoConfig


def register(app: typer.Typer) -> None:
    @config_command(app, "demo", DemoConfig)
    def demo_cmd(
        out: Path = typer.Argument(Path("brfgs-demo"), help="Folder for the demo's scene, runs and report."),
        options: dict | None = None,
    ) -> None:
        """Simulate -> select bands -> initialise -> autoencoder -> stage 1 -> stage 2 -> evaluate, BRF-GS vs SH."""
        from brfgs.workflows.demo import run_demo

        dc = apply_options(DemoConfig(), options)
        say = (lambda *a: None) if dc.quiet else typer.echo
        report = run_demo(out, dc, progress=not dc.quiet, say=say)
        typer.echo(report)
        typer.echo(f"report: {out / 'report.txt'}")
