"""pycolmap plumbing: a COLMAP database of our own features, exhaustive matching with geometric
verification, incremental mapping (unknown poses) and point triangulation (known poses).

pycolmap comes through :mod:`brfgs.init.pycolmap_safe` (zlib first, SIGTERM left alone).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brfgs.init.pycolmap_safe import pycolmap

from brfgs.data.cameras import GL_TO_CV

_SIFT = pycolmap.FeatureExtractorType.SIFT


def set_verbose(verbose: bool = False) -> None:
    """COLMAP's log: INFO lines when ``verbose``, otherwise errors only."""
    pycolmap.logging.minloglevel = 0 if verbose else 2


set_verbose(False)


@dataclass
class MatchStats:
    """Putative (ratio test + cross check) and verified (two-view geometry inliers) matches."""

    putative_total: int
    verified_total: int
    pairs_total: int
    pairs_verified: int
    putative_per_image: np.ndarray   # [F]
    verified_per_image: np.ndarray   # [F]
    verified_pairs_per_image: np.ndarray  # [F] number of partner views with a verified geometry
    max_pair_verified: int = 0       # verified matches of the best pair

    @property
    def success_rate(self) -> float | None:
        return None if self.putative_total == 0 else self.verified_total / self.putative_total


def write_database(db_path: Path, intr, names: list[str], feats) -> list[int]:
    """Create a COLMAP database with one PINHOLE camera (known intrinsics), one trivial rig/frame
    per image, and our keypoints and descriptors. Returns the image ids in ``names`` order."""
    db_path = Path(db_path)
    if db_path.exists():
        db_path.unlink()
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", float(intr.fl_x), int(intr.w), int(intr.h))
    cam.params = np.array([intr.fl_x, intr.fl_y, intr.cx, intr.cy], float)
    cam.has_prior_focal_length = True
    ids = []
    with pycolmap.Database.open(str(db_path)) as db:
        cam_id = db.write_camera(cam)
        cam.camera_id = cam_id
        rig = pycolmap.Rig()
        rig.add_ref_sensor(cam.sensor_id)
        rig_id = db.write_rig(rig)
        for name, f in zip(names, feats):
            image = pycolmap.Image(name=name, camera_id=cam_id)
            image_id = db.write_image(image)
            frame = pycolmap.Frame()
            frame.rig_id = rig_id
            frame.add_data_id(pycolmap.data_t(sensor_id=cam.sensor_id, id=image_id))
            frame_id = db.write_frame(frame)
            image.image_id = image_id
            image.frame_id = frame_id
            db.update_image(image)
            kp = np.concatenate([f.xy, f.scale[:, None], f.angle_rad[:, None]], 1).astype(np.float32)  # [N, 4]
            db.write_keypoints(image_id, kp.reshape(-1, 4))
            db.write_descriptors(image_id, pycolmap.FeatureDescriptors(_SIFT, np.ascontiguousarray(f.desc,
                                                                                                    np.uint8)))
            ids.append(image_id)
    return ids


def match_exhaustive(db_path: Path, num_threads: int = 1, seed: int = 0, min_inliers: int = 15,
                     max_error_px: float = 4.0, guided: bool = False) -> None:
    """COLMAP exhaustive SIFT matching (ratio 0.8, cross check) + two-view geometric verification (RANSAC);
    ``guided``: re-match each verified pair along its epipolar geometry (more inliers)."""
    pycolmap.set_random_seed(seed)
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = num_threads
    mopt.guided_matching = bool(guided)
    mopt.use_gpu = False
    vopt = pycolmap.TwoViewGeometryOptions()
    vopt.min_num_inliers = min_inliers
    vopt.ransac.max_error = max_error_px
    vopt.ransac.random_seed = seed
    vopt.ransac.num_threads = 1
    vopt.detect_watermark = False
    pycolmap.match_exhaustive(str(db_path), matching_options=mopt, verification_options=vopt,
                              device=pycolmap.Device.cpu)


