"""``brfgs export RUN OUT``: the Gaussians as a 3DGS PLY and the model file (brfgs.products.export)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._options import OverwriteOpt, RunArg

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def export_cmd(
    run: Path = RunArg,
    out: Path = typer.Argument(..., help="Output folder (gaussians.ply, model.safetensors, export.json).",
                               show_default=False),
    view_dependence: str = typer.Option("fit", "--view-dependence",
                                        help="'fit': the view-dependent CIR colour of each Gaussian (training sun) "
                                        "fitted with degree-3 SH into f_dc/f_rest, so viewers show the BRF's "
                                        "hotspot and glint; 'none': the nadir-view colour, f_rest all zero."),
    sh_directions: int = typer.Option(48, "--sh-directions", min=16, max=1024,
                                      help="View directions (zenith <= 80 deg) sampled per Gaussian for the SH fit."),
    up: str = typer.Option(None, "--up", help="Up axis of the PLY: 'z' (default: the scene's ENU frame, metres), "
                           "'y' (y-up, glTF axes: x east, y up, z south) or '-y' (3DGS/COLMAP convention that SuperSplat "
                           "and PlayCanvas expect). The y frames are centred on the scene."),
    target: str = typer.Option(None, "--for", help="Named viewer: 'supersplat' or 'playcanvas' (= --up -y), "
                               "'enu' (= --up z)."),
    scale: float = typer.Option(1.0, "--scale", help="PLY units per metre."),
    overwrite: bool = OverwriteOpt,
) -> None:
    """Export the Gaussians as a 3DGS PLY (full standard attribute set x y z nx ny nz f_dc_0..2 f_rest_0..44
    opacity scale_0..2 rot_0..3 with CIR colours, + BRF parameters) and the self-describing model file."""
    from brfgs.products.export import VIEWER_TARGETS, ExportOptions, export_model
    from brfgs.errors import UserError

    if target is not None and target not in VIEWER_TARGETS:
        raise UserError(f"expected one of {', '.join(VIEWER_TARGETS)}, got {target!r}", field="--for")
    if target is not None and up is not None and VIEWER_TARGETS[target] != up:
        raise UserError(f"--for {target} writes --up {VIEWER_TARGETS[target]}, not {up}", field="--up")
    up = up if up is not None else VIEWER_TARGETS.get(target, "z")
    info = export_model(run, out, ExportOptions(view_dependence=view_dependence, sh_directions=sh_directions,
                                                up=up, scale=scale, overwrite=overwrite))
    typer.echo(f"wrote {out / info['ply']} ({info['n_gaussians']} Gaussians) and {out / info['model']}")


def register(app: typer.Typer) -> None:
    app.command("export")(export_cmd)
