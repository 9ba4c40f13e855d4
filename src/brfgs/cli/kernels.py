"""``brfgs kernels``: plot the BRDF kernels and write their values as CSV."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.brdf.options import KernelsOptions
from brfgs.cli._config import apply_options, config_command
from brfgs.errors import UserError

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def kernels_cmd(o: KernelsOptions) -> None:
    """Draw Ross-Thick, Li-Sparse-R and Cook–Torrance on the principal plane and as polar maps."""
    o.validate()
    targets: list[Path] = []
    png = o.png
    if o.plot:
        if png is None:
            png = o.out / f"kernels_sun{o.sun_zenith_deg:g}.png"
        if png.suffix.lower() != ".png":
            raise UserError(f"the figure path must end in .png: {png}", field="--png")
        targets.append(png)
    if o.csv is not None:
        targets.append(o.csv)
    for t in targets:
        if t.exists() and not o.overwrite:
            raise UserError("exists; pass --overwrite to replace it", file=t)
        if t.exists() and t.is_dir():
            raise UserError("is a folder, expected a file path", file=t)
        try:
            t.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"cannot create the output folder: {exc}", file=t.parent) from exc

    from brfgs.brdf.plots import kernel_grid, plot_kernels, write_kernel_csv

    grid = kernel_grid(o.sun_zenith_deg, roughness=o.roughness, step_deg=o.step_deg,
                       max_view_zenith_deg=o.max_view_zenith_deg)
    if o.csv is not None:
        write_kernel_csv(o.csv, grid)
        typer.echo(f"wrote {o.csv} ({grid.k_ross.size} rows)")
    if o.plot:
        plot_kernels(png, grid)
        typer.echo(f"wrote {png}")


def register(app: typer.Typer) -> None:
    @config_command(app, "kernels", KernelsOptions)
    def command(options: dict | None = None) -> None:
        """Draw Ross-Thick, Li-Sparse-R and Cook–Torrance on the principal plane and as polar maps.

        The CSV has columns sun_zenith_deg, view_zenith_deg, relative_azimuth_deg, k_ross, k_li,
        k_cook (Cook–Torrance for a horizontal facet, F0 = 0.04, the given roughness);
        relative azimuth φ = φ_view − φ_sun, φ = 0 is backscatter.
        """
        kernels_cmd(apply_options(KernelsOptions(), options))
