"""``brfgs import colmap PROJECT``: a COLMAP model + cube folder + spectral sidecar → transforms.json
(brfgs.init.colmap_io)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.init.options import ImportColmapOptions

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no pycolmap).

import_app = typer.Typer(help="Bring scenes in from other tools' layouts.", no_args_is_help=True)


@config_command(import_app, "colmap", ImportColmapOptions)
def colmap_cmd(
    project: Path = typer.Argument(..., help="Project folder: transforms.json is written here; the cubes must "
                                   "lie inside it.", show_default=False),
    options: dict | None = None,
) -> None:
    """Write PROJECT/transforms.json from a COLMAP model (PINHOLE, SIMPLE_PINHOLE, OPENCV, SIMPLE_RADIAL,
    RADIAL cameras; per-image cameras kept per frame), the cubes and a spectral sidecar; then
    `brfgs inspect PROJECT` checks it and `brfgs train PROJECT OUT` trains on it."""
    from brfgs.init.colmap_io import import_colmap

    o = apply_options(ImportColmapOptions(), options)
    sparse = project / "sparse" / "0" if o.sparse is None else o.sparse
    images = project / "images" if o.images is None else o.images
    sidecar = o.sidecar
    if sidecar is None and (project / "spectral.json").is_file():
        sidecar = project / "spectral.json"
    tf, info = import_colmap(project, sparse, images, sidecar, overwrite=o.overwrite)
    typer.echo(f"wrote {tf}: {info['frames']} frames, {info['cameras']} camera(s), alignment: {info['alignment']}")
    if info["unregistered"]:
        names = ", ".join(info["unregistered"][:8]) + (", ..." if len(info["unregistered"]) > 8 else "")
        typer.echo(f"left out {len(info['unregistered'])} sidecar frame(s) whose cube COLMAP did not register: {names}")


def register(app: typer.Typer) -> None:
    app.add_typer(import_app, name="import")
