"""``brfgs kernels``: plot the BRDF kernels and write their values as CSV."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import typer

from brfgs.errors import UserError

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def kernels_cmd(
    sun_zenith: float = typer.Option(30.0, "--sun-zenith", help="Sun zenith angle in degrees, 0..89."),
    roughness: float = typer.Option(0.3, "--roughness", help="GGX roughness ρ of the Cook–Torrance kernel, (0, 1]."),
    out_dir: Path = typer.Option(Path("."), "--out", "--out-dir", help="Folder for the figure (created if needed)."),
    png: Optional[Path] = typer.Option(None, "--png", help="PNG path (default OUT/kernels_sun<Z>.png)."),
    csv_path: Optional[Path] = typer.Option(None, "--csv", help="Also write the grid values to this CSV file."),
    step: float = typer.Option(2.0, "--step", help="Grid step of view zenith and relative azimuth, degrees (0, 30]."),
    max_view_zenith: float = typer.Option(80.0, "--max-view-zenith", help="Largest view zenith of the grid, degrees (0, 89]."),
    no_plot: bool = typer.Option(False, "--no-plot", help="Only write the CSV."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace existing output files."),
) -> None:
    """Draw Ross-Thick, Li-Sparse-R and Cook–Torrance on the principal plane and as polar maps.

    The CSV has columns sun_zenith_deg, view_zenith_deg, relative_azimuth_deg, k_ross, k_li,
    k_cook (Cook–Torrance for a horizontal facet, F0 = 0.04, the given roughness);
    relative azimuth φ = φ_view − φ_sun, φ = 0 is backscatter.
    """

    def bad(cond, msg, field):
        if cond:
            raise UserError(msg, field=field)

    bad(not math.isfinite(sun_zenith) or not (0.0 <= sun_zenith <= 89.0),
        f"sun zenith must be in [0, 89] degrees, got {sun_zenith}", "--sun-zenith")
    bad(not math.isfinite(roughness) or not (0.0 < roughness <= 1.0),
        f"roughness must be in (0, 1], got {roughness}", "--roughness")
    bad(not math.isfinite(step) or not (0.0 < step <= 30.0), f"step must be in (0, 30] degrees, got {step}", "--step")
    bad(not math.isfinite(max_view_zenith) or not (0.0 < max_view_zenith <= 89.0),
        f"max view zenith must be in (0, 89] degrees, got {max_view_zenith}", "--max-view-zenith")
    bad(step > max_view_zenith, f"step ({step}) is larger than the max view zenith ({max_view_zenith})", "--step")
    bad(no_plot and csv_path is None, "--no-plot needs --csv (nothing to write otherwise)", "--no-plot")

    targets: list[Path] = []
    if not no_plot:
        if png is None:
            png = out_dir / f"kernels_sun{sun_zenith:g}.png"
        bad(png.suffix.lower() != ".png", f"the figure path must end in .png: {png}", "--png")
        targets.append(png)
    if csv_path is not None:
        targets.append(csv_path)
    for t in targets:
        if t.exists() and not overwrite:
            raise UserError("exists; pass --overwrite to replace it", file=t)
        if t.exists() and t.is_dir():
            raise UserError("is a folder, expected a file path", file=t)
        try:
            t.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"cannot create the output folder: {exc}", file=t.parent) from exc

    from brfgs.brdf.plots import kernel_grid, plot_kernels, write_kernel_csv

    grid = kernel_grid(sun_zenith, roughness=roughness, step_deg=step, max_view_zenith_deg=max_view_zenith)
    if csv_path is not None:
        write_kernel_csv(csv_path, grid)
        typer.echo(f"wrote {csv_path} ({grid.k_ross.size} rows)")
    if not no_plot:
        plot_kernels(png, grid)
        typer.echo(f"wrote {png}")


def register(app: typer.Typer) -> None:
    app.command("kernels")(kernels_cmd)
