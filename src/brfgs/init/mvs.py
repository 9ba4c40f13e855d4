"""Dense multi-view stereo: plane-sweep depth maps of the training views, fused into a dense
point cloud that seeds the Gaussians (beyond the paper, which starts from the sparse SfM points;
``brfgs train --init-fill mvs``).

Each training view is a *reference* in turn: :mod:`brfgs.init.plane_sweep` gives its depth map
from its ``neighbours`` closest views (:func:`stereo_depths`). Depths are kept only where at
least ``min_consistent`` other views' depth maps agree within a relative tolerance
(:func:`consistent_views`). Pixels left without a depth take the point where their ray meets a
height field through the kept stereo points (:func:`fill_holes`), so water and shadows, where
matching fails, are covered too. The kept pixels become 3-D points with normals from the depth
map's gradient (:func:`depth_normals`), thinned on a voxel grid to a target count
(:func:`voxel_thin`; :func:`dense_cloud` runs it all).

Everything runs on images area-downscaled to at most ``max_size_px`` (a start for the Gaussians
needs no more), in float32 PyTorch on the CPU. Cameras follow docs/data-format.md (OpenGL
camera-to-world); pixel centres lie at +0.5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from plyfile import PlyData, PlyElement
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
from torch import Tensor
from tqdm import tqdm

from brfgs.data import atomic
from brfgs.data.cameras import Intrinsics
from brfgs.init.plane_sweep import (backproject, cv_pose, depth_map, fronto_parallel, horizontal, intrinsic_matrix,
                                    matching_scale, parallax_spaced, pixel_grid, project, reference_rays,
                                    scaled_intrinsics, sweep_depths)


FINE_PLANES = 2048  # the fine sweep (depths and heights) from which parallax_spaced picks the planes


@dataclass
class MVSConfig:
    """Options of the dense initialisation (``brfgs train --init-fill mvs`` uses the defaults)."""

    max_size_px: int = 256          # views are area-downscaled so that their longer side is at most this
    neighbours: int = 6             # views compared with each reference (closest viewing directions)
    planes: int = 160               # at most this many fronto-parallel planes per reference view
    level_planes: int = 160         # at most this many level (z = const) planes (0 = none)
    plane_step_px: float = 0.5      # planes spaced so that the image moves about this much between them
    window_px: int = 5              # NCC window (odd), in matching pixels
    min_score: float = 0.3          # best-half mean NCC below this: no depth
    min_consistent: int = 2         # other views whose depth maps must agree
    depth_tol: float = 0.01         # relative depth agreement between views
    max_points: int = 60_000        # voxel thinning target of the fused cloud
    fill_holes: bool = True         # pixels without a stereo depth: where their rays meet a height field
    #                                 through the stereo points


def sample_nearest(
    image: Tensor,  # [H, W]
    uv: Tensor,  # [..., 2] px
) -> Tensor:  # [...] NaN outside
    """Nearest-pixel values of ``image`` at ``uv`` (NaN outside the image)."""
    h, w = image.shape
    col = torch.floor(uv[..., 0]).long()
    row = torch.floor(uv[..., 1]).long()
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    vals = image[row.clamp(0, h - 1), col.clamp(0, w - 1)]
    return torch.where(inside, vals, torch.full_like(vals, float("nan")))


def consistent_views(
    depths: list[Tensor],  # V x [H, W] m (NaN: none)
    poses: list[tuple[Tensor, Tensor]],  # V poses
    intr: Intrinsics,
    others: list[list[int]],  # for each view, the views to check against
    tol: float,
) -> list[Tensor]:  # V x [H, W] int: how many of ``others`` agree
    """For every pixel with a depth, the number of other views whose own depth map, at the
    point's projection, agrees with the point's depth in that view within ``tol`` (relative)."""
    out = []
    for r, (dep, pose) in enumerate(zip(depths, poses)):
        pts = backproject(torch.nan_to_num(dep, nan=1.0), intr, *pose)  # [H, W, 3]
        count = torch.zeros(dep.shape, dtype=torch.int32)
        for j in others[r]:
            uv, z = project(pts, intr, *poses[j])
            dj = sample_nearest(depths[j], uv)
            count += (torch.abs(dj - z) <= tol * z).to(torch.int32)  # NaN compares False
        out.append(torch.where(torch.isfinite(dep), count, torch.zeros_like(count)))
    return out


def depth_normals(points: Tensor, centre: Tensor) -> Tensor:  # [H, W, 3] unit, facing the camera
    """Normals of a back-projected depth map [H, W, 3] from central differences of its points."""
    dx = torch.zeros_like(points)
    dy = torch.zeros_like(points)
    dx[:, 1:-1] = points[:, 2:] - points[:, :-2]
    dx[:, 0], dx[:, -1] = points[:, 1] - points[:, 0], points[:, -1] - points[:, -2]
    dy[1:-1] = points[2:] - points[:-2]
    dy[0], dy[-1] = points[1] - points[0], points[-1] - points[-2]
    n = torch.linalg.cross(dx, dy)
    n = n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp_min(1e-12)
    toward = ((centre - points) * n).sum(-1, keepdim=True)
    return torch.where(toward < 0, -n, n)


def voxel_thin(points: np.ndarray, normals: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean point and mean normal (renormalised) per cell of the coarsest cubic grid, found by
    bisection, that leaves at most ``max_points`` cells."""
    if len(points) <= max_points:
        return points, normals

    def cells(size):
        key = np.floor(points / size).astype(np.int64)
        _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        return inv.ravel(), cnt

    lo, hi = 1e-6, float(np.ptp(points, 0).max()) + 1.0
    for _ in range(40):  # smallest cell size with <= max_points cells
        mid = math.sqrt(lo * hi)
        if len(cells(mid)[1]) > max_points:
            lo = mid
        else:
            hi = mid
    inv, cnt = cells(hi)
    p = np.zeros((len(cnt), 3))
    n = np.zeros((len(cnt), 3))
    np.add.at(p, inv, points)
    np.add.at(n, inv, normals)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return p / cnt[:, None], n


@dataclass
class DenseCloud:
    """The fused cloud: points [P, 3] (m, ENU), unit normals [P, 3] and a report (per view: the
    fraction of pixels kept, the median score; counts; the thinning)."""

    points: np.ndarray
    normals: np.ndarray
    report: dict
    depths: list[np.ndarray]  # V x [h, w] m at the matching scale, NaN where not kept


def view_neighbours(centres_m: np.ndarray, target_m: np.ndarray, k: int) -> list[list[int]]:
    """For each camera (centres [V, 3]), the ``k`` others whose direction from ``target_m`` [3]
    is closest in angle (the reference itself excluded)."""
    d = centres_m - target_m
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    ang = np.arccos(np.clip(d @ d.T, -1.0, 1.0))  # [V, V]
    np.fill_diagonal(ang, np.inf)
    return [list(np.argsort(ang[i], kind="stable")[: min(k, len(d) - 1)]) for i in range(len(d))]


def view_depth_range(points_m: np.ndarray, pose: tuple[Tensor, Tensor], intr: Intrinsics,
                     ground_z_m: float) -> tuple[float, float] | None:
    """Depth range (m) to sweep for one view: the sparse points it sees (1st-99th percentile,
    widened by 15 %), extended to where its image border rays meet the plane ``z = ground_z_m``
    (oblique views see ground far beyond the points), at most 4x the points' median depth.
    None when the view sees no point."""
    uv, z = project(torch.as_tensor(points_m, dtype=torch.float64), intr, *pose)
    inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < intr.w) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.h)
    if int(inside.sum()) < 3:
        return None
    zs = z[inside].numpy()
    near, far = 0.85 * float(np.percentile(zs, 1)), 1.15 * float(np.percentile(zs, 99))
    rot, centre = pose
    grid = pixel_grid(intr)
    border = torch.cat([grid[0], grid[-1], grid[:, 0], grid[:, -1]])  # [Q, 3]
    rays = border @ torch.linalg.inv(intrinsic_matrix(intr)).T @ rot.T  # [Q, 3] world, camera depth 1 per unit
    down = rays[:, 2] < -1e-9
    if bool(down.any()):
        t = (ground_z_m - float(centre[2])) / rays[down, 2]  # camera depth at the plane
        far = max(far, float(t[t > 0].max()) * 1.05) if bool((t > 0).any()) else far
    return max(near, 1e-3), min(far, 4.0 * float(np.median(zs)))


def _prepare(images: list[np.ndarray], factor: int) -> Tensor:  # [V, C, h, w] float32
    """Views [H, W, C] (NaN allowed) as area-downscaled tensors, each channel divided by its 99th
    percentile over all views and NaN replaced by the view's channel mean."""
    x = torch.as_tensor(np.stack([np.asarray(im, np.float32) for im in images])).permute(0, 3, 1, 2)  # [V, C, H, W]
    scale = torch.nan_to_num(torch.nanquantile(x.transpose(0, 1).reshape(x.shape[1], -1)[:, ::7], 0.99, dim=1))
    x = x / torch.where(scale > 0, scale, torch.ones_like(scale))[None, :, None, None]
    mean = torch.nan_to_num(torch.nanmean(x, dim=(2, 3), keepdim=True))
    x = torch.where(torch.isfinite(x), x, mean)
    return F.avg_pool2d(x, factor) if factor > 1 else x


def stereo_depths(views: Tensor, poses: list[tuple[Tensor, Tensor]], intr: Intrinsics, points_m: np.ndarray,
                  cfg: MVSConfig, progress: bool = False) -> tuple[list[Tensor], list[Tensor]]:
    """Depth maps [h, w] of every view (``views`` [V, C, h, w] at the matching scale), NaN where
    the score is below ``min_score`` or fewer than ``min_consistent`` neighbours agree; and the
    scores [h, w]."""
    centres = np.stack([p[1].numpy() for p in poses])
    nbrs = view_neighbours(centres, np.median(points_m, 0), cfg.neighbours)
    ground_z = float(np.percentile(points_m[:, 2], 2))
    top_z = float(np.percentile(points_m[:, 2], 99.5))
    margin = 0.1 * (top_z - ground_z) + 0.5
    heights = torch.linspace(ground_z - margin, top_z + margin, FINE_PLANES, dtype=torch.float64)
    depths, scores = [], []
    it = range(len(views))
    if progress:
        it = tqdm(it, desc="dense stereo", unit="view")
    for r in it:
        rng = view_depth_range(points_m, poses[r], intr, ground_z)
        if rng is None or not nbrs[r]:
            depths.append(torch.full((intr.h, intr.w), float("nan"), dtype=torch.float64))
            scores.append(torch.full((intr.h, intr.w), -1.0, dtype=torch.float64))
            continue
        nb_poses = [poses[j] for j in nbrs[r]]
        fams = [parallax_spaced(fronto_parallel(poses[r], sweep_depths(*rng, FINE_PLANES)), intr, poses[r], nb_poses,
                                cfg.plane_step_px, cfg.planes)]
        if cfg.level_planes > 0:
            fams.append(parallax_spaced(horizontal(heights), intr, poses[r], nb_poses, cfg.plane_step_px,
                                        cfg.level_planes))
        d, s = depth_map(views[r], views[nbrs[r]], intr, poses[r], nb_poses, fams, cfg.window_px)
        depths.append(torch.where(s >= cfg.min_score, d, torch.full_like(d, float("nan"))))
        scores.append(s)
    counts = consistent_views(depths, poses, intr, nbrs, cfg.depth_tol)
    kept = [torch.where(c >= cfg.min_consistent, d, torch.full_like(d, float("nan"))) for d, c in zip(depths, counts)]
    return kept, scores


def height_field(points_m: np.ndarray, max_nodes: int | None = None):
    """z(x, y) through ``points_m`` [P, 3]: linear over their Delaunay triangulation in plan view,
    the nearest point's height outside it (a DSM); with ``max_nodes``, the points are first thinned
    to that many (a random draw, seed 0). Returns ``z_at(xy [N, 2]) -> z [N]`` (m)."""
    p = np.asarray(points_m, np.float64)
    if max_nodes is not None and len(p) > max_nodes:
        p = p[np.random.default_rng(0).choice(len(p), max_nodes, replace=False)]
    lin = LinearNDInterpolator(p[:, :2], p[:, 2])
    near = NearestNDInterpolator(p[:, :2], p[:, 2])

    def z_at(xy: np.ndarray) -> np.ndarray:  # [N, 2] -> [N]
        z = lin(xy)
        bad = ~np.isfinite(z)
        if bad.any():
            z[bad] = near(xy[bad])
        return z

    return z_at


