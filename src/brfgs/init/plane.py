"""A start without features: with known poses and no matched points (a texture-less or tiny scene), the
sparse points are samples of the ground plane the cameras look at, observed in every view that sees them.

The plane is horizontal at the height of the point nearest to every camera's optical axis (the point the
flight looks at, a least-squares intersection of the axes); the points are where a grid of pixels of each
view meets it. Their observations are their exact projections, so the initialisation's filters keep them
and the training starts from a surface, as it does from a surface fill through SfM points.
"""

from __future__ import annotations

import numpy as np

from brfgs.data.cameras import Intrinsics, pixel_rays, project_points
from brfgs.init.colmap import ReconArrays

GRID = 8  # pixels per image side whose rays seed the plane


def look_at_point(c2w: np.ndarray) -> np.ndarray:  # [3] m
    """The point nearest (least squares) to the optical axes of the cameras ``c2w`` [F, 4, 4] (OpenGL:
    each looks along its −z axis); their centres' mean when the axes are parallel."""
    centres = c2w[:, :3, 3]
    dirs = -c2w[:, :3, 2] / np.linalg.norm(c2w[:, :3, 2], axis=1, keepdims=True)  # [F, 3]
    proj = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]                 # [F, 3, 3]
    a, b = proj.sum(0), np.einsum("fij,fj->i", proj, centres)
    if np.linalg.cond(a) > 1e8:
        return centres.mean(0)
    return np.linalg.solve(a, b)


def plane_arrays(c2w: np.ndarray, intr: Intrinsics) -> ReconArrays:
    """Ground-plane points seen by the cameras ``c2w`` [F, 4, 4] with intrinsics ``intr``, with their
    observations in every view that sees them (tracks of at least two views)."""
    z0 = float(look_at_point(c2w)[2])
    pts = []
    step = max(1, min(intr.w, intr.h) // GRID)
    for m in c2w:
        origins, dirs = pixel_rays(m, intr)
        o, d = origins[step // 2::step, step // 2::step].reshape(-1, 3), dirs[step // 2::step, step // 2::step].reshape(-1, 3)
        down = d[:, 2] < -1e-6
        t = (z0 - o[down, 2]) / d[down, 2]
        pts.append(o[down] + t[:, None] * d[down])
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    of, op, oxy = [], [], []
    for f, m in enumerate(c2w):
        uv, z = project_points(points, m, intr)
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < intr.w) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.h)
        idx = np.nonzero(inside)[0]
        of += [f] * len(idx)
        op += idx.tolist()
        oxy += uv[idx].tolist()
    track = np.bincount(np.asarray(op, np.int64), minlength=len(points))
    keep = track >= 2
    new_id = np.cumsum(keep) - 1
    ok = keep[np.asarray(op, np.int64)] if op else np.zeros(0, bool)
    return ReconArrays(c2w=[np.asarray(m, float) for m in c2w], points=points[keep], errors_px=np.zeros(int(keep.sum())),
                       track_len=track[keep], obs_frame=np.asarray(of, np.int64)[ok],
                       obs_point=new_id[np.asarray(op, np.int64)[ok]] if op else np.zeros(0, np.int64),
                       obs_xy=np.asarray(oxy, float).reshape(-1, 2)[ok])
