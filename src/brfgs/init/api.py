"""Step 3 of the pipeline: cameras and a sparse point cloud from the selected bands.

    res = initialize(scene, band_indices, poses="known"|"sfm"|"auto", out_dir=...)
    res.points [P, 3] (m, ENU)   res.colors [P, k] (reflectance in the selected bands)
    res.c2w [F, 4, 4] (OpenGL)   res.registered [F]   res.report (init_report.json)

Features: SIFT on an 8-bit stretch of each selected band, pooled over bands with duplicates
removed (:mod:`brfgs.init.features`); matching: COLMAP exhaustive matching with ratio test and
cross check (putative matches), then two-view geometric verification by RANSAC (verified
matches). ``sfm`` runs COLMAP incremental mapping with the known intrinsics and aligns the
result to the scene's ENU frame by a similarity (Umeyama) fitted to the camera centres of
transforms.json (measured or nominal), so angles keep their meaning. ``known`` triangulates
the verified matches with the poses of transforms.json (COLMAP point triangulator).
Two steps go beyond the paper (both on by default for ``sfm``, ``InitConfig.rectify`` and
``robust_refinement``): features of oblique views are detected on a nadir-rectified copy (a pure-rotation
homography from the camera orientation only; keypoints mapped back to the image), which gives the 58° views
matches with the other rings; and mapping ends with retriangulation and a Cauchy-loss global bundle
adjustment, which keeps the weakly constrained near-nadir cameras from being pulled by a few bad matches.
``auto`` uses ``known`` when every frame of transforms.json has a ``transform_matrix``
(e.g. RTK/gimbal poses) and ``sfm`` when some frames only give nominal view angles; if SfM
then fails it falls back to the nominal poses (recorded in the report).
"""

from __future__ import annotations

import errno
import json
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from brfgs.bands.efc import make_sift
from brfgs.bands.select import (STRATEGY_LABELS, TABLE2_STRATEGIES, _block_mean, compute_band_stats,
                                detect_downscale_factor, select_bands)
from brfgs.data.cameras import project_points
from brfgs.errors import UserError
from brfgs.init.align import umeyama_robust
from brfgs.init.features import ViewFeatures, extract_view_features, nadir_rectification
from brfgs.init.options import POSE_MODES, InitConfig  # noqa: F401  (re-exported)
from brfgs.init.plane import plane_arrays

MIN_TRIANGULATED = 8  # fewer known-pose points than this: the scene has too little texture to start from them
from brfgs.init.outputs import (DEFINITIONS, fmt_or_na, report_markdown,  # noqa: F401  (re-exported)
                                strategies_table, write_outputs, write_points_ply)
from brfgs.init.truth import truth_checks



@dataclass
class InitResult:
    """Cameras and sparse points of a scene (frames in the scene's order)."""

    points: np.ndarray          # [P, 3] metres, ENU
    colors: np.ndarray          # [P, k] mean observed reflectance in the selected bands
    c2w: np.ndarray             # [F, 4, 4] OpenGL camera-to-world
    registered: np.ndarray      # [F] bool: pose from SfM (True) or taken from transforms.json
    track_length: np.ndarray    # [P]
    error_px: np.ndarray        # [P] mean reprojection error of each point
    band_indices: list[int]
    report: dict = field(default_factory=dict)
    obs_frame: np.ndarray | None = None     # [O] frame of each observation (the points' tracks)
    obs_point: np.ndarray | None = None     # [O] point of each observation


def _frames_have_poses(scene) -> bool:
    try:
        meta = json.loads((Path(scene.root) / "transforms.json").read_text())
        return all(fr.get("transform_matrix") is not None for fr in meta.get("frames", []))
    except (OSError, ValueError):
        return True


def _check_bands(scene, band_indices) -> list[int]:
    b = [int(i) for i in np.asarray(band_indices).reshape(-1)]
    n_b = len(scene.wavelengths_nm)
    if not b:
        raise UserError("no bands selected for initialisation", field="bands")
    bad = [i for i in b if not 0 <= i < n_b]
    if bad:
        raise UserError(f"band indices {bad} outside 0..{n_b - 1}", field="bands")
    if len(set(b)) != len(b):
        raise UserError(f"band indices repeat: {b}", field="bands")
    return b


