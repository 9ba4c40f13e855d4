"""``brfgs inspect SCENE``: validate a scene, print a summary table, plot the view directions."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.cli import _options as opt

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def inspect_cmd(
    scene: Path = opt.SceneArg,
    out: Path = typer.Option(None, "--out", "-o",
                             help="Folder for views_polar.png and summary.json [default: ./inspect_<scene>]."),
    downscale: int = opt.DownscaleOpt,
    value_range: str = opt.ValueRangeOpt,
    allow_outside_links: bool = opt.AllowLinksOpt,
    split_seed: int = opt.SplitSeedOpt,
    split_rule: str = opt.SplitRuleOpt,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Read and validate a scene; print frames, bands, split, angles, per-band noise/SNR and NaN counts."""
    from brfgs.data import atomic
    from brfgs.data.summary import format_summary, plot_views, summarize

    sc = opt.load_scene(scene, downscale, value_range, split_seed, split_rule,
                        allow_outside_links=allow_outside_links)
    out = out if out is not None else Path.cwd() / f"inspect_{sc.name}"
    opt.check_output_dir(out, sc.root, overwrite=True)
    summary = summarize(sc, progress=not quiet)
    out.mkdir(parents=True, exist_ok=True)
    atomic.write_json(out / "summary.json", summary.to_json())
    plot_views(sc, out / "views_polar.png")
    typer.echo(format_summary(summary))
    typer.echo(f"\nwrote {out / 'summary.json'} and {out / 'views_polar.png'}")


def register(app: typer.Typer) -> None:
    app.command("inspect")(inspect_cmd)
