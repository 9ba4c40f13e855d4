"""``brfgs export RUN OUT``: a 3DGS PLY and the self-describing model file (brfgs.products.export).

Options are generated from :class:`brfgs.products.options.ExportOptions`; the body imports the
library lazily so that ``brfgs --help`` stays fast (no torch, no numba).
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.cli._options import RunArg
from brfgs.products.options import ExportOptions


def register(app: typer.Typer) -> None:
    @config_command(app, "export", ExportOptions)
    def export_cmd(
        run: Path = RunArg,
        out: Path = typer.Argument(..., help="Output folder (gaussians.ply, model.safetensors, export.json).",
                                   show_default=False),
        options: dict | None = None,
    ) -> None:
        """Export the Gaussians as a 3DGS PLY (the standard attributes x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity
        scale_0..2 rot_0..3 with CIR colours, and the BRF parameters) and the self-describing model file."""
        from brfgs.products.export import export_model

        info = export_model(run, out, apply_options(ExportOptions(), options))
        typer.echo(f"wrote {out / info['ply']} ({info['n_gaussians']} Gaussians) and {out / info['model']}")
