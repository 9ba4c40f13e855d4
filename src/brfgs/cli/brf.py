"""``brfgs brf RUN --roi ...``: the BRF of a region (brfgs.analysis.brf_report)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.analysis.options import parse_floats
from brfgs.cli._options import BackendOpt, OverwriteOpt, QuietOpt, RunArg

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def brf_cmd(
    run: Path = RunArg,
    roi: str = typer.Option(..., "--roi", help="polygon:X1,Y1;X2,Y2;... (ENU m) | FILE.geojson (or geojson:FILE): "
                            "a Polygon/MultiPolygon geometry, Feature or FeatureCollection (union) with "
                            "coordinates in the scene's local ENU metres (x east, y north; not lon/lat; a 'crs' "
                            "member other than a local/ENU one is refused) | box:VIEW:C0,R0,C1,R1 | "
                            "mask:VIEW:FILE(.npy/.png) | material:NAME (simulated scenes)."),
    roi_name: str = typer.Option(None, "--roi-name", help="Name used in file names and titles."),
    bands: str = typer.Option("480,680,760,860", "--bands", help="Wavelengths (nm) of the curves and maps."),
    scene: Path = typer.Option(None, "--scene", help="Scene folder for observations/truth "
                               "(default: the training scene, when it still exists)."),
    step: float = typer.Option(2.5, "--step", min=0.1, help="Principal-plane step (deg)."),
    max_zenith: float = typer.Option(75.0, "--max-zenith", min=1.0, max=85.0, help="Largest view zenith (deg)."),
    polar_azimuths: int = typer.Option(60, "--polar-azimuths", min=4, help="Azimuth sectors of the polar map."),
    polar_zeniths: int = typer.Option(24, "--polar-zeniths", min=2, help="Zenith rings of the polar map."),
    no_polar: bool = typer.Option(False, "--no-polar", help="Skip the polar maps."),
    min_alpha: float = typer.Option(0.5, "--min-alpha", min=0.0, max=1.0,
                                    help="Pixels count for the ROI only where the accumulated opacity is at least this."),
    distance: float = typer.Option(None, "--distance", min=1.0, help="ROI camera distance (m) (default: the "
                                   "training cameras' median distance, at least 8 ROI radii)."),
    size: int = typer.Option(None, "--size", min=8, max=1024, help="Pixels of the square ROI camera (the ROI fills "
                             "~90 percent of it) (default: the training images' pixel footprint on the ground)."),
    truth_render: bool = typer.Option(True, "--truth-render/--no-truth-render",
                                      help="On simulated scenes (truth/scene.json), render the truth again with the "
                                      "simulator along the principal plane and on a coarse polar grid, and report "
                                      "the model's BRF error per band (slow: about 0.3-1 s per direction)."),
    truth_step: float = typer.Option(10.0, "--truth-step", min=1.0, help="Principal-plane step (deg) of the truth renders."),
    truth_size: int = typer.Option(128, "--truth-size", min=16, help="Pixels of the principal-plane truth renders "
                                   "(acquisition FOV)."),
    truth_polar_azimuths: int = typer.Option(12, "--truth-polar-azimuths", min=1,
                                             help="Azimuth sectors of the truth polar grid (coarse: each direction is "
                                             "a simulator render)."),
    truth_polar_zeniths: int = typer.Option(6, "--truth-polar-zeniths", min=1,
                                            help="Zenith rings of the truth polar grid."),
    truth_polar_size: int = typer.Option(64, "--truth-polar-size", min=16,
                                         help="Pixels of the polar truth renders (acquisition FOV)."),
    truth_spp: int = typer.Option(16, "--truth-spp", min=1, help="Samples per pixel of all truth renders: a power "
                                  "of 4 (1, 4, 16, 64, 256) for scenes simulated with the default 'ldsampler', a "
                                  "power of two for older 'independent' scenes."),
    max_plane_offset: float = typer.Option(20.0, "--max-plane-offset",
                                           help="Observations within this azimuth (deg) of the principal plane are plotted."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: RUN/analysis/brf_<roi name>)."),
    threads: int = typer.Option(1, "--threads", min=0, help="PyTorch threads in the sampling loops "
                                "(0 = leave as is; 1 is fastest for small ROI cameras)."),
    backend: str = BackendOpt,
    overwrite: bool = OverwriteOpt,
    quiet: bool = QuietOpt,
) -> None:
    """BRF of a region: principal-plane curves, polar maps, spectra vs observations (and truth), CSVs.

    On a simulated scene (truth/scene.json) the simulator renders the truth again for the principal
    plane and a coarse polar grid (polar_truth.png/.csv); per-band RMSE and mean bias of the model
    against it are in brf.json and truth_error.csv.
    """
    from brfgs.analysis.brf_report import BRFOptions, TruthOptions, brf_report

    truth = TruthOptions(render=truth_render, step_deg=truth_step, size=truth_size, polar_azimuths=truth_polar_azimuths,
                         polar_zeniths=truth_polar_zeniths, polar_size=truth_polar_size, spp=truth_spp)
    opts = BRFOptions(roi=roi, roi_name=roi_name, bands_nm=tuple(parse_floats(bands, "--bands")), scene=scene,
                      step_deg=step, max_zenith_deg=max_zenith, polar_azimuths=polar_azimuths,
                      polar_zeniths=polar_zeniths, polar=not no_polar, min_alpha=min_alpha, distance_m=distance,
                      size=size, truth=truth, max_plane_offset_deg=max_plane_offset, threads=threads, backend=backend,
                      overwrite=overwrite, progress=not quiet)
    typer.echo(brf_report(run, opts, out, warn=lambda message: typer.echo(message, err=True)).message)


def register(app: typer.Typer) -> None:
    app.command("brf")(brf_cmd)
