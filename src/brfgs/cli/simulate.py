"""``brfgs simulate``: render a simulated multi-angle hyperspectral scene (Mitsuba 3) with truth."""

from __future__ import annotations

from pathlib import Path

from dataclasses import asdict

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.data.lock import folder_lock
from brfgs.errors import UserError
from brfgs.sim.options import LAYOUTS, SimulateOptions

# The command body imports the simulator lazily, so that `brfgs --help` stays fast (no mitsuba).


def register(app: typer.Typer) -> None:
    @config_command(app, "simulate", SimulateOptions)
    def simulate_cmd(
        out: Path = typer.Argument(..., help="Output scene folder (must be new or empty unless --overwrite)."),
        options: dict | None = None,
    ) -> None:
        """Render an AIR-BRF-like acquisition (nadir + 12 azimuths x 18/23/38/58 deg, or --rings) with ground truth."""
        from brfgs.sim import SimConfig, simulate

        o = apply_options(SimulateOptions(), options)
        cfg = SimConfig(**asdict(o.sim))
        if o.layout not in LAYOUTS:
            raise UserError(f"expected one of {', '.join(LAYOUTS)}, got {o.layout!r}", field="--layout")
        if out.exists() and not out.is_dir():
            raise UserError("output path exists and is not a folder", file=out)
        with folder_lock(out, "brfgs simulate"):  # one writer: the folder checks and the simulation under it
            if o.layout == "native":
                path = simulate(out, cfg, overwrite=o.overwrite, progress=not o.quiet, resume=o.resume)
            else:
                path = _simulate_colmap(out, cfg, o.overwrite, o.resume, o.quiet)
        t = getattr(simulate, "last_timing", {"setup_s": 0.0, "view_s": [], "total_s": 0.0})
        per_view = sorted(t["view_s"])[len(t["view_s"]) // 2] if t["view_s"] else float("nan")
        typer.echo(f"wrote {path} ({cfg.n_views()} views, {cfg.bands} bands, {cfg.size}x{cfg.size}, spp {cfg.spp} "
                   f"{cfg.sampler}); setup {t['setup_s']:.1f} s, median {per_view:.2f} s per view, total "
                   f"{t['total_s']:.1f} s")


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
