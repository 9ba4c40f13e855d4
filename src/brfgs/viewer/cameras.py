"""viser's browser camera ↔ brfgs cameras.

viser reports a camera by its position (world, m), an orientation quaternion ``wxyz`` that turns
camera axes into world axes with **OpenCV** camera axes (+x right, +y down, +z forward), the
vertical field of view (radians) and the aspect ratio (W / H). brfgs stores camera-to-world
matrices with **OpenGL** axes (+y up, looking along −z; :data:`brfgs.data.cameras.GL_TO_CV`).
"""

from __future__ import annotations

import math

import numpy as np

from brfgs.data.cameras import GL_TO_CV, Intrinsics

__all__ = ["quat_to_rotmat_np", "rotmat_to_quat_np", "c2w_from_viser", "viser_from_c2w", "intrinsics_from_fov",
           "fov_from_intrinsics"]


def quat_to_rotmat_np(wxyz: np.ndarray) -> np.ndarray:  # [3, 3]
    """Rotation matrix of a quaternion (w, x, y, z) (normalised first)."""
    w, x, y, z = np.asarray(wxyz, float) / np.linalg.norm(wxyz)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotmat_to_quat_np(R: np.ndarray) -> np.ndarray:  # [4] wxyz, w >= 0
    """Quaternion (w, x, y, z) of a rotation matrix [3, 3] (Shepperd's method)."""
    R = np.asarray(R, float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-12))
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q) / np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def c2w_from_viser(position_m: np.ndarray, wxyz: np.ndarray) -> np.ndarray:  # [4, 4] OpenGL c2w
    """brfgs camera-to-world (OpenGL axes) of a viser camera (position [3] m, OpenCV-axes wxyz [4])."""
    c2w_cv = np.eye(4)
    c2w_cv[:3, :3] = quat_to_rotmat_np(wxyz)
    c2w_cv[:3, 3] = np.asarray(position_m, float)
    return c2w_cv @ GL_TO_CV  # GL_TO_CV is its own inverse


def viser_from_c2w(c2w_gl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position [3] m, wxyz [4]) for viser of a brfgs camera-to-world [4, 4] (OpenGL axes)."""
    c2w_cv = np.asarray(c2w_gl, float) @ GL_TO_CV
    return c2w_cv[:3, 3].copy(), rotmat_to_quat_np(c2w_cv[:3, :3])


def intrinsics_from_fov(fov_y_rad: float, aspect: float, height_px: int) -> Intrinsics:
    """Square-pixel pinhole of a viser camera: vertical field of view (rad), aspect W / H, height (px)."""
    h = max(int(height_px), 2)
    w = max(int(round(h * float(aspect))), 2)
    f = 0.5 * h / math.tan(0.5 * float(fov_y_rad))
    return Intrinsics(f, f, w / 2.0, h / 2.0, w, h)


def fov_from_intrinsics(intr: Intrinsics) -> tuple[float, float]:
    """(vertical field of view in radians, aspect W / H) of a pinhole (for viser's frustums)."""
    return 2.0 * math.atan(0.5 * intr.h / intr.fl_y), intr.w / intr.h
