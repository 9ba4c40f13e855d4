"""``brfgs products RUN``: per-pixel kernel products from nadir (brfgs.products.report)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.analysis.options import parse_floats
from brfgs.cli._options import BackendOpt, OverwriteOpt, QuietOpt, RunArg

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def products_cmd(
    run: Path = RunArg,
    size: str = typer.Option(None, "--size", metavar="W[,H]", help="Pixels of the nadir map (default: the "
                             "training images' pixel footprint on the ground, at most 2048)."),
    half_extent: float = typer.Option(None, "--half-extent", help="Half width of the mapped area (m) "
                                      "(default: half the Gaussians' 2–98 % extent)."),
    sun_zenith: float = typer.Option(None, "--sun-zenith", help="Sun zenith (deg) of the contribution maps and "
                                     "ANIX (default: training sun)."),
    nbar_sun_zenith: float = typer.Option(None, "--nbar-sun-zenith", help="Sun zenith (deg) of NBAR "
                                          "(default: the sun zenith)."),
    albedo_sun_zenith: float = typer.Option(None, "--albedo-sun-zenith", help="Sun zenith (deg) of the black-sky "
                                            "albedo (default: the sun zenith)."),
    min_alpha: float = typer.Option(0.5, "--min-alpha", min=0.0, max=1.0,
                                    help="Pixels whose accumulated opacity is below this are NaN in the products."),
    check_decoder: bool = typer.Option(True, "--check-decoder/--no-check-decoder",
                                       help="Measure how far latent-space albedo is from integrating decoded spectra."),
    mcd43: bool = typer.Option(True, "--mcd43/--no-mcd43", help="Fit MODIS MCD43-style f_iso, f_vol, f_geo per "
                               "pixel and band to the model's BRF (RossThick-LiSparse-R, 75 directions) and write "
                               "them with the fit's RMSE and MCD43 NBAR/albedo from them."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: RUN/analysis/products)."),
    backend: str = BackendOpt,
    overwrite: bool = OverwriteOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Per-pixel products from nadir: kernel contribution maps, NBAR, black/white-sky albedo, ANIX, and
    MODIS MCD43-style kernel weights (f_iso, f_vol, f_geo) with the NBAR and albedos computed from them."""
    from brfgs.products.report import ProductsOptions, products_report

    opts = ProductsOptions(size=None if size is None else tuple(parse_floats(size, "--size")),
                           half_extent_m=half_extent, sun_zenith_deg=sun_zenith, nbar_sun_zenith_deg=nbar_sun_zenith,
                           albedo_sun_zenith_deg=albedo_sun_zenith, min_alpha=min_alpha, check_decoder=check_decoder, mcd43=mcd43,
                           backend=backend, overwrite=overwrite, progress=not quiet)
    typer.echo(products_report(run, opts, out).message)


def register(app: typer.Typer) -> None:
    app.command("products")(products_cmd)
