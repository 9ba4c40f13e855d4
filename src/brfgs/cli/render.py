"""``brfgs render RUN``: the model from any view under any sun (brfgs.analysis.render_report)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.analysis.options import parse_floats, parse_size
from brfgs.cli._options import BackendOpt, OverwriteOpt, QuietOpt, RunArg

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).

REPEAT_HELP = ("Render this many times; timings report the median of the calls after the first (which also loads "
               "compiled kernels).")


def render_cmd(
    run: Path = RunArg,
    view_zenith: float = typer.Option(..., "--view-zenith", help="View zenith (deg, 0 = nadir, < 90)."),
    view_azimuth: float = typer.Option(..., "--view-azimuth", help="View azimuth (deg, clockwise from north, "
                                       "direction from the target toward the sensor)."),
    sun_zenith: float = typer.Option(None, "--sun-zenith", help="Sun zenith (deg) (default: the training sun)."),
    sun_azimuth: float = typer.Option(None, "--sun-azimuth", help="Sun azimuth (deg) (default: the training sun)."),
    distance: float = typer.Option(None, "--distance", help="Camera distance to the target (m) "
                                   "(default: median distance of the training cameras)."),
    target: str = typer.Option(None, "--target", metavar="X,Y,Z", help="Point looked at (ENU m) "
                               "(default: median Gaussian position)."),
    size: str = typer.Option(None, "--size", metavar="W[,H]", help="Image size in pixels (default: training size)."),
    fov: float = typer.Option(None, "--fov", help="Horizontal field of view (deg) (default: training camera's)."),
    path: str = typer.Option(None, "--path", help="'orbit' (all azimuths at --view-zenith) or 'sweep' "
                             "(through nadir in the plane of --view-azimuth, up to --view-zenith): PNG sequence + GIF."),
    frames: int = typer.Option(36, "--frames", min=2, help="Frames of --path."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: RUN/analysis/render_z<Z>_a<A>)."),
    repeat: int = typer.Option(1, "--repeat", min=1, help=REPEAT_HELP),
    backend: str = BackendOpt,
    overwrite: bool = OverwriteOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Render the model from any view: ENVI cube, CIR PNG, depth and normal maps (PNG + .npy), timing."""
    from brfgs.analysis.render_report import RenderOptions, render_report

    opts = RenderOptions(view_zenith_deg=view_zenith, view_azimuth_deg=view_azimuth, sun_zenith_deg=sun_zenith,
                         sun_azimuth_deg=sun_azimuth, distance_m=distance,
                         target_m=None if target is None else tuple(parse_floats(target, "--target", 3)),
                         size=None if size is None else parse_size(size, "--size"), fov_deg=fov, path=path,
                         frames=frames, repeat=repeat, backend=backend, overwrite=overwrite, progress=not quiet)
    typer.echo(render_report(run, opts, out).message)


def register(app: typer.Typer) -> None:
    app.command("render")(render_cmd)
