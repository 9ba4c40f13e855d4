"""``brfgs import colmap PROJECT``: a COLMAP model + cube folder + spectral sidecar → transforms.json
(brfgs.init.colmap_io)."""

from __future__ import annotations

from pathlib import Path

import typer

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no pycolmap).

import_app = typer.Typer(help="Bring scenes in from other tools' layouts.", no_args_is_help=True)


@import_app.command("colmap")
def colmap_cmd(
    project: Path = typer.Argument(..., help="Project folder: transforms.json is written here; the cubes must "
                                   "lie inside it.", show_default=False),
    sparse: Path = typer.Option(None, "--sparse", help="COLMAP sparse model folder (cameras/images/points3D, .bin "
                                "or .txt) (default: PROJECT/sparse/0)."),
    images: Path = typer.Option(None, "--images", help="Folder of the hyperspectral cubes, named like the COLMAP "
                                "images (stem + .hdr/.tif/.tiff/.npy) (default: PROJECT/images)."),
    sidecar: Path = typer.Option(None, "--sidecar", help="JSON with wavelengths_nm, fwhm_nm, sun_zenith_deg, "
                                 "sun_azimuth_deg, optionally origin/crs, dark_frames/dark_sigma, and enu_from_colmap "
                                 "(4x4 similarity) or camera_positions_enu ({image stem: (x, y, z)}) "
                                 "(default: PROJECT/spectral.json if present)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing PROJECT/transforms.json."),
) -> None:
    """Write PROJECT/transforms.json from a COLMAP model (PINHOLE, SIMPLE_PINHOLE, OPENCV, SIMPLE_RADIAL,
    RADIAL cameras; per-image cameras kept per frame), the cubes and a spectral sidecar; then
    `brfgs inspect PROJECT` checks it and `brfgs train PROJECT OUT` trains on it."""
    from brfgs.init.colmap_io import import_colmap

    sparse = project / "sparse" / "0" if sparse is None else sparse
    images = project / "images" if images is None else images
    if sidecar is None and (project / "spectral.json").is_file():
        sidecar = project / "spectral.json"
    tf, info = import_colmap(project, sparse, images, sidecar, overwrite=overwrite)
    typer.echo(f"wrote {tf}: {info['frames']} frames, {info['cameras']} camera(s), alignment: {info['alignment']}"
               + (f"; {info['skipped_unregistered']} unregistered image(s) left out" if info["skipped_unregistered"]
                  else ""))


def register(app: typer.Typer) -> None:
    app.add_typer(import_app, name="import")