def fill_holes(depth: Tensor, intr: Intrinsics, pose: tuple[Tensor, Tensor], z_at, iterations: int = 12) -> Tensor:
    """``depth`` [h, w] with its NaN pixels set to where their rays meet the height field ``z_at``
    (fixed-point iteration on the ray parameter, starting from the field's height below the camera;
    rays that do not point down stay NaN)."""
    hole = ~torch.isfinite(depth)
    if not bool(hole.any()):
        return depth
    rays = reference_rays(intr, pose)[hole].numpy()  # [N, 3] world, per unit camera depth
    c = pose[1].numpy()
    down = rays[:, 2] < -1e-6
    t = np.full(len(rays), np.nan)
    if down.any():
        r = rays[down]
        tt = (float(z_at(c[None, :2])[0]) - c[2]) / r[:, 2]
        for _ in range(iterations):
            xy = c[:2] + tt[:, None] * r[:, :2]
            tt = np.maximum((z_at(xy) - c[2]) / r[:, 2], 1e-3)
        t[down] = tt
    out = depth.clone()
    out[hole] = torch.as_tensor(t, dtype=depth.dtype)
    return out


def dense_cloud(
    images: list[np.ndarray],  # V x [H, W, C] views to match (e.g. the stage-1 bands), NaN allowed
    c2w: list[np.ndarray],  # V x [4, 4] OpenGL camera-to-world
    intr: Intrinsics,  # of the full-size images
    sparse_points_m: np.ndarray,  # [P, 3] the SfM points (depth ranges)
    cfg: MVSConfig | None = None,
    progress: bool = False,
) -> DenseCloud:
    """Plane-sweep depth maps of every view against its neighbours, kept where ``min_consistent``
    other views agree; each view's remaining pixels filled from a height field through the kept
    points (so that every pixel of every view has a point, at the density the view sees it); all
    fused into points with normals and thinned to ``max_points``."""
    cfg = cfg or MVSConfig()
    factor = matching_scale(intr.w, intr.h, cfg.max_size_px)
    si = scaled_intrinsics(intr, factor)
    views = _prepare(images, factor)  # [V, C, h, w]
    poses = [cv_pose(m) for m in c2w]
    pts = np.asarray(sparse_points_m, np.float64)
    depths, scores = stereo_depths(views, poses, si, pts, cfg, progress)
    stereo = [backproject(torch.nan_to_num(d, nan=1.0), si, *pose)[torch.isfinite(d)].numpy()
              for d, pose in zip(depths, poses)]
    stereo_pts = np.concatenate(stereo) if stereo else np.zeros((0, 3))
    z_at = height_field(stereo_pts if len(stereo_pts) >= 4 else pts, max_nodes=40_000)
    all_p, all_n, n_filled = [], [], 0
    for d, pose in zip(depths, poses):
        full = fill_holes(d, si, pose, z_at) if cfg.fill_holes else d
        n_filled += int((torch.isfinite(full) & ~torch.isfinite(d)).sum())
        ok = torch.isfinite(full)
        p = backproject(torch.nan_to_num(full, nan=1.0), si, *pose)  # [h, w, 3]
        all_p.append(p[ok].numpy())
        all_n.append(depth_normals(p, pose[1])[ok].numpy())
    points = np.concatenate(all_p) if all_p else np.zeros((0, 3))
    normals = np.concatenate(all_n) if all_n else np.zeros((0, 3))
    n_fused = len(points)
    points, normals = voxel_thin(points, normals, cfg.max_points)
    kept = [float(torch.isfinite(d).double().mean()) for d in depths]
    report = {"matching_scale": factor, "matching_size_px": [si.w, si.h], "stereo_points": int(len(stereo_pts)),
              "hole_points": n_filled, "points_fused": int(n_fused), "points": int(len(points)),
              "kept_fraction_per_view": [round(k, 4) for k in kept],
              "median_score_per_view": [round(float(torch.nanmedian(s)), 4) for s in scores]}
    return DenseCloud(points, normals, report, [d.numpy() for d in depths])


def write_dense_ply(path, points_m: np.ndarray, normals: np.ndarray) -> None:
    """Binary PLY of the fused cloud: x, y, z (m, ENU) and nx, ny, nz (float32), written atomically."""
    p = np.asarray(points_m, np.float32).reshape(-1, 3)
    n = np.asarray(normals, np.float32).reshape(-1, 3)
    rec = np.empty(len(p), dtype=[(k, "f4") for k in ("x", "y", "z", "nx", "ny", "nz")])
    for j, k in enumerate("xyz"):
        rec[k], rec["n" + k] = p[:, j], n[:, j]
    with atomic.atomic_path(path) as tmp:
        PlyData([PlyElement.describe(rec, "vertex")], comments=["brfgs dense stereo points (ENU metres)"]).write(str(tmp))
