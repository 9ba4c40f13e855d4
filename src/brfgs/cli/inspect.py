"""``brfgs inspect SCENE``: validate a scene, print a summary table, plot the view directions."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli import _options as opt
from brfgs.cli._config import apply_options, config_command
from brfgs.data.options import InspectOptions, MergeOptions

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def register(app: typer.Typer) -> None:
    @config_command(app, "inspect", InspectOptions)
    def inspect_cmd(scene: Path = opt.SceneArg, options: dict | None = None) -> None:
        """Read and validate a scene; print frames, bands, split, angles, per-band noise/SNR and NaN counts."""
        from brfgs.data import atomic
        from brfgs.data.summary import format_summary, plot_views, summarize

        o = apply_options(InspectOptions(), options)
        sc = opt.read_scene(scene, o.read, split_seed=o.split_seed)
        out = o.out if o.out is not None else Path.cwd() / f"inspect_{sc.name}"
        opt.check_output_dir(out, sc.root, overwrite=True)
        summary = summarize(sc, progress=not o.quiet)
        out.mkdir(parents=True, exist_ok=True)
        atomic.write_json(out / "summary.json", summary.to_json())
        plot_views(sc, out / "views_polar.png")
        typer.echo(format_summary(summary))
        typer.echo(f"\nwrote {out / 'summary.json'} and {out / 'views_polar.png'}")

    @config_command(app, "merge", MergeOptions)
    def merge_cmd(out: Path = typer.Argument(..., help="New (or empty) scene folder for the merged flights, written "
                                                         "all at once: a failure leaves none."),
                  scenes: list[Path] = typer.Argument(..., help="Two or more co-registered flights of one site."),
                  options: dict | None = None) -> None:
        """One scene from several flights of a site (other hours or days): each frame under its own sun, each
        flight's split kept; train on it to learn the site under several suns."""
        from brfgs.workflows.merge_flights import merge_flights

        o = apply_options(MergeOptions(), options)
        merged = merge_flights(out, scenes, split_seed=o.split_seed)
        for f in merged["flights"]:
            typer.echo(f"{f['name']}: {f['frames']} frames from {f['source']}")
        typer.echo(f"wrote {out / 'transforms.json'} ({len(merged['frames'])} frames)")
