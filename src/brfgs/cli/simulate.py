"""``brfgs simulate``: render a simulated multi-angle hyperspectral scene (Mitsuba 3) with truth."""

from __future__ import annotations

from pathlib import Path

import typer

# The command body imports the simulator lazily, so that `brfgs --help` stays fast (no mitsuba).


def register(app: typer.Typer) -> None:
    @app.command("simulate")
    def simulate_cmd(
        out: Path = typer.Argument(..., help="Output scene folder (must be new or empty unless --overwrite)."),
        scene: str = typer.Option("testsite", "--scene", help="Scene: testsite, forest or flat."),
        size: int = typer.Option(128, "--size", help="Image width = height in pixels (>= 8)."),
        bands: int = typer.Option(164, "--bands", help="Number of bands over 350-1000 nm."),
        views: int = typer.Option(49, "--views", help="Number of views: 1, 13, 25, 37 or 49 (the paper's layout)."),
        rings: str = typer.Option(None, "--rings", metavar="Z1,Z2,...",
                                  help="Another view layout: nadir + --azimuths views on each of these view-zenith "
                                  "rings (degrees, e.g. 15,30,45,65), instead of --views."),
        azimuths: int = typer.Option(12, "--azimuths", help="Views per ring of --rings, evenly spaced from 0 deg."),
        spp: int = typer.Option(64, "--spp", help="Samples per pixel: a power of 4 (1, 4, 16, 64, 256) for "
                                "the default ldsampler, a power of two for independent."),
        sampler: str = typer.Option("ldsampler", "--sampler",
                                    help="Monte Carlo sampler: ldsampler (low discrepancy) or independent."),
        sun_zenith: float = typer.Option(38.0, "--sun-zenith", help="Sun zenith angle, degrees [0, 89]."),
        sun_azimuth: float = typer.Option(150.0, "--sun-azimuth",
                                          help="Sun azimuth, degrees clockwise from north."),
        seed: int = typer.Option(0, "--seed", help="Seed of every random choice."),
        start_time: str = typer.Option(None, "--start-time", help="UTC time of the first view (ISO 8601, e.g. "
                                       "2024-06-21T07:00:00Z; needs --origin): every view gets its time and the sun "
                                       "of that time (NREL SPA), so the sun moves over the flight."),
        duration: float = typer.Option(0.0, "--duration-min", help="Minutes from the first to the last view."),
        distortion: str = typer.Option(None, "--distortion", metavar="K1,K2,P1,P2",
                                       help="OPENCV lens distortion of the camera (e.g. -0.12,0.03,0.001,-0.0005): "
                                       "images rendered through it, transforms.json camera_model OPENCV."),
        irradiance_drift: float = typer.Option(0.0, "--irradiance-drift", help="Amplitude d of a smooth per-view "
                                               "drift of the downwelling irradiance (factor in [1-d, 1+d], written "
                                               "as each frame's irradiance_scale)."),
        origin: str = typer.Option(None, "--origin", metavar="LAT,LON[,ALT]",
                                   help="Put the scene on the Earth: WGS 84 latitude, longitude (deg) and "
                                   "ellipsoidal height (m) of the scene centre, written to transforms.json; "
                                   "products are then georeferenced (UTM zone of the origin)."),
        distance: float = typer.Option(100.0, "--distance", help="Camera distance from the scene centre, m."),
        fov: float = typer.Option(35.0, "--fov", help="Horizontal field of view, degrees."),
        noise_scale: float = typer.Option(1.0, "--noise-scale", help="Multiplies the dark noise sigma_b."),
        shot_coeff: float = typer.Option(0.01, "--shot-coeff", help="Signal-dependent noise k (var = k^2 rho)."),
        n_dark: int = typer.Option(20, "--dark-frames", help="Number of dark frames in calibration/."),
        max_depth: int = typer.Option(10, "--max-depth", help="Longest light path (bounces)."),
        layout: str = typer.Option("native", "--layout", help="native: transforms.json + ENVI cubes; colmap: "
                                   "a COLMAP project as a user brings it (images/*.tif LZW cubes, sparse/0 in an "
                                   "arbitrary frame, spectral.json sidecar; then `brfgs import colmap OUT`)."),
        overwrite: bool = typer.Option(False, "--overwrite", help="Replace a simulation already in OUT."),
        resume: bool = typer.Option(False, "--resume", help="Continue an interrupted simulation in OUT."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Render an AIR-BRF-like acquisition (nadir + 12 azimuths x 18/23/38/58 deg, or --rings) with ground truth."""
        from brfgs.analysis.options import parse_floats
        from brfgs.sim import SimConfig, simulate

        cfg = SimConfig(scene=scene, size=size, bands=bands, views=views, spp=spp, sun_zenith_deg=sun_zenith,
                        sun_azimuth_deg=sun_azimuth, seed=seed, distance_m=distance, fov_deg=fov,
                        noise_scale=noise_scale, shot_coeff=shot_coeff, n_dark=n_dark, max_depth=max_depth,
                        sampler=sampler, start_time=start_time, duration_min=duration,
                        irradiance_drift=irradiance_drift,
                        distortion=None if distortion is None else tuple(parse_floats(distortion, "--distortion", 4)),
                        origin=None if origin is None else tuple(parse_floats(origin, "--origin")),
                        rings_deg=None if rings is None else tuple(parse_floats(rings, "--rings")), n_azimuths=azimuths)
        if layout not in ("native", "colmap"):
            from brfgs.errors import UserError
            raise UserError(f"expected native or colmap, got {layout!r}", field="--layout")
        if layout == "native":
            path = simulate(out, cfg, overwrite=overwrite, progress=not quiet, resume=resume)
        else:
            path = _simulate_colmap(out, cfg, overwrite, resume, quiet)
        t = getattr(simulate, "last_timing", {"setup_s": 0.0, "view_s": [], "total_s": 0.0})
        per_view = sorted(t["view_s"])[len(t["view_s"]) // 2] if t["view_s"] else float("nan")
        typer.echo(f"wrote {path} ({cfg.n_views()} views, {cfg.bands} bands, {cfg.size}x{cfg.size}, spp {cfg.spp} {cfg.sampler}); "
                   f"setup {t['setup_s']:.1f} s, median {per_view:.2f} s per view, total {t['total_s']:.1f} s")


def _simulate_colmap(out: Path, cfg, overwrite: bool, resume: bool, quiet: bool) -> Path:
    """Simulate into OUT/.native (resumable), then write OUT as a COLMAP project and drop the staging."""
    import shutil

    from brfgs.init.colmap_project import prepare_project_dir, write_colmap_project
    from brfgs.sim import simulate

    prepare_project_dir(out, overwrite, resume)
    staging = out / ".native"
    if not (resume and (staging / "transforms.json").is_file()):     # else only the conversion was cut short
        simulate(staging, cfg, overwrite=overwrite, progress=not quiet, resume=resume)
    info = write_colmap_project(staging, out, seed=cfg.seed, move_extras=True)
    shutil.rmtree(staging)
    typer.echo(f"wrote the COLMAP project {out}: {info['images']} LZW TIFF cubes, sparse/0 ({info['cameras']} "
               f"camera(s), {info['points']} points, arbitrary frame), spectral.json; next: brfgs import colmap {out}")
    return out