def match_stats(db_path: Path, image_ids: list[int]) -> MatchStats:
    """Count putative and verified matches in the database (per image and in total)."""
    pos = {iid: k for k, iid in enumerate(image_ids)}
    n = len(image_ids)
    put_img = np.zeros(n, np.int64)
    ver_img = np.zeros(n, np.int64)
    pairs_img = np.zeros(n, np.int64)
    with pycolmap.Database.open(str(db_path)) as db:
        pair_ids, matches = db.read_all_matches()
        put_total = 0
        for pid, m in zip(pair_ids, matches):
            a, b = pycolmap.pair_id_to_image_pair(pid)
            put_total += len(m)
            put_img[pos[a]] += len(m)
            put_img[pos[b]] += len(m)
        g_ids, geoms = db.read_two_view_geometries()
        ver_total = 0
        n_ver_pairs = 0
        best = 0
        for pid, g in zip(g_ids, geoms):
            k = len(g.inlier_matches) if _is_verified(g) else 0
            if k == 0:
                continue
            a, b = pycolmap.pair_id_to_image_pair(pid)
            ver_total += k
            n_ver_pairs += 1
            best = max(best, k)
            for iid in (a, b):
                ver_img[pos[iid]] += k
                pairs_img[pos[iid]] += 1
    return MatchStats(put_total, ver_total, n * (n - 1) // 2, n_ver_pairs, put_img, ver_img, pairs_img, best)


def _is_verified(g) -> bool:
    cfg = pycolmap.TwoViewGeometryConfiguration
    return g.config not in (cfg.UNDEFINED, cfg.DEGENERATE, cfg.WATERMARK, cfg.MULTIPLE)


def _mapper_options(seed: int, num_threads: int, min_inliers: int,
                    max_error_px: float = 4.0) -> "pycolmap.IncrementalPipelineOptions":
    opt = pycolmap.IncrementalPipelineOptions()
    opt.mapper.filter_max_reproj_error = max_error_px
    opt.triangulation.merge_max_reproj_error = max_error_px
    opt.triangulation.complete_max_reproj_error = max_error_px
    opt.random_seed = seed
    opt.num_threads = num_threads
    opt.extract_colors = False
    opt.ba_refine_focal_length = False
    opt.ba_refine_principal_point = False
    opt.ba_refine_extra_params = False
    opt.min_num_matches = min_inliers
    opt.mapper.abs_pose_refine_focal_length = False
    opt.mapper.abs_pose_refine_extra_params = False
    opt.mapper.random_seed = seed
    opt.mapper.num_threads = num_threads
    opt.triangulation.random_seed = seed
    opt.multiple_models = True
    opt.min_model_size = 3
    return opt


def incremental_mapping(db_path: Path, work_dir: Path, seed: int = 0, num_threads: int = 1,
                        min_inliers: int = 15, init_min_inliers: int | None = None, max_error_px: float = 4.0):
    """COLMAP incremental SfM; returns the reconstruction with the most registered images, or None."""
    pycolmap.set_random_seed(seed)
    opt = _mapper_options(seed, num_threads, min_inliers, max_error_px)
    if init_min_inliers is not None:
        opt.mapper.init_min_num_inliers = init_min_inliers
    out = Path(work_dir) / "sfm"
    out.mkdir(parents=True, exist_ok=True)
    recs = pycolmap.incremental_mapping(str(db_path), str(work_dir), str(out), options=opt)
    if not recs:
        return None
    return max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))


def refine_reconstruction(rec, db_path: Path, seed: int = 0, num_threads: int = 1, min_inliers: int = 15,
                          max_error_px: float = 2.0, loss_scale_px: float = 1.0, max_refinements: int = 5):
    """Final refinement after incremental mapping (beyond the paper): retriangulate the pairs the scene graph
    says should share points, complete and merge tracks, then iterative global bundle adjustment with a
    Cauchy loss (scale ``loss_scale_px``) and fixed intrinsics, filtering observations above ``max_error_px``
    between rounds. COLMAP's own global BA uses a squared loss, so a few wrong or view-dependent matches
    (tree-crown edges, shadows) pull the weakly constrained near-nadir cameras sideways. Refines ``rec``
    in place and returns it."""
    pycolmap.set_random_seed(seed)
    opt = _mapper_options(seed, num_threads, min_inliers, max_error_px)
    opt.ba_global_max_num_iterations = 200
    cache_opt = pycolmap.DatabaseCacheOptions()
    cache_opt.min_num_matches = min_inliers
    with pycolmap.Database.open(str(db_path)) as db:
        cache = pycolmap.DatabaseCache.create(db, cache_opt)
    mapper = pycolmap.IncrementalMapper(cache)
    mapper.begin_reconstruction(rec)
    mapper_opt = opt.get_mapper()
    tri_opt = opt.get_triangulation()
    ba_opt = opt.get_global_bundle_adjustment()
    ba_opt.refine_focal_length = False
    ba_opt.refine_principal_point = False
    ba_opt.refine_extra_params = False
    ba_opt.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    ba_opt.ceres.loss_function_scale = float(loss_scale_px)
    mapper.retriangulate(tri_opt)
    mapper.complete_and_merge_tracks(tri_opt)
    mapper.iterative_global_refinement(max_refinements, 1e-5, mapper_opt, ba_opt, tri_opt,
                                       normalize_reconstruction=False)
    mapper.filter_points(mapper_opt)
    mapper.end_reconstruction(False)
    return rec


