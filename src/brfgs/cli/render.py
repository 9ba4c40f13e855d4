"""``brfgs render RUN``: the model from any view under any sun (brfgs.analysis.render_report).

Options are generated from :class:`brfgs.analysis.options.RenderOptions`; the body imports the
library lazily so that ``brfgs --help`` stays fast (no torch, no numba).
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.analysis.options import RenderOptions
from brfgs.cli._config import apply_options, config_command
from brfgs.cli._options import RunArg


def register(app: typer.Typer) -> None:
    @config_command(app, "render", RenderOptions)
    def render_cmd(run: Path = RunArg, options: dict | None = None) -> None:
        """Render the model from any view: ENVI cube, CIR PNG, depth, normal and sun-visibility (shadow) maps (PNG + .npy), timing."""
        from brfgs.analysis.render_report import render_report

        opts = apply_options(RenderOptions(view_zenith_deg=0.0, view_azimuth_deg=0.0), options)
        typer.echo(render_report(run, opts).message)