def extract_features(scene, band_indices, config: InitConfig, progress: bool = False, keep_cubes: bool = True,
                     mode: str = "sfm", rectify: bool | None = None):
    """Features of every view on the selected bands. Returns (features [F], cubes [F] or None, factor).

    ``rectify`` (default: ``config.rectify`` in SfM mode): detect on a nadir-rectified copy of each
    oblique view (:func:`brfgs.init.features.nadir_rectification`, orientation from transforms.json)."""
    if rectify is None:
        rectify = bool(config.rectify) and mode == "sfm"
    factor = detect_downscale_factor(scene.width, scene.height, config.detect_max_px)
    feats: list[ViewFeatures] = []
    cubes = [] if keep_cubes else None
    it = range(len(scene.frames))
    if progress:
        it = tqdm(it, desc="features", unit="view")
    sift = make_sift(contrast_threshold=config.contrast_threshold)
    for i in it:
        cube = scene.load_image(i, bands=band_indices)  # [H, W, k]
        small = _block_mean(cube, factor)
        up = _upsample(scene, config, mode)
        if up > 1:  # pixel-centre aligned cubic upsampling
            small = np.stack([cv2.resize(small[:, :, j], None, fx=up, fy=up, interpolation=cv2.INTER_CUBIC)
                              for j in range(small.shape[-1])], -1)
        scale = factor / up
        rect = None
        if rectify:  # intrinsics of the detection image, OpenCV pixel convention
            intr = scene.intrinsics
            rect = nadir_rectification(scene.frames[i].c2w, intr.fl_x / scale, intr.fl_y / scale,
                                       intr.cx / scale - 0.5, intr.cy / scale - 0.5, small.shape[1], small.shape[0])
        f = extract_view_features(small, np.isfinite(small).all(-1), config.max_features, sift=sift,
                                  use_root_sift=config.root_sift, rect=rect)
        if scale != 1:  # pixel-edge coordinates (COLMAP convention) scale linearly
            f.xy = (f.xy * scale).astype(np.float32)
            f.scale = (f.scale * scale).astype(np.float32)
        feats.append(f)
        if keep_cubes:
            cubes.append(cube)
    return feats, cubes, factor


def _upsample(scene, config: InitConfig, mode: str = "sfm") -> int:
    """Upsampling factor for feature detection. Auto: 2 for SfM on small images (<= 256 px), which
    then give many more usable SIFT features on a 2x cubic-upsampled copy (simulated testsite 128^2:
    176 -> 2881 per view, 39 -> 45 of 49 views registered, camera error 1.4 % -> 0.84 % of the
    distance), beyond the x2 of SIFT's own first octave; 1 for known poses (about 4x faster)."""
    if config.detect_upsample and config.detect_upsample >= 1:
        return int(config.detect_upsample)
    return 2 if mode == "sfm" and max(scene.width, scene.height) <= 256 else 1


