"""Camera conventions.

Files (``transforms.json``) hold nerfstudio camera-to-world matrices with OpenGL
camera axes (camera looks along −Z, +Y up in the image, +X right). The rasterizer
(brfgs.render) takes, like gsplat, a world-to-camera ``viewmat`` with OpenCV axes
(+X right, +Y down, +Z forward) and a pinhole ``K`` with pixel centres at +0.5.
This module converts between them and builds poses from view angles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from brfgs.data.angles import direction_from_angles_deg

# OpenGL camera axes -> OpenCV camera axes (flip Y and Z).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels (pixel centres at +0.5)."""

    fl_x: float
    fl_y: float
    cx: float
    cy: float
    w: int
    h: int

    def K(self) -> np.ndarray:
        """3×3 intrinsic matrix [3, 3]."""
        return np.array([[self.fl_x, 0.0, self.cx], [0.0, self.fl_y, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, factor: int) -> "Intrinsics":
        """Intrinsics of the image area-averaged by an integer ``factor`` (w, h floor-divided)."""
        return Intrinsics(self.fl_x / factor, self.fl_y / factor, self.cx / factor, self.cy / factor,
                          self.w // factor, self.h // factor)

    def cropped(self, x0: int, y0: int, w: int, h: int) -> "Intrinsics":
        """Intrinsics of the sub-image starting at pixel (x0, y0) of size w×h."""
        return Intrinsics(self.fl_x, self.fl_y, self.cx - x0, self.cy - y0, w, h)

    @staticmethod
    def from_fov(fov_deg: float, w: int, h: int) -> "Intrinsics":
        """Square-pixel intrinsics with horizontal field of view ``fov_deg`` and centred principal point."""
        f = 0.5 * w / math.tan(math.radians(fov_deg) / 2)
        return Intrinsics(f, f, w / 2.0, h / 2.0, int(w), int(h))


def look_at_c2w(eye_m: np.ndarray, target_m: np.ndarray | None = None, up: np.ndarray | None = None) -> np.ndarray:
    """OpenGL camera-to-world [4, 4] for a camera at ``eye_m`` looking at ``target_m``.

    Image-up is toward ``up`` (+z by default) as far as possible; when the view is
    vertical, image-up is north (+y).
    """
    eye = np.asarray(eye_m, float)
    target = np.zeros(3) if target_m is None else np.asarray(target_m, float)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float)
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight down/up: image-up = north
        right = np.cross(forward, np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0] = right
    c2w[:3, 1] = cam_up
    c2w[:3, 2] = -forward
    c2w[:3, 3] = eye
    return c2w


def pose_from_view_angles(view_zenith_deg: float, view_azimuth_deg: float, distance_m: float,
                          target_m: np.ndarray | None = None) -> np.ndarray:
    """OpenGL camera-to-world [4, 4] at ``distance_m`` from the target in the view direction.

    The view direction points from the target toward the sensor (conventions: Angles).
    """
    target = np.zeros(3) if target_m is None else np.asarray(target_m, float)
    eye = target + distance_m * direction_from_angles_deg(view_zenith_deg, view_azimuth_deg)
    return look_at_c2w(eye, target)


def viewmat_from_c2w(c2w_gl: np.ndarray) -> np.ndarray:
    """World-to-camera [4, 4] with OpenCV axes from an OpenGL camera-to-world [4, 4]."""
    c2w_cv = np.asarray(c2w_gl, float) @ GL_TO_CV
    R = c2w_cv[:3, :3]
    t = c2w_cv[:3, 3]
    w2c = np.eye(4)
    w2c[:3, :3] = R.T
    w2c[:3, 3] = -R.T @ t
    return w2c


def c2w_from_viewmat(viewmat_cv: np.ndarray) -> np.ndarray:
    """Inverse of :func:`viewmat_from_c2w`."""
    return np.linalg.inv(np.asarray(viewmat_cv, float)) @ GL_TO_CV


def camera_centre(c2w_gl: np.ndarray) -> np.ndarray:
    """Camera centre [3] (metres, ENU) of a camera-to-world matrix."""
    return np.asarray(c2w_gl, float)[:3, 3].copy()


def project_points(points_m: np.ndarray, c2w_gl: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Project world points [N, 3] → pixel coordinates [N, 2] (x right, y down) and depth [N] (m, along the view axis)."""
    vm = viewmat_from_c2w(c2w_gl)
    pc = points_m @ vm[:3, :3].T + vm[:3, 3]  # [N, 3] OpenCV camera coords
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intr.fl_x * pc[:, 0] / z + intr.cx
        v = intr.fl_y * pc[:, 1] / z + intr.cy
    return np.stack([u, v], -1), z


def pixel_rays(c2w_gl: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins [H, W, 3] and unit directions [H, W, 3] (world) through pixel centres."""
    j, i = np.meshgrid(np.arange(intr.h) + 0.5, np.arange(intr.w) + 0.5, indexing="ij")
    x = (i - intr.cx) / intr.fl_x
    y = (j - intr.cy) / intr.fl_y
    d_cv = np.stack([x, y, np.ones_like(x)], -1)  # [H, W, 3]
    c2w_cv = np.asarray(c2w_gl, float) @ GL_TO_CV
    d = d_cv @ c2w_cv[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = np.broadcast_to(c2w_cv[:3, 3], d.shape).copy()
    return o, d


def paper_view_angles(n_views: int = 49) -> list[tuple[float, float]]:
    """(view_zenith_deg, view_azimuth_deg) of the paper's acquisition: nadir + 12 azimuths × (18, 23, 38, 58)°.

    Smaller ``n_views`` (1 + 12·k, e.g. 13 or 25) keep nadir and the first k zenith rings
    in the order 38, 18, 58, 23 so a small preset still spans the angular range.
    """
    rings = [38.0, 18.0, 58.0, 23.0]
    if (n_views - 1) % 12 != 0 or not 1 <= n_views <= 49:
        raise ValueError("n_views must be 1 + 12k with k in 0..4 (1, 13, 25, 37, 49)")
    return ring_view_angles(rings[: (n_views - 1) // 12], 12)


def ring_view_angles(rings_deg, n_azimuths: int) -> list[tuple[float, float]]:
    """(view_zenith_deg, view_azimuth_deg) of nadir + ``n_azimuths`` azimuths (from 0°, evenly spaced)
    on each ring of ``rings_deg``, ring by ring in ascending zenith."""
    step = 360.0 / int(n_azimuths)
    return [(0.0, 0.0)] + [(z, k * step) for z in sorted(float(v) for v in rings_deg) for k in range(int(n_azimuths))]
