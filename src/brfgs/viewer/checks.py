"""Every value a browser sends, checked before the viewer uses it.

A viser client reports its camera (position, orientation, vertical field of view, canvas size in
pixels), clicks (screen position) and widget values; any page that may connect can send any
value. These functions turn them into what the viewer needs or raise a one-line
:class:`brfgs.errors.UserError` naming the field, so that a bad message costs that client one
status line and nothing else: frames are at most :data:`MAX_SIDE_PX` a side, cameras finite,
fields of view in (0, π), sun angles and radii within the sliders' ranges, ROI names safe as
folder names.
"""

from __future__ import annotations

import math
import re

import numpy as np

from brfgs.data.cameras import Intrinsics
from brfgs.errors import UserError
from brfgs.viewer.cameras import c2w_from_viser

__all__ = ["MAX_SIDE_PX", "MAX_COORDINATE_M", "SUN_ZENITH_DEG", "SUN_AZIMUTH_DEG", "ROI_RADIUS_M", "frame_size",
           "client_view", "checked_number", "roi_name", "screen_point"]

MAX_SIDE_PX = 4096                  # no frame side larger than this, whatever the canvas
MAX_COORDINATE_M = 1.0e7            # camera positions beyond this are not a view of a scene
SUN_ZENITH_DEG = (0.0, 85.0)        # the sliders' ranges
SUN_AZIMUTH_DEG = (0.0, 360.0)
ROI_RADIUS_M = (0.1, 50.0)
_ROI_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


def _finite(values, n: int, field: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise UserError(f"{field} must be {n} numbers", field=field) from None
    if a.size != n or not np.isfinite(a).all():
        raise UserError(f"{field} must be {n} finite numbers", field=field)
    return a


def checked_number(value, lo: float, hi: float, field: str) -> float:
    """``value`` as a float within [lo, hi]; UserError naming ``field`` otherwise (NaN included)."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise UserError(f"{field} must be a number, got {str(value)[:40]!r}", field=field) from None
    if not (lo <= v <= hi):
        raise UserError(f"{field} must be within [{lo:g}, {hi:g}], got {v:g}", field=field)
    return v


def frame_size(canvas_w, canvas_h, height_px: int) -> tuple[int, int]:
    """(W, H) of a frame ``height_px`` high with the canvas's aspect ratio, both sides within
    [2, MAX_SIDE_PX] (a very wide canvas gets a lower frame); UserError for a canvas size that is not
    two positive numbers."""
    w, h = _finite((canvas_w, canvas_h), 2, "canvas size")
    if w < 1 or h < 1:
        raise UserError(f"the browser's canvas is {w:g} x {h:g} px; nothing to draw", field="canvas size")
    aspect = w / h
    fh = min(int(height_px), MAX_SIDE_PX)
    fw = int(round(fh * aspect))
    if fw > MAX_SIDE_PX:
        fw, fh = MAX_SIDE_PX, int(round(MAX_SIDE_PX / aspect))
    return min(max(fw, 2), MAX_SIDE_PX), min(max(fh, 2), MAX_SIDE_PX)


def client_view(position, wxyz, fov_rad, canvas_w, canvas_h, height_px: int) -> tuple[np.ndarray, Intrinsics]:
    """(OpenGL camera-to-world [4, 4], square-pixel pinhole) of a browser camera: ``position`` [3] (m),
    orientation ``wxyz`` [4] (OpenCV axes, any non-zero length), vertical field of view (rad, in
    (0, π)), canvas size (px) → a frame ``height_px`` high (:func:`frame_size`)."""
    p = _finite(position, 3, "camera position")
    if np.abs(p).max() > MAX_COORDINATE_M:
        raise UserError(f"camera position beyond {MAX_COORDINATE_M:g} m", field="camera position")
    q = _finite(wxyz, 4, "camera orientation")
    if np.linalg.norm(q) < 1e-6:
        raise UserError("camera orientation is a zero quaternion", field="camera orientation")
    fov = float(_finite((fov_rad,), 1, "field of view")[0])
    if not 0.0 < fov < math.pi:
        raise UserError(f"field of view must be in (0, pi) rad, got {fov:g}", field="field of view")
    w, h = frame_size(canvas_w, canvas_h, height_px)
    f = 0.5 * h / math.tan(0.5 * fov)
    if not (math.isfinite(f) and f > 0):
        raise UserError(f"field of view {fov:g} rad gives no usable focal length", field="field of view")
    return c2w_from_viser(p, q), Intrinsics(f, f, w / 2.0, h / 2.0, w, h)


def screen_point(screen_pos) -> tuple[float, float]:
    """(x, y) of a click in [0, 1]² (0, 0 top left); UserError otherwise."""
    x, y = _finite(screen_pos, 2, "click position")
    if not (0.0 <= x <= 1.0 and 0.0 <= y <= 1.0):
        raise UserError(f"click position ({x:g}, {y:g}) is outside the view", field="click position")
    return float(x), float(y)


def roi_name(text) -> str:
    """A saved ROI's folder name: 1–64 letters, digits, ``_ . -``, starting with a letter or digit
    (no path separators, no ``..``); UserError naming ``ROI name`` otherwise."""
    t = str(text).strip()
    if not _ROI_NAME.match(t) or ".." in t:
        raise UserError(f"ROI name {t[:40]!r}: use 1-64 letters, digits, _ . - (starting with a letter or digit)",
                        field="ROI name")
    return t
