"""Geometry of Gaussians and pinhole cameras shared by the rasterizer, the reflectance head, the
trainer and the evaluation: one copy of each formula.

Conventions (as gsplat): quaternions (w, x, y, z); world-to-camera ``viewmat`` with OpenCV axes
(+x right, +y down, +z forward); pinhole ``K`` in pixels with pixel i spanning [i, i + 1).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["quat_to_rotmat", "project_pinhole", "normals_from_depth"]


def quat_to_rotmat(
    quats: Tensor,  # [..., 4] (w, x, y, z), need not be normalised
) -> Tensor:  # [..., 3, 3]
    """Rotation matrices from quaternions (normalised here, the norm clamped at 1e-12).

    Column j is the world direction of the Gaussian's local axis j, so the covariance is
    Σ = R S² Rᵀ (3DGS, Kerbl et al. 2023, eq. 6; gsplat).
    """
    q = quats / torch.linalg.vector_norm(quats, dim=-1, keepdim=True).clamp_min(1e-12)  # [..., 4]
    w, x, y, z = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        torch.stack([1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)], -1),
        torch.stack([2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)], -1),
        torch.stack([2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)], -1),
    ]
    return torch.stack(rows, -2)  # [..., 3, 3]


def project_pinhole(
    points: Tensor,  # [N, 3] world, m
    viewmat: Tensor,  # [4, 4] world -> camera (OpenCV axes)
    K: Tensor,  # [3, 3] px
) -> tuple[Tensor, Tensor]:  # uv [N, 2] px, z [N] m
    """Pixel coordinates and camera depth of world points.

    uv = (f_x x/z + c_x, f_y y/z + c_y) with (x, y, z) = R p + t; z is clamped at 1e-6 m in the
    division only, so points behind the camera keep z ≤ 0 (callers mask them).
    """
    pc = points @ viewmat[:3, :3].T + viewmat[:3, 3]  # [N, 3]
    z = pc[:, 2]
    u = K[0, 0] * pc[:, 0] / z.clamp_min(1e-6) + K[0, 2]
    v = K[1, 1] * pc[:, 1] / z.clamp_min(1e-6) + K[1, 2]
    return torch.stack([u, v], -1), z


def normals_from_depth(depth: torch.Tensor, K: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Surface normals [H, W, 3] (camera axes, facing the camera) of a depth map [H, W] (m along
    the optical axis) from central differences of the back-projected points, and a validity
    mask [H, W] (border pixels and non-finite or non-positive depths are invalid).

    Pixel (u, v) back-projects to depth · K⁻¹ [u + 0.5, v + 0.5, 1] (pixel centres).
    """
    h, w = depth.shape
    v, u = torch.meshgrid(torch.arange(h, dtype=depth.dtype) + 0.5, torch.arange(w, dtype=depth.dtype) + 0.5,
                          indexing="ij")
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    ok = torch.isfinite(depth) & (depth > 0)
    d = torch.where(ok, depth, torch.ones_like(depth))
    pts = torch.stack([x * d, y * d, d], -1)  # [H, W, 3]
    dx = torch.zeros_like(pts)
    dy = torch.zeros_like(pts)
    dx[:, 1:-1] = pts[:, 2:] - pts[:, :-2]
    dy[1:-1, :] = pts[2:, :] - pts[:-2, :]
    n = torch.cross(dx, dy, dim=-1)  # [H, W, 3]; for a fronto-parallel plane (0, 0, +): away from the camera
    n = -n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    inner = torch.zeros_like(ok)
    inner[1:-1, 1:-1] = True
    valid = ok & inner
    valid[1:-1, 1:-1] &= ok[2:, 1:-1] & ok[:-2, 1:-1] & ok[1:-1, 2:] & ok[1:-1, :-2]
    return n, valid
