"""``brfgs brf RUN --roi ...``: the BRF of a region (brfgs.analysis.brf_report).

Options are generated from :class:`brfgs.analysis.options.BRFOptions`; the body imports the
library lazily so that ``brfgs --help`` stays fast (no torch, no numba).
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.analysis.options import BRFOptions
from brfgs.cli._config import apply_options, config_command
from brfgs.cli._options import RunArg


def register(app: typer.Typer) -> None:
    @config_command(app, "brf", BRFOptions)
    def brf_cmd(run: Path = RunArg, options: dict | None = None) -> None:
        """BRF of a region: principal-plane curves, polar maps, spectra vs observations (and truth), CSVs.

        On a simulated scene (truth/scene.json) the simulator renders the truth again for the principal
        plane and a coarse polar grid (polar_truth.png/.csv); per-band RMSE and mean bias of the model
        against it are in brf.json and truth_error.csv.
        """
        from brfgs.analysis.brf_report import brf_report

        opts = apply_options(BRFOptions(roi=""), options)
        typer.echo(brf_report(run, opts, warn=lambda message: typer.echo(message, err=True)).message)