def _sample(cube: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples [N, k] of ``cube`` [H, W, k] at COLMAP pixel coordinates ``xy`` [N, 2]."""
    h, w = cube.shape[:2]
    x = np.clip(xy[:, 0] - 0.5, 0, w - 1)
    y = np.clip(xy[:, 1] - 0.5, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(int), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(int), h - 2 if h > 1 else 0)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    return ((1 - fx) * (1 - fy) * cube[y0, x0] + fx * (1 - fy) * cube[y0, x1]
            + (1 - fx) * fy * cube[y1, x0] + fx * fy * cube[y1, x1])


def point_colors(scene, band_indices, cubes, obs_frame, obs_point, obs_xy, n_points) -> np.ndarray:
    """Mean observed reflectance [P, k] of each point over its track (NaN samples ignored)."""
    k = len(band_indices)
    acc = np.zeros((n_points, k))
    cnt = np.zeros((n_points, k))
    for f in np.unique(obs_frame):
        cube = cubes[f] if cubes is not None else scene.load_image(int(f), bands=band_indices)
        sel = obs_frame == f
        vals = _sample(cube, obs_xy[sel])
        ok = np.isfinite(vals)
        np.add.at(acc, obs_point[sel], np.where(ok, vals, 0.0))
        np.add.at(cnt, obs_point[sel], ok)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (acc / cnt).astype(np.float32)


def reprojection_errors(points, c2w, intr, obs_frame, obs_point, obs_xy) -> np.ndarray:
    """Pixel distance [O] between each observation and the projection of its point with ``c2w``."""
    err = np.zeros(len(obs_frame))
    for f in np.unique(obs_frame):
        sel = obs_frame == f
        uv, _ = project_points(points[obs_point[sel]], c2w[f], intr)
        err[sel] = np.linalg.norm(uv - obs_xy[sel], axis=1)
    return err


def geometry_metrics(feats: list[ViewFeatures], stats) -> dict:
    """The Table 2 geometry columns of one band configuration."""
    return {
        "mean_detected_features_per_view": float(np.mean([f.n_detected for f in feats])),
        "mean_used_features_per_view": float(np.mean([len(f.xy) for f in feats])),
        "putative_matches": int(stats.putative_total),
        "verified_matches": int(stats.verified_total),
        "matching_success_rate": stats.success_rate,
        "image_pairs": int(stats.pairs_total),
        "verified_image_pairs": int(stats.pairs_verified),
    }


def match_features(scene, feats, work_dir: Path, config: InitConfig, guided: bool = False):
    """Write the COLMAP database and match; returns (db_path, image_ids, MatchStats)."""
    from brfgs.init import colmap as C  # lazy: pulls in pycolmap (must follow zlib, see init/__init__.py)

    work_dir.mkdir(parents=True, exist_ok=True)
    db_path = work_dir / "database.db"
    check_database_space(db_path, feats)
    names = [f.name for f in scene.frames]
    try:
        ids = C.write_database(db_path, scene.intrinsics, names, feats)
        C.match_exhaustive(db_path, num_threads=config.match_threads, seed=config.seed,
                           min_inliers=config.min_inliers, guided=guided)
        return db_path, ids, C.match_stats(db_path, ids)
    except RuntimeError as exc:  # COLMAP's SQLite errors come back as RuntimeError
        if "full" in str(exc).lower() or "disk i/o" in str(exc).lower():
            raise OSError(errno.ENOSPC, "no space left for the COLMAP database", str(db_path)) from None
        raise


def database_bytes(feats) -> int:
    """A generous estimate of the COLMAP database's size for the features ``feats`` (keypoints and
    descriptors, every view pair's matches and two-view geometry, SQLite's overhead)."""
    n = [len(f.xy) for f in feats]
    pairs = sum(min(a, b) for i, a in enumerate(n) for b in n[i + 1:])
    return int(2 * (sum(n) * (128 + 24) + pairs * 8 * 3) + 4 * 2**20)


def check_database_space(db_path: Path, feats) -> None:
    """OSError (ENOSPC, naming the database) when the file system of ``db_path`` has less free space
    than the database needs: COLMAP aborts the process when SQLite runs out of space mid-write, so the
    shortage is found before it starts."""
    need, free = database_bytes(feats), shutil.disk_usage(db_path.parent).free
    if free < need:
        raise OSError(errno.ENOSPC, f"not enough free space for the COLMAP database (needs about {need / 2**20:.1f} "
                      f"MiB, {free / 2**20:.1f} MiB free)", str(db_path))


def _sfm_failure(scene, stats, registered_names: list[str], reason: str) -> UserError:
    names = [f.name for f in scene.frames]
    failed = [n for n in names if n not in set(registered_names)]
    order = np.argsort(stats.verified_per_image, kind="stable")
    weakest = [f"{names[i]} ({int(stats.verified_per_image[i])} verified matches with "
               f"{int(stats.verified_pairs_per_image[i])} views)" for i in order[:8]]
    listing = ", ".join(failed[:20]) + (f" and {len(failed) - 20} more" if len(failed) > 20 else "")
    if stats.verified_total < MIN_TRIANGULATED * len(names):
        reason += (f"; the images have too little texture for SfM ({stats.verified_total} verified matches over "
                   f"{len(names)} views)")
    return UserError(
        f"SfM failed: {reason}. Views not registered: {listing or 'none'}. Views with the fewest verified "
        f"matches: {', '.join(weakest)}. Matching success rate "
        f"{(stats.success_rate or 0.0):.1%} ({stats.verified_total} of {stats.putative_total} putative matches). "
        f"Try `--poses known` to triangulate with the poses in transforms.json, or another band strategy.",
        file=Path(scene.root) / "transforms.json", field="frames")


@dataclass
class _Reconstruction:
    """Cameras and sparse points as :func:`initialize` builds them up."""

    mode: str                               # "sfm" or "known" (after a fallback)
    arr: object                             # colmap.ReconArrays: points, cameras, observations
    known_c2w: np.ndarray                   # [F, 4, 4] poses of transforms.json
    alignment: dict | None = None           # SfM → ENU similarity
    fallback: str | None = None             # why SfM failed, when "auto" fell back to known poses
    guided_stats: object = None             # MatchStats of guided matching (SfM)
    c2w: np.ndarray | None = None           # [F, 4, 4] final cameras (OpenGL)
    registered: np.ndarray | None = None    # [F] bool
    points: np.ndarray | None = None        # [P, 3] after filtering
    point_err: np.ndarray | None = None     # [P] mean reprojection error (px)
    rep_err: np.ndarray | None = None       # [O] reprojection error of each kept observation (px)
    n_before: int = 0                       # points before filtering


def initialize(scene, band_indices, poses: str = "auto", out_dir: str | Path | None = None,
               config: InitConfig | None = None, selection=None, progress: bool = False) -> InitResult:
    """Cameras and sparse points from the bands ``band_indices`` of ``scene`` (see module docstring).

    ``out_dir``: when given, OUT/points.ply, cameras.json, init_report.{json,md} (and bands.json
    when ``selection`` is given) are written there; the COLMAP work files go to OUT/colmap.
    """
    config = config or InitConfig()
    if poses not in POSE_MODES:
        raise UserError(f"--poses must be one of {', '.join(POSE_MODES)}, got {poses!r}", field="poses")
    bands = _check_bands(scene, band_indices)
    t0 = time.perf_counter()
    timings = {}
    mode = poses
    if poses == "auto":
        mode = "known" if _frames_have_poses(scene) else "sfm"

    tmp = None
    if out_dir is not None:
        work = Path(out_dir) / "colmap"
    else:
        tmp = tempfile.mkdtemp(prefix="brfgs_init_")
        work = Path(tmp)
    try:
        feats, cubes, factor = extract_features(scene, bands, config, progress,
                                                keep_cubes=_cube_bytes(scene, bands) < 512 * 2**20, mode=mode)
        timings["features"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        db_path, _ids, stats = match_features(scene, feats, work, config)
        timings["matching"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        rec = _reconstruct(scene, feats, db_path, work, stats, config, poses, mode)
        timings["reconstruction"] = time.perf_counter() - t1
        _final_cameras(rec)
        _filter_points(rec, scene.intrinsics, config)
        arr = rec.arr
        colors = point_colors(scene, bands, cubes, arr.obs_frame, arr.obs_point, arr.obs_xy, len(rec.points))
        report = _report(scene, config, poses, bands, rec, geometry_metrics(feats, stats), factor, timings,
                         selection)
        result = InitResult(rec.points, colors, rec.c2w, rec.registered, arr.track_len, rec.point_err, bands,
                            report, arr.obs_frame, arr.obs_point)
        if out_dir is not None:
            write_outputs(Path(out_dir), scene, result, selection)
        return result
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        elif not config.keep_database and out_dir is not None:
            shutil.rmtree(Path(out_dir) / "colmap", ignore_errors=True)


def _reconstruct(scene, feats, db_path: Path, work: Path, stats, config: InitConfig, poses: str,
                 mode: str) -> _Reconstruction:
    """SfM (``mode`` "sfm"; with ``poses`` "auto" a failure falls back to the known poses) or
    triangulation of the verified matches with the poses of transforms.json."""
    from brfgs.init import colmap as C  # lazy: pulls in pycolmap (must follow zlib, see init/__init__.py)

    names = [f.name for f in scene.frames]
    known_c2w = np.stack([np.asarray(f.c2w, float) for f in scene.frames])  # [F, 4, 4]
    rec = _Reconstruction(mode, None, known_c2w)
    if mode == "sfm":
        try:
            sfm_db, sfm_stats = db_path, stats
            if config.guided_matching:  # Table 2 metrics stay those of plain matching (above)
                sfm_db, _, rec.guided_stats = match_features(scene, feats, work / "guided", config, guided=True)
                sfm_stats = rec.guided_stats
            _, rec.arr, rec.alignment = _run_sfm(scene, sfm_db, work / "guided" if config.guided_matching else work,
                                                 sfm_stats, config, names, known_c2w)
        except UserError as exc:
            if poses != "auto":
                raise
            rec.fallback = str(exc)
            rec.mode = "known"
    if rec.mode == "known":
        colmap_rec = C.triangulate_known(db_path, work, names, known_c2w, seed=config.seed,
                                         num_threads=config.threads, min_inliers=config.min_inliers)
        rec.arr = C.reconstruction_arrays(colmap_rec, names)
        if len(rec.arr.points) < MIN_TRIANGULATED:  # too little texture: start from the ground plane
            rec.fallback = (f"{len(rec.arr.points)} points triangulated from {stats.verified_total} verified "
                            f"matches (too little texture); started from the ground plane the cameras look at")
            rec.arr = plane_arrays(known_c2w, scene.intrinsics)
    return rec


def _final_cameras(rec: _Reconstruction) -> None:
    """rec.c2w: the reconstructed pose of each registered view, the known pose of the others."""
    n_frames = len(rec.known_c2w)
    arr, known_c2w = rec.arr, rec.known_c2w
    rec.registered = np.array([c is not None for c in arr.c2w])
    rec.c2w = np.stack([arr.c2w[i] if rec.registered[i] else known_c2w[i] for i in range(n_frames)])
    if rec.mode == "known":  # poses must be untouched by the triangulator
        drift = max(float(np.abs(arr.c2w[i] - known_c2w[i]).max()) for i in range(n_frames) if rec.registered[i])
        if drift > 1e-6:
            raise RuntimeError(f"COLMAP's triangulator changed the known poses (by {drift:g})")


def _filter_points(rec: _Reconstruction, intr, config: InitConfig) -> None:
    """Keep well-constrained points: enough views and a small mean reprojection error (rec.points,
    rec.point_err, rec.rep_err; the observations of rec.arr are filtered in place)."""
    arr = rec.arr
    points = arr.points
    rep_err = reprojection_errors(points, rec.c2w, intr, arr.obs_frame, arr.obs_point, arr.obs_xy)
    point_err = np.zeros(len(points))
    if len(points):
        np.add.at(point_err, arr.obs_point, rep_err)
        point_err /= np.maximum(arr.track_len, 1)
    keep = (arr.track_len >= config.min_track_length) & (point_err <= config.max_point_error_px)
    n_before = len(points)
    if not keep.all():
        new_id = np.cumsum(keep) - 1
        ok_obs = keep[arr.obs_point]
        arr.obs_frame, arr.obs_xy = arr.obs_frame[ok_obs], arr.obs_xy[ok_obs]
        arr.obs_point = new_id[arr.obs_point[ok_obs]]
        rep_err = rep_err[ok_obs]
        points, point_err, arr.track_len = points[keep], point_err[keep], arr.track_len[keep]
    if len(points) == 0:
        raise UserError(f"no sparse point has a track of >= {config.min_track_length} views and a mean "
                        f"reprojection error <= {config.max_point_error_px} px ({n_before} before filtering)",
                        field="poses")
    rec.points, rec.point_err, rec.rep_err, rec.n_before = points, point_err, rep_err, n_before


def _report(scene, config: InitConfig, poses: str, bands: list[int], rec: _Reconstruction, geometry: dict,
            factor: int, timings: dict, selection) -> dict:
    """Content of init_report.json."""
    names = [f.name for f in scene.frames]
    n_frames = len(names)
    points, registered, rep_err = rec.points, rec.registered, rec.rep_err
    return {
        "scene": str(scene.root),
        "poses": rec.mode,
        "poses_requested": poses,
        "fallback": rec.fallback,
        "bands": {"indices": bands, "wavelengths_nm": [float(scene.wavelengths_nm[i]) for i in bands],
                  "strategy": getattr(selection, "strategy", None)},
        "views": n_frames,
        "registered_views": int(registered.sum()),
        "unregistered_views": [names[i] for i in range(n_frames) if not registered[i]],
        "points": int(len(points)),
        "points_removed_by_filter": int(rec.n_before - len(points)),
        "mean_track_length": float(rec.arr.track_len.mean()) if len(points) else None,
        "mean_reprojection_error_px": float(rep_err.mean()) if len(rep_err) else None,
        "geometry": geometry,
        "guided_verified_matches": None if rec.guided_stats is None else int(rec.guided_stats.verified_total),
        "alignment": rec.alignment,
        "truth": truth_checks(scene, [rec.c2w[i] if registered[i] else None for i in range(n_frames)], points),
        "image_size": [int(scene.width), int(scene.height)],
        "detect_downscale": int(factor),
        "detect_upsample": _upsample(scene, config, "sfm" if rec.mode == "sfm" or rec.fallback else "known"),
        "settings": asdict(config),
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "definitions": DEFINITIONS,
    }


def _cube_bytes(scene, bands) -> int:
    return len(scene.frames) * scene.width * scene.height * len(bands) * 4


def _run_sfm(scene, db_path, work, stats, config: InitConfig, names, known_c2w):
    """Incremental mapping, checks, and similarity alignment to the transforms.json camera centres."""
    from brfgs.init import colmap as C  # lazy: pulls in pycolmap (must follow zlib, see init/__init__.py)

    n = len(names)
    if stats.pairs_verified == 0:
        raise _sfm_failure(scene, stats, [], "no pair of views has enough verified matches "
                                             f"(at least {config.min_inliers} inliers)")
    init_min = config.init_min_inliers
    if init_min is None:  # COLMAP's 100 unless small images cannot give that many
        init_min = int(min(100, max(config.min_inliers, 0.5 * stats.max_pair_verified)))
    rec = C.incremental_mapping(db_path, work, seed=config.seed, num_threads=config.threads,
                                min_inliers=config.min_inliers, init_min_inliers=init_min,
                                max_error_px=config.mapper_max_error_px)
    if rec is None:
        raise _sfm_failure(scene, stats, [], "incremental mapping found no initial pair")
    if config.robust_refinement:
        rec = C.refine_reconstruction(rec, db_path, seed=config.seed, num_threads=config.threads,
                                      min_inliers=config.min_inliers, max_error_px=config.mapper_max_error_px,
                                      loss_scale_px=config.robust_loss_px)
    arr = C.reconstruction_arrays(rec, names)
    reg = [i for i in range(n) if arr.c2w[i] is not None]
    need = max(3, int(np.ceil(config.min_registered_fraction * n)))
    if len(reg) < need:
        raise _sfm_failure(scene, stats, [names[i] for i in reg],
                           f"only {len(reg)} of {n} views registered (at least {need} needed)")
    src = np.array([arr.c2w[i][:3, 3] for i in reg])
    dst = known_c2w[reg, :3, 3]
    sim, inl = umeyama_robust(src, dst)
    arr.points = sim.apply(arr.points) if len(arr.points) else arr.points
    for i in reg:
        arr.c2w[i] = sim.apply_c2w(arr.c2w[i])
    res = np.linalg.norm(np.array([arr.c2w[i][:3, 3] for i in reg]) - dst, axis=1)
    alignment = {"method": "Umeyama similarity of SfM camera centres onto transforms.json camera centres",
                 **sim.to_json(), "views_used": int(inl.sum()),
                 "views_rejected": [names[reg[j]] for j in range(len(reg)) if not inl[j]],
                 "residual_m": {"median": float(np.median(res)), "max": float(res.max())}}
    return rec, arr, alignment


def strategy_ablation(scene, strategies=None, top: int = 3, stats=None, config: InitConfig | None = None,
                      progress: bool = False) -> list[dict]:
    """Table 2 geometry columns (detected features per view, matching success rate) for each strategy."""
    config = config or InitConfig()
    strategies = list(strategies or TABLE2_STRATEGIES)
    if stats is None:
        stats = compute_band_stats(scene, progress=progress)
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="brfgs_ablation_"))
    try:
        for s in strategies:
            sel = select_bands(scene, s, top=top, stats=stats)
            feats, _, _ = extract_features(scene, sel.selected, config, progress=False, keep_cubes=False,
                                           rectify=False)  # Table 2: plain SIFT, as in the paper
            _, _, mstats = match_features(scene, feats, tmp / s, config)
            row = {"strategy": s, "label": STRATEGY_LABELS.get(s, s), "bands": sel.selected,
                   "wavelengths_nm": sel.selected_wavelengths_nm, **geometry_metrics(feats, mstats)}
            rows.append(row)
            if progress:
                print(f"  {s:14s} features/view {row['mean_detected_features_per_view']:8.1f}  success "
                      f"{fmt_or_na(row['matching_success_rate'], '.1%')}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows
