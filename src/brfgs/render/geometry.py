"""Geometry of Gaussians and pinhole cameras shared by the rasterizer, the reflectance head and
the trainer: one copy of each formula."""

from __future__ import annotations

import torch
from torch import Tensor


def quat_to_rotmat(
    quats: Tensor,  # [..., 4] (w, x, y, z), need not be normalised
) -> Tensor:  # [..., 3, 3]
    """Rotation matrices from quaternions. Column j is the world direction of the Gaussian's local
    axis j (Σ = R S² Rᵀ), as in 3DGS/gsplat."""
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
    return torch.stack(rows, -2)


def project_pinhole(
    points: Tensor,  # [N, 3] world, m
    viewmat: Tensor,  # [4, 4] world -> camera (OpenCV axes)
    K: Tensor,  # [3, 3] px
) -> tuple[Tensor, Tensor]:  # uv [N, 2] px, z [N] m
    """Pixel coordinates (pixel i spans [i, i + 1)) and camera depth of world points; depth is
    clamped at 1e-6 m in the division only, so points behind the camera have z <= 0."""
    pc = points @ viewmat[:3, :3].T + viewmat[:3, 3]  # [N, 3]
    z = pc[:, 2]
    u = K[0, 0] * pc[:, 0] / z.clamp_min(1e-6) + K[0, 2]
    v = K[1, 1] * pc[:, 1] / z.clamp_min(1e-6) + K[1, 2]
    return torch.stack([u, v], -1), z