def _rigid_from_w2c(w2c_cv: np.ndarray) -> "pycolmap.Rigid3d":
    return pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(w2c_cv[:3, :3], float)), np.asarray(w2c_cv[:3, 3], float))


def triangulate_known(db_path: Path, work_dir: Path, names: list[str], c2w_gl: np.ndarray, seed: int = 0,
                      num_threads: int = 1, min_inliers: int = 15):
    """Triangulate the verified matches with fixed, known poses (COLMAP point_triangulator)."""
    pycolmap.set_random_seed(seed)
    rec = pycolmap.Reconstruction()
    with pycolmap.Database.open(str(db_path)) as db:
        for cam in db.read_all_cameras():
            rec.add_camera(cam)
        for rig in db.read_all_rigs():
            rec.add_rig(rig)
        images = {im.name: im for im in db.read_all_images()}
        frames = {fr.frame_id: fr for fr in db.read_all_frames()}
    pose_of = {name: np.asarray(c, float) for name, c in zip(names, c2w_gl)}
    for name, im in images.items():
        fr = frames[im.frame_id]
        c2w_cv = pose_of[name] @ GL_TO_CV
        fr.rig_from_world = _rigid_from_w2c(np.linalg.inv(c2w_cv))
        rec.add_frame(fr)
    for im in images.values():
        rec.add_image(im)
    for fr in list(frames.values()):
        rec.register_frame(fr.frame_id)
    opt = _mapper_options(seed, num_threads, min_inliers)
    out = Path(work_dir) / "triangulated"
    out.mkdir(parents=True, exist_ok=True)
    return pycolmap.triangulate_points(rec, str(db_path), str(work_dir), str(out), clear_points=True,
                                       options=opt, refine_intrinsics=False)


@dataclass
class ReconArrays:
    """A reconstruction as plain arrays, frames in the scene's order."""

    c2w: list                    # [F] OpenGL c2w [4, 4] or None (not registered)
    points: np.ndarray           # [P, 3] in the reconstruction's frame
    errors_px: np.ndarray        # [P] mean reprojection error
    track_len: np.ndarray        # [P]
    obs_frame: np.ndarray        # [O] frame index of each observation
    obs_point: np.ndarray        # [O] point index of each observation
    obs_xy: np.ndarray           # [O, 2] pixel (COLMAP convention, centres at +0.5)


def reconstruction_arrays(rec, names: list[str]) -> ReconArrays:
    """Poses (OpenGL c2w), points, per-point errors and the observations of ``rec``."""
    idx = {n: k for k, n in enumerate(names)}
    c2w = [None] * len(names)
    for image in rec.images.values():
        if not image.has_pose:
            continue
        w2c = np.eye(4)
        w2c[:3, :] = image.cam_from_world().matrix()
        c2w[idx[image.name]] = np.linalg.inv(w2c) @ GL_TO_CV
    pids = sorted(rec.points3D.keys())
    pts = np.zeros((len(pids), 3))
    err = np.zeros(len(pids))
    tl = np.zeros(len(pids), np.int64)
    of, op, oxy = [], [], []
    for k, pid in enumerate(pids):
        p = rec.points3D[pid]
        pts[k] = p.xyz
        err[k] = p.error
        els = p.track.elements
        tl[k] = len(els)
        for el in els:
            im = rec.images[el.image_id]
            of.append(idx[im.name])
            op.append(k)
            oxy.append(im.points2D[el.point2D_idx].xy)
    return ReconArrays(c2w, pts, err, tl, np.asarray(of, np.int64), np.asarray(op, np.int64),
                       np.asarray(oxy, float).reshape(-1, 2))
