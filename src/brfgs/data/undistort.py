"""Distorted and per-frame cameras: resampled once, on reading, to the scene's common pinhole camera.

``transforms.json`` may give ``camera_model: "OPENCV"`` with ``k1, k2, p1, p2`` (OpenCV's radial and
tangential coefficients, nerfstudio's keys), and any frame may carry its own ``camera_model``, ``fl_x``,
``fl_y``, ``cx``, ``cy``, ``w``, ``h``, ``k1`` … ``p2`` (per-frame intrinsics). brfgs resamples every
such frame, band by band, onto the scene's pinhole camera (the top-level ``fl_x`` … ``h``, or the
first frame's when the top level has none) with OpenCV (``initUndistortRectifyMap`` + ``remap``,
bilinear): the rest of the pipeline — rays, the rasterizer, metrics — sees ideal pinhole images.
Target pixels whose ray falls outside the frame's image are NaN (masked like any invalid pixel).

Pixel convention: brfgs's intrinsics put pixel centres at +0.5 (docs/data-format.md), OpenCV's at integer
coordinates; the maps convert between them (c_opencv = c − 0.5).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from brfgs.data import validation as V
from brfgs.data.cameras import Intrinsics
from brfgs.errors import UserError

__all__ = ["CAMERA_MODELS", "DIST_KEYS", "FrameCamera", "read_frame_camera", "resample_maps", "resample_cube"]

CAMERA_MODELS = ("PINHOLE", "OPENCV")
DIST_KEYS = ("k1", "k2", "p1", "p2")
_INTR_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
MAX_IMAGE_SIDE = 65_535  # pixels a side of an image (COLMAP's and TIFF's practical limit)
MAX_FOCAL_PX = 1e7  # a focal length beyond this many pixels is not a camera's


@dataclass(frozen=True)
class FrameCamera:
    """A frame's own camera: pinhole intrinsics (pixel centres at +0.5) and OpenCV distortion."""

    intrinsics: Intrinsics
    dist: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)   # k1, k2, p1, p2

    def is_pinhole_like(self, target: Intrinsics) -> bool:
        """True when reading this frame needs no resampling onto ``target``."""
        return not any(self.dist) and self.intrinsics == target

    def opencv_K(self) -> np.ndarray:  # [3, 3], OpenCV pixel convention
        i = self.intrinsics
        return np.array([[i.fl_x, 0.0, i.cx - 0.5], [0.0, i.fl_y, i.cy - 0.5], [0.0, 0.0, 1.0]])


def read_frame_camera(d: dict, tf: Path, field: str, base: dict | None = None) -> FrameCamera | None:
    """The camera of ``d`` (top level or a frame) with ``base``'s keys as defaults; None when
    the intrinsics are not all given. UserError naming ``field.key`` for bad values."""
    merged = dict(base or {})
    merged.update({k: d[k] for k in ("camera_model", *_INTR_KEYS, *DIST_KEYS) if k in d})
    given_null = [k for k in (*_INTR_KEYS, *DIST_KEYS) if k in d and d[k] is None]
    if given_null:
        raise UserError("expected a number, found null", file=tf, field=f"{field}{given_null[0]}")
    model = merged.get("camera_model", "PINHOLE")
    if model not in CAMERA_MODELS:
        raise UserError(f"camera model {model!r} not supported, expected one of {', '.join(CAMERA_MODELS)}",
                        file=tf, field=f"{field}camera_model")
    if not all(merged.get(k) is not None for k in _INTR_KEYS):
        return None
    w = V.number(merged["w"], tf, f"{field}w", lo=1, hi=MAX_IMAGE_SIDE, integer=True)
    h = V.number(merged["h"], tf, f"{field}h", lo=1, hi=MAX_IMAGE_SIDE, integer=True)
    fx, fy = (V.number(merged[k], tf, f"{field}{k}", lo=1e-3, hi=MAX_FOCAL_PX) for k in ("fl_x", "fl_y"))
    cx, cy = V.number(merged["cx"], tf, f"{field}cx"), V.number(merged["cy"], tf, f"{field}cy")
    if not 0 < cx < w:
        raise UserError(f"principal point cx = {cx:g} lies outside the image width w = {w}", file=tf, field=f"{field}cx")
    if not 0 < cy < h:
        raise UserError(f"principal point cy = {cy:g} lies outside the image height h = {h}", file=tf,
                        field=f"{field}cy")
    dist = (0.0, 0.0, 0.0, 0.0)
    if model == "OPENCV":
        dist = tuple(V.number(merged.get(k, 0.0), tf, f"{field}{k}", lo=-10.0, hi=10.0) for k in DIST_KEYS)
    elif any(merged.get(k) not in (None, 0, 0.0) for k in DIST_KEYS):
        raise UserError("distortion coefficients given for a PINHOLE camera; set camera_model to 'OPENCV'",
                        file=tf, field=f"{field}camera_model")
    return FrameCamera(Intrinsics(fx, fy, cx, cy, int(w), int(h)), dist)


@functools.lru_cache(maxsize=16)
def resample_maps(src: FrameCamera, dst: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(map_x, map_y) float32 [dst.h, dst.w]: the source pixel (OpenCV coordinates) that each target
    pixel's ray hits in the frame's distorted image."""
    dst_k = FrameCamera(dst).opencv_K()
    mx, my = cv2.initUndistortRectifyMap(src.opencv_K(), np.asarray(src.dist, float), None, dst_k,
                                         (int(dst.w), int(dst.h)), cv2.CV_32FC1)
    return mx, my


def resample_cube(cube: np.ndarray, src: FrameCamera, dst: Intrinsics) -> np.ndarray:
    """Resample a frame's cube [src.h, src.w, B] onto the pinhole ``dst`` → [dst.h, dst.w, B] float32
    (bilinear; NaN outside the frame's image)."""
    mx, my = resample_maps(src, dst)
    cube = np.ascontiguousarray(cube, np.float32)
    out = np.empty((dst.h, dst.w, cube.shape[2]), np.float32)
    for b0 in range(0, cube.shape[2], 4):                       # remap takes at most 4 channels at a time
        part = cube[:, :, b0:b0 + 4]
        res = cv2.remap(part, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        out[:, :, b0:b0 + part.shape[2]] = res.reshape(dst.h, dst.w, -1)
    return out
