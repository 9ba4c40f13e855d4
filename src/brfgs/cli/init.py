"""``brfgs init SCENE OUT``: band selection + SfM (pycolmap) or known poses → cameras and sparse points."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from brfgs.cli import _options as opt
from brfgs.cli._config import apply_options, config_command
from brfgs.errors import UserError
from brfgs.init.options import InitCommandOptions

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no pycolmap;
# pycolmap must never be imported before zlib, see brfgs.init).


def init_cmd(scene: Path, out: Path, options: dict) -> None:
    """Select geometry bands, then SfM or known-pose triangulation; write cameras, sparse points and a report."""
    from brfgs.init import colmap as C
    from brfgs.init import initialize
    from brfgs.init.api import write_outputs

    o = apply_options(InitCommandOptions(), options).validate()
    C.set_verbose(o.verbose)
    sc = opt.read_scene(scene, o.read)
    opt.check_output_dir(out, sc.root, overwrite=o.overwrite, marker="init_report.json")
    if o.bands is not None:
        selection, rows = _given_bands(o.bands, sc), None
    else:
        selection, rows = _select(sc, o.strategy, o.top, o.min_separation_nm, o.sfm, o.quiet)
    res = initialize(sc, selection.selected, poses=o.poses, out_dir=None, config=o.sfm, selection=selection,
                     progress=not o.quiet)
    if rows is not None:
        res.report["strategies"] = rows
        res.report["strategies_definition"] = ("each row: features of that strategy's bands, COLMAP exhaustive "
                                               "matching and verification on the same views; see definitions")
    write_outputs(out, sc, res, selection)
    _echo_report(res.report, rows)
    typer.echo(f"\nwrote {out}/points.ply, tracks.npz, cameras.json, init_report.json, init_report.md")


def _given_bands(text: str, sc):
    """The BandSelection of ``--bands`` (indices or a bands.json)."""
    from brfgs.bands import BandSelection

    idx = _parse_bands(text, sc)
    return BandSelection("given", idx, sc.wavelengths_nm, top=len(idx))


def _select(sc, strategy: str, top: int, min_separation: float, cfg, quiet: bool):
    """(BandSelection, Table 2 rows or None) of ``--strategy`` (all-strategies: the eight strategies'
    geometry columns, then efc-top3)."""
    from brfgs.bands import compute_band_stats, select_bands
    from brfgs.init import strategy_ablation

    if strategy != "all-strategies":
        return select_bands(sc, strategy, top=top, progress=not quiet, min_separation_nm=min_separation), None
    stats = compute_band_stats(sc, progress=not quiet)
    if not quiet:
        typer.echo("Table 2 geometry columns, eight strategies:")
    rows = strategy_ablation(sc, top=top, stats=stats, config=cfg, progress=not quiet)
    return select_bands(sc, "efc-top3", stats=stats, min_separation_nm=min_separation), rows


def _echo_report(r: dict, rows) -> None:
    """Print the initialisation report's numbers (and the strategies table)."""
    from brfgs.init.api import strategies_table

    g = r["geometry"]
    typer.echo(f"poses {r['poses']}: {r['registered_views']}/{r['views']} views registered, {r['points']} points, "
               f"mean track length {r['mean_track_length'] or 0:.2f}, reprojection error "
               f"{r['mean_reprojection_error_px'] or 0:.3f} px")
    typer.echo(f"features per view {g['mean_detected_features_per_view']:.1f}, matching success rate "
               f"{(g['matching_success_rate'] or 0):.1%}")
    if r.get("truth"):
        t = r["truth"]
        msg = (f"truth: camera-centre error median {t['camera_centre_error_rel']['median']:.3%}, max "
               f"{t['camera_centre_error_rel']['max']:.3%} of the camera distance")
        if t.get("point_to_surface_rel"):
            msg += f"; point-to-surface median {t['point_to_surface_rel']['median']:.3%}"
        if t.get("views_above_1pct"):
            msg += f"; views above 1%: {', '.join(t['views_above_1pct'])}"
        typer.echo(msg)
    if rows is not None:
        typer.echo("\n" + strategies_table(rows))


def _parse_bands(text: str, sc) -> list[int]:
    p = Path(text)
    if p.suffix == ".json" or p.is_file():
        try:
            data = json.loads(p.read_text())
            return [int(s["index"]) for s in data["selected"]]
        except FileNotFoundError:
            raise UserError("bands file not found", file=p) from None
        except (ValueError, KeyError, TypeError) as exc:
            raise UserError(f"not a bands.json with 'selected': [{{'index': ...}}] ({exc})", file=p) from None
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"expected band indices 'i,j,k' or a bands.json path, got {text!r}", field="--bands") from None


def register(app: typer.Typer) -> None:
    @config_command(app, "init", InitCommandOptions)
    def command(
        scene: Path = opt.SceneArg,
        out: Path = typer.Argument(..., help="Output folder (points.ply, tracks.npz, cameras.json, init_report.json/"
                                   ".md, bands.json, sparse/0).", show_default=False),
        options: dict | None = None,
    ) -> None:
        """Select geometry bands, then SfM or known-pose triangulation; write cameras, sparse points and a report."""
        init_cmd(scene, out, options)
