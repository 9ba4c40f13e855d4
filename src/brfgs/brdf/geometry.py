"""Per-Gaussian geometry for the reflectance head: normals and view directions.

Conventions (shared/conventions.md): ENU world frame; ω_o of Gaussian k is
``normalize(camera_centre − μ_k)``; the normal n_k is the axis of the Gaussian's smallest
scale, flipped to face ω_o (paper, after eq. 21).
"""

from __future__ import annotations

import torch

__all__ = ["quat_to_rotmat", "gaussian_normals", "view_directions", "sun_direction"]


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N, 3, 3] from quaternions [N, 4] (w, x, y, z; need not be normalised).

    Column j is the world direction of the Gaussian's local axis j (Σ = R S² Rᵀ), as in
    3DGS/gsplat.
    """
    q = quats / torch.linalg.vector_norm(quats, dim=-1, keepdim=True).clamp_min(1e-12)  # [N, 4]
    w, x, y, z = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        torch.stack([1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)], -1),
        torch.stack([2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)], -1),
        torch.stack([2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)], -1),
    ]
    return torch.stack(rows, -2)  # [N, 3, 3]


def gaussian_normals(quats: torch.Tensor, scales: torch.Tensor, omega_o: torch.Tensor) -> torch.Tensor:
    """Unit normals n_k [N, 3]: the axis of each Gaussian's smallest scale, facing ω_o.

    Args:
        quats: [N, 4] rotations (w, x, y, z), need not be normalised.
        scales: [N, 3] scales in metres (or log-scales: only their order matters).
        omega_o: [N, 3] (or [3]) unit vectors from the Gaussian toward the camera.
    Returns: [N, 3] unit normals with n·ω_o ≥ 0. Gradients flow to ``quats`` (the choice of
    axis is piecewise constant in ``scales``).
    """
    rot = quat_to_rotmat(quats)  # [N, 3, 3]
    idx = torch.argmin(scales.detach(), dim=-1)  # [N]
    n = torch.gather(rot, 2, idx.view(-1, 1, 1).expand(-1, 3, 1)).squeeze(-1)  # [N, 3]
    side = (n * omega_o).sum(-1, keepdim=True)  # [N, 1]
    sign = torch.where(side < 0, -1.0, 1.0).to(n.dtype)
    return n * sign


def shading_normals(quats: torch.Tensor, scales: torch.Tensor, omega_o: torch.Tensor,
                    normals: torch.Tensor | None = None) -> torch.Tensor:
    """Normals n_k [N, 3] used by the reflectance head, facing ω_o.

    ``normals`` [N, 3] (any length, any sign): the model's learned shading normals (stage 2,
    ``TrainConfig.learn_normals``); None: the geometric normal, the smallest axis
    (:func:`gaussian_normals`).
    """
    if normals is None:
        return gaussian_normals(quats, scales, omega_o)
    n = normals / torch.linalg.vector_norm(normals, dim=-1, keepdim=True).clamp_min(1e-12)  # [N, 3]
    side = (n * omega_o).sum(-1, keepdim=True)  # [N, 1]
    return torch.where(side < 0, -n, n)


def view_directions(means: torch.Tensor, camera_centre: torch.Tensor) -> torch.Tensor:
    """ω_o [N, 3]: unit vectors from each Gaussian centre means [N, 3] toward camera_centre [3] (m)."""
    v = camera_centre.to(means.dtype).reshape(1, 3) - means  # [N, 3]
    return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min(1e-12)


def sun_direction(sun_zenith_deg: float, sun_azimuth_deg: float, dtype=torch.float32) -> torch.Tensor:
    """ω_i [3]: unit vector toward the sun (ENU) from zenith/azimuth in degrees."""
    import math

    tz, az = math.radians(sun_zenith_deg), math.radians(sun_azimuth_deg)
    return torch.tensor(
        [math.sin(tz) * math.sin(az), math.sin(tz) * math.cos(az), math.cos(tz)], dtype=dtype
    )
