"""Depth supervision from the dense stereo of the initialisation (``--init-fill mvs``): each
training view's rendered depth is pulled toward its own plane-sweep depth map where stereo kept
a depth (:func:`brfgs.init.mvs.stereo_depths`: a good score and at least two other views that
agree). The dense counterpart of :mod:`brfgs.train.sparse_depth` (DS-NeRF-style supervision,
here with multi-view stereo depth as in depth-regularised 3DGS, Chung et al. 2024).

The depth maps live in OUT/init/dense_depths.npz (frame names and one float32 map per training
frame, at the stereo's matching scale), so a resumed run reads the same targets.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from brfgs.data import atomic
from brfgs.errors import UserError
from brfgs.model.camera import Camera

FILE = "dense_depths.npz"


def save_dense_depths(path: Path, names: list[str], depths: list[np.ndarray]) -> None:
    """Write the depth maps [h, w] (m, NaN: none) of the frames ``names`` to ``path`` (npz)."""
    arr = np.stack([np.asarray(d, np.float32) for d in depths]) if depths else np.zeros((0, 1, 1), np.float32)
    with atomic.atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, names=np.asarray(names, dtype=str), depths=arr)


@dataclass
class DenseDepth:
    """Per training frame index, its stereo depth map [H, W] (m, NaN: none) at the training images' size."""

    by_frame: dict[int, Tensor]

    def target(self, frame: int, cam: Camera, window) -> Tensor | None:
        """The depth map of ``frame`` cropped to the batch ``window`` (x0, y0, w, h) or None."""
        d = self.by_frame.get(int(frame))
        if d is None:
            return None
        if window is not None:
            x0, y0, w, h = window
            d = d[y0 : y0 + h, x0 : x0 + w]
        return d if d.shape == (cam.height, cam.width) else None


def upsample_nearest(depth: np.ndarray, height: int, width: int) -> np.ndarray:  # [height, width]
    """A depth map [h, w] on the ``height`` x ``width`` pixel grid (nearest; pixel centres aligned)."""
    h, w = depth.shape
    rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(int), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(int), w - 1)
    return depth[rows][:, cols]


def load_dense_depth(init_dir: Path, frame_names: list[str], train_indices: list[int], height: int,
                     width: int) -> DenseDepth:
    """The stereo depth maps of a run's initialisation (``init_dir``/dense_depths.npz) for the
    training frames, resampled to the training images' size."""
    path = Path(init_dir) / FILE
    if not path.is_file():
        raise UserError("the dense-depth loss needs the stereo depth maps of a dense initialisation; this run "
                        "has none: pass --init-fill mvs, or --lambda-dense-depth 0", file=path, field="lambda_dense_depth")
    try:
        with np.load(path) as z:
            names, depths = [str(n) for n in z["names"]], np.asarray(z["depths"], np.float32)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise UserError(f"cannot read the stereo depth maps: {exc}", file=path, field="depths") from None
    if depths.ndim != 3 or len(names) != len(depths):
        raise UserError(f"expected one depth map per name, got {len(names)} names and maps of shape "
                        f"{depths.shape}", file=path, field="depths")
    index_of = {n: i for i, n in enumerate(frame_names)}
    train = set(int(i) for i in train_indices)
    by_frame = {}
    for n, d in zip(names, depths):
        i = index_of.get(n)
        if i is not None and i in train:
            by_frame[i] = torch.as_tensor(upsample_nearest(d, height, width))
    return DenseDepth(by_frame)


def dense_depth_loss(depth_premult: Tensor, alpha: Tensor, target_m: Tensor, min_alpha: float = 0.5) -> Tensor:
    """Mean relative depth error |d_r − d_t| / d_t over the pixels with a stereo depth d_t.

    Args:
        depth_premult: [H, W] rasterized (premultiplied) camera depth (m); d_r = it / alpha.
        alpha: [H, W] accumulated opacity; pixels below ``min_alpha`` do not count.
        target_m: [H, W] stereo depth (m), NaN where stereo kept none.
    Relative, as the sparse-depth loss, and L1, so that a wrong stereo depth pulls with a bounded force.
    """
    ok = torch.isfinite(target_m) & (alpha > min_alpha)
    if not bool(ok.any()):
        return depth_premult.sum() * 0.0
    d = depth_premult[ok] / alpha[ok]
    t = target_m[ok]
    return ((d - t).abs() / t).mean()
