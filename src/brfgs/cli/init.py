"""``brfgs init SCENE OUT``: band selection + SfM (pycolmap) or known poses → cameras and sparse points."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from brfgs.cli import _options as opt
from brfgs.errors import UserError

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no pycolmap;
# pycolmap must never be imported before zlib, see brfgs.init).

BANDS_HELP = "Explicit band indices 'i,j,k' or a bands.json from select-bands (overrides --strategy)."
RECTIFY_HELP = ("SfM: detect features on nadir-rectified copies of oblique views (uses only the cameras' orientation "
                "from transforms.json; beyond the paper).")
REFINEMENT_HELP = ("SfM: retriangulate and finish with a global bundle adjustment with a Cauchy loss (beyond the "
                   "paper).")


def init_cmd(
    scene: Path = opt.SceneArg,
    out: Path = typer.Argument(..., help="Output folder (points.ply, tracks.npz, cameras.json, init_report.json/.md, "
                               "bands.json, sparse/0).",
                               show_default=False),
    poses: str = typer.Option("auto", "--poses", "-p",
                              help="sfm: COLMAP incremental SfM aligned to ENU; known: triangulate with the poses "
                                   "of transforms.json; auto: known when every frame has a transform_matrix, "
                                   "else sfm (falling back to the nominal poses if SfM fails)."),
    strategy: str = typer.Option(
        "efc-top3", "--strategy", "-s",
        help="Band strategy: efc, efc-top1, efc-top3, all, rgb, cir, central, max-snr, max-features, or "
             "all-strategies (Table 2 geometry columns for the eight strategies, then init with efc-top3)."),
    top: int = typer.Option(3, "--top", "-k", min=1, help="k of the 'efc' strategy."),
    min_separation: float = typer.Option(0.0, "--min-separation-nm", min=0.0,
                                         help="EFC strategies: chosen bands at least this far apart in wavelength "
                                              "(beyond the paper; 0 = paper eq. 8)."),
    bands: str = typer.Option(None, "--bands", help=BANDS_HELP),
    max_features: int = typer.Option(8192, "--max-features", min=16, help="Features per view kept for matching."),
    min_inliers: int = typer.Option(15, "--min-inliers", min=5, help="Verified matches a view pair needs."),
    min_track: int = typer.Option(2, "--min-track", min=2, help="Drop sparse points seen in fewer views."),
    max_point_error: float = typer.Option(2.0, "--max-point-error", min=0.1,
                                          help="Drop sparse points with a larger mean reprojection error (px)."),
    detect_upsample: int = typer.Option(0, "--detect-upsample", min=0,
                                        help="Detect features on a xN cubic-upsampled copy (0: 2 for SfM on images up "
                                             "to 256 px, else 1)."),
    rectify: bool = typer.Option(True, "--rectify/--no-rectify", help=RECTIFY_HELP),
    robust_refinement: bool = typer.Option(True, "--robust-refinement/--no-robust-refinement", help=REFINEMENT_HELP),
    threads: int = typer.Option(1, "--threads", min=1, help="COLMAP mapping threads (1 gives deterministic mapping)."),
    match_threads: int = typer.Option(1, "--match-threads", min=-1,
                                      help="COLMAP matching threads (1 gives deterministic matches; -1 = all: about "
                                           "1.7x faster matching on 2 cores, see BENCHMARKS.md)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (RANSAC, mapping)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a finished initialisation in OUT."),
    keep_database: bool = typer.Option(False, "--keep-database", help="Keep OUT/colmap/database.db."),
    downscale: int = opt.DownscaleOpt,
    value_range: str = opt.ValueRangeOpt,
    allow_outside_links: bool = opt.AllowLinksOpt,
    verbose: bool = typer.Option(False, "--verbose", help="Show COLMAP's log."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output."),
) -> None:
    """Select geometry bands, then SfM or known-pose triangulation; write cameras, sparse points and a report."""
    from brfgs.init import InitConfig, initialize
    from brfgs.init import colmap as C
    from brfgs.init.api import write_outputs

    if match_threads == 0:
        raise UserError("--match-threads must be >= 1 or -1 (all threads), got 0", field="match_threads")
    C.set_verbose(verbose)
    sc = opt.load_scene(scene, downscale, value_range, allow_outside_links=allow_outside_links)
    opt.check_output_dir(out, sc.root, overwrite=overwrite, marker="init_report.json")
    cfg = InitConfig(max_features=max_features, min_inliers=min_inliers, num_threads=threads, match_threads=match_threads, seed=seed,
                     keep_database=keep_database, min_track_length=min_track, max_point_error_px=max_point_error,
                     detect_upsample=detect_upsample, rectify=rectify, robust_refinement=robust_refinement)
    if bands is not None:
        selection, rows = _given_bands(bands, sc), None
    else:
        selection, rows = _select(sc, strategy, top, min_separation, cfg, quiet)
    res = initialize(sc, selection.selected, poses=poses, out_dir=None, config=cfg, selection=selection,
                     progress=not quiet)
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
    app.command("init")(init_cmd)
