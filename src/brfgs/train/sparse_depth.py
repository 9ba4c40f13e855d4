"""Depth supervision from the sparse SfM points (DS-NeRF-style, Deng et al. 2022; as used for
3DGS by Chung et al. 2024 and DNGaussian): each training view's rendered depth is pulled toward
the camera depth of the sparse points that view observed.

The SfM points are triangulated from many views at once, so their heights hold across the view
rings; the photometric loss alone lets the ground's height drift by a fraction of a pixel's
parallax, which fits the training views but moves the ground texture between a 58° view and the
nadir (docs/results.md, "Where the 58° ring loses"). Only a point's own track supervises a view:
a view that did not match the point may not see it (occlusion).
"""

from __future__ import annotations

import zipfile

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData
from torch import Tensor

from brfgs.errors import UserError
from brfgs.init.outputs import read_tracks
from brfgs.model.camera import Camera


@dataclass
class SparseDepth:
    """The sparse points [P, 3] (m, ENU) and, per frame index, the points its track lists."""

    points: Tensor                      # [P, 3] float32
    by_frame: dict[int, Tensor]         # frame -> [m] long point indices

    @classmethod
    def from_tracks(cls, points: np.ndarray, obs_frame: np.ndarray, obs_point: np.ndarray,
                    frames: list[int]) -> "SparseDepth":
        """From COLMAP-style observations (``obs_frame``/``obs_point`` [O]), for ``frames`` only."""
        obs_frame, obs_point = np.asarray(obs_frame, np.int64), np.asarray(obs_point, np.int64)
        by_frame = {}
        for f in frames:
            idx = np.unique(obs_point[obs_frame == f])
            if idx.size:
                by_frame[int(f)] = torch.as_tensor(idx, dtype=torch.long)
        return cls(torch.as_tensor(np.asarray(points, np.float32).reshape(-1, 3)), by_frame)

    def targets(self, frame: int, cam: Camera) -> tuple[Tensor, Tensor] | None:
        """Pixel positions [m, 2] (x, y; pixel centres at +0.5, in ``cam``'s window) and camera
        depths [m] (m along the optical axis) of frame ``frame``'s points inside ``cam``; None if none."""
        idx = self.by_frame.get(int(frame))
        if idx is None:
            return None
        return project_points(self.points[idx], cam)


def project_points(points: Tensor, cam: Camera) -> tuple[Tensor, Tensor] | None:
    """Pinhole projection of ``points`` [m, 3] (m, world) by ``cam``: (xy [k, 2] px, depth [k] m) of
    those in front of the camera and inside its image (a 1-pixel margin for interpolation)."""
    vm, K = cam.viewmat, cam.K
    pc = points @ vm[:3, :3].T + vm[:3, 3]  # [m, 3] camera (OpenCV: z forward)
    z = pc[:, 2]
    front = z > 1e-6
    uv = (pc[:, :2] / z.clamp_min(1e-6)[:, None]) @ K[:2, :2].T + K[:2, 2]  # [m, 2] px
    inside = front & (uv[:, 0] >= 0.5) & (uv[:, 0] <= cam.width - 0.5) & (uv[:, 1] >= 0.5) & (uv[:, 1] <= cam.height - 0.5)
    if not bool(inside.any()):
        return None
    return uv[inside], z[inside]


def sample_bilinear(img: Tensor, xy: Tensor) -> Tensor:  # [k, C]
    """``img`` [H, W, C] at the pixel positions ``xy`` [k, 2] (pixel centres at +0.5), bilinear,
    differentiable in ``img``; positions are clamped to the pixel centres of the border."""
    h, w = img.shape[:2]
    x = (xy[:, 0] - 0.5).clamp(0, w - 1)
    y = (xy[:, 1] - 0.5).clamp(0, h - 1)
    x0, y0 = x.floor().long().clamp(max=w - 2 if w > 1 else 0), y.floor().long().clamp(max=h - 2 if h > 1 else 0)
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def sparse_depth_loss(depth_premult: Tensor, alpha: Tensor, xy: Tensor, depth_m: Tensor,
                      min_alpha: float = 0.5) -> Tensor:
    """Mean relative depth error |d_r(x_p) − d_p| / d_p over the sparse points p the view observed.

    Args:
        depth_premult: [H, W] rasterized (premultiplied) camera depth (m); d_r = it / alpha.
        alpha: [H, W] accumulated opacity; points where it is below ``min_alpha`` do not count.
        xy: [k, 2] the points' pixel positions (pixel centres at +0.5); depth_m: [k] their camera depths.
    Relative, so that near and far points weigh alike; L1, so that a wrong SfM point pulls with a
    bounded force.
    """
    both = sample_bilinear(torch.stack([depth_premult, alpha], -1), xy)  # [k, 2]
    ok = both[:, 1] > min_alpha
    if not bool(ok.any()):
        return depth_premult.sum() * 0.0
    d = both[ok, 0] / both[ok, 1]
    return ((d - depth_m[ok]).abs() / depth_m[ok]).mean()


def load_sparse_depth(init_dir: Path, frame_names: list[str], train_indices: list[int]) -> SparseDepth:
    """The sparse points (``init_dir``/points.ply) and their tracks (tracks.npz) of a run's
    initialisation, for the training frames ``train_indices`` (indices into ``frame_names``)."""
    ply_path, tracks_path = Path(init_dir) / "points.ply", Path(init_dir) / "tracks.npz"
    for p in (ply_path, tracks_path):
        if not p.is_file():
            raise UserError("the sparse-depth loss needs the initialisation's points and tracks; this run's "
                            "initialisation has none (made by an older brfgs?): pass --lambda-sparse-depth 0",
                            file=p, field="lambda_sparse_depth")
    try:
        v = PlyData.read(str(ply_path))["vertex"]
        points = np.stack([np.asarray(v[k], np.float64) for k in ("x", "y", "z")], 1)  # [P, 3]
        obs_frame, obs_point, names = read_tracks(tracks_path)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise UserError(f"cannot read the initialisation's sparse points or tracks: {exc}", file=tracks_path,
                        field="obs_frame") from None
    if obs_point.size and (obs_point.max() >= len(points) or obs_point.min() < 0):
        raise UserError("a track names a point that points.ply does not have", file=tracks_path, field="obs_point")
    # tracks index the frames by the names of the run's scene; map them to this scene's order
    index_of = {n: i for i, n in enumerate(frame_names)}
    remap = np.array([index_of.get(n, -1) for n in names], np.int64)
    if obs_frame.size and (obs_frame.max() >= len(remap) or obs_frame.min() < 0):
        raise UserError("a track names a frame that tracks.npz does not list", file=tracks_path, field="obs_frame")
    return SparseDepth.from_tracks(points, remap[obs_frame] if obs_frame.size else obs_frame, obs_point,
                                   list(train_indices))
