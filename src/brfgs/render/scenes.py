"""Seeded random Gaussian scenes for the rasterizer's tests and benchmark.

:func:`ground_scene` imitates a trained landscape model: Gaussians spread over a ground
patch (gentle relief plus a canopy layer) filling a camera's view, sized so that each covers
a few pixels on screen, flattened along z like surface elements, random orientations,
opacities 0.05–0.95. :func:`random_scene` is an unstructured cloud in front of the camera
(parts behind the near plane and off-screen) for the correctness tests.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from brfgs.data.cameras import Intrinsics, pose_from_view_angles, viewmat_from_c2w


def _camera(width, height, fov_deg, zen_deg, az_deg, dist_m):
    intr = Intrinsics.from_fov(fov_deg, width, height)
    c2w = pose_from_view_angles(zen_deg, az_deg, dist_m)
    return viewmat_from_c2w(c2w), intr.K()


def ground_scene(n: int, width: int, height: int, channels: int, seed: int = 0,
                 dtype: torch.dtype = torch.float32, px_size: float = 1.0, view_zenith_deg: float = 20.0,
                 view_azimuth_deg: float = 30.0, fov_deg: float = 35.0, distance_m: float = 30.0) -> dict:
    """A landscape-like scene of ``n`` Gaussians seen by one camera.

    Returns dict with means [n,3], quats [n,4], scales [n,3], opacities [n], features [n,C],
    normals [n,3], viewmat [4,4], K [3,3] (float64 camera), width, height. ``px_size`` is the
    typical on-screen 1σ size of a Gaussian in pixels.
    """
    g = np.random.default_rng(seed)
    viewmat, K = _camera(width, height, fov_deg, view_zenith_deg, view_azimuth_deg, distance_m)
    # ground patch half-size that fills the view (a bit larger, so some are off-screen)
    half = 1.15 * distance_m * math.tan(math.radians(fov_deg) / 2) / max(math.cos(math.radians(view_zenith_deg)), 0.3)
    xy = g.uniform(-half, half, (n, 2))
    relief = 0.3 * np.sin(xy[:, 0] / 3.0) * np.cos(xy[:, 1] / 4.0)
    canopy = (g.random(n) < 0.4) * g.uniform(0.2, 1.5, n)
    z = relief + canopy + g.normal(0, 0.05, n)
    means = np.column_stack([xy, z])
    # pixel footprint at the patch centre: distance / focal length
    m_per_px = distance_m / K[0, 0]
    s = m_per_px * px_size * np.exp(g.normal(0, 0.4, (n, 3)))
    s[:, 2] *= 0.3  # flattened surface elements
    quats = g.normal(size=(n, 4))
    quats[:, 0] += 3.0  # mostly close to identity: elements roughly horizontal
    opac = g.uniform(0.05, 0.95, n)
    feats = g.uniform(0.0, 1.0, (n, channels))
    normals = g.normal(size=(n, 3)) * 0.2 + np.array([0, 0, 1.0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    t = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
    return dict(means=t(means), quats=t(quats), scales=t(s), opacities=t(opac), features=t(feats),
                normals=t(normals), viewmat=torch.tensor(viewmat), K=torch.tensor(K),
                width=width, height=height)


def random_scene(n: int, width: int, height: int, channels: int, seed: int = 0, dtype: torch.dtype = torch.float32,
                 px_size: float = 2.5, behind_fraction: float = 0.1, offscreen: float = 0.25,
                 max_opacity: float = 0.95) -> dict:
    """Unstructured Gaussians in front of a camera at the origin looking along +z (OpenCV).

    A fraction ``behind_fraction`` lies behind or on the near plane; the field is widened by
    ``offscreen`` so that Gaussians are partly off-screen. Returns the same dict as
    :func:`ground_scene`.
    """
    g = np.random.default_rng(seed)
    f = 0.9 * max(width, height)
    K = np.array([[f, 0, width / 2.0], [0, f * 1.05, height / 2.0], [0, 0, 1.0]])
    z = g.uniform(2.0, 6.0, n)
    behind = g.random(n) < behind_fraction
    z[behind] = g.uniform(-1.0, 0.011, behind.sum())
    zz = np.abs(z) + 1.0
    u = g.uniform(-offscreen * width, (1 + offscreen) * width, n)
    v = g.uniform(-offscreen * height, (1 + offscreen) * height, n)
    x = (u - K[0, 2]) / f * zz
    y = (v - K[1, 2]) / K[1, 1] * zz
    means = np.column_stack([x, y, z])
    s = (zz / f * px_size)[:, None] * np.exp(g.normal(0, 0.5, (n, 3)))
    quats = g.normal(size=(n, 4))
    opac = g.uniform(0.02, max_opacity, n)
    feats = g.normal(0.5, 0.5, (n, channels))
    normals = g.normal(size=(n, 3))
    # a rotated, translated camera so that the world-to-camera path is exercised
    ang = 0.3
    R = np.array([[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]])
    t_cw = np.array([0.2, -0.1, 0.3])
    viewmat = np.eye(4)
    viewmat[:3, :3] = R
    viewmat[:3, 3] = t_cw
    means_w = (means - t_cw) @ R  # world points whose camera coordinates are `means`
    t = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
    return dict(means=t(means_w), quats=t(quats), scales=t(s), opacities=t(opac), features=t(feats),
                normals=t(normals), viewmat=torch.tensor(viewmat), K=torch.tensor(K),
                width=width, height=height)
