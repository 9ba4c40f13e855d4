"""Distorted simulated cameras: render a pinhole image wide enough, then resample it into the
OPENCV-distorted image (k1, k2, p1, p2) a real lens would record.

Every pixel of the distorted image looks along the ray OpenCV's ``undistortPoints`` gives for it;
the pinhole render (same focal length, a margin so that every such ray is inside) is sampled there
(bilinear for radiance and depth, nearest for material ids). brfgs reads such frames back through
:mod:`brfgs.data.undistort`.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from brfgs.data.cameras import Intrinsics

__all__ = ["render_grid", "to_distorted"]


def render_grid(intr: Intrinsics, dist) -> tuple[Intrinsics, tuple[np.ndarray, np.ndarray]]:
    """(pinhole intrinsics to render, (map_x, map_y) [h, w] float32 into that render) for the
    distorted camera ``intr`` + ``dist`` (k1, k2, p1, p2)."""
    k = np.array([[intr.fl_x, 0, intr.cx - 0.5], [0, intr.fl_y, intr.cy - 0.5], [0, 0, 1]], float)
    u, v = np.meshgrid(np.arange(intr.w, dtype=np.float64), np.arange(intr.h, dtype=np.float64))
    und = cv2.undistortPoints(np.c_[u.ravel(), v.ravel()][:, None], k, np.asarray(dist, float))[:, 0]
    xn, yn = und[:, 0].reshape(intr.h, intr.w), und[:, 1].reshape(intr.h, intr.w)
    half_w = max(abs(xn).max() * intr.fl_x, intr.cx, intr.w - intr.cx) + 2.0
    half_h = max(abs(yn).max() * intr.fl_y, intr.cy, intr.h - intr.cy) + 2.0
    w, h = 2 * math.ceil(half_w), 2 * math.ceil(half_h)
    grid = Intrinsics(intr.fl_x, intr.fl_y, w / 2, h / 2, w, h)
    mx = (xn * intr.fl_x + grid.cx - 0.5).astype(np.float32)
    my = (yn * intr.fl_y + grid.cy - 0.5).astype(np.float32)
    return grid, (mx, my)


def to_distorted(img: np.ndarray, maps: tuple[np.ndarray, np.ndarray], nearest: bool = False) -> np.ndarray:
    """Sample a render of :func:`render_grid`'s pinhole camera [H', W'(, B)] into the distorted image."""
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    if img.ndim == 2:
        return cv2.remap(img, maps[0], maps[1], interp, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    out = np.empty(maps[0].shape + (img.shape[2],), img.dtype)
    for b0 in range(0, img.shape[2], 4):
        part = np.ascontiguousarray(img[..., b0:b0 + 4])
        res = cv2.remap(part, maps[0], maps[1], interp, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        out[..., b0:b0 + part.shape[2]] = res.reshape(maps[0].shape + (-1,))
    return out
