"""``brfgs products RUN``: per-pixel products from nadir (brfgs.products.report).

Options are generated from :class:`brfgs.products.options.ProductsOptions`; the body imports the
library lazily so that ``brfgs --help`` stays fast (no torch, no numba).
"""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.cli._options import RunArg
from brfgs.products.options import ProductsOptions


def register(app: typer.Typer) -> None:
    @config_command(app, "products", ProductsOptions)
    def products_cmd(run: Path = RunArg, options: dict | None = None) -> None:
        """Per-pixel products from nadir: kernel contribution maps, NBAR, black/white-sky albedo, ANIX, a DSM, and
        MODIS MCD43-style kernel weights (f_iso, f_vol, f_geo) with the NBAR and albedos computed from them."""
        from brfgs.products.report import products_report

        typer.echo(products_report(run, apply_options(ProductsOptions(), options)).message)
