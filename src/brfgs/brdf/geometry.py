"""Per-Gaussian geometry for the reflectance head: normals and view and sun directions.

Conventions (docs/data-format.md): ENU world frame; ω_o of Gaussian k is
``normalize(camera_centre − μ_k)``; the normal n_k is the axis of the Gaussian's smallest
scale, flipped to face ω_o (paper, after eq. 21). ``quat_to_rotmat`` lives in
:mod:`brfgs.render.geometry` and is re-exported here.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from brfgs.data.angles import direction_from_angles_deg
from brfgs.render.geometry import quat_to_rotmat

__all__ = ["quat_to_rotmat", "gaussian_normals", "shading_normals", "view_directions", "sun_direction"]


def gaussian_normals(
    quats: Tensor,  # [N, 4] (w, x, y, z), need not be normalised
    scales: Tensor,  # [N, 3] m (or log-scales: only their order matters)
    omega_o: Tensor,  # [N, 3] or [3] unit, toward the camera
) -> Tensor:  # [N, 3] unit, n·ω_o ≥ 0
    """Geometric normals n_k: the axis of each Gaussian's smallest scale, facing ω_o (after eq. 21).

    Gradients flow to ``quats`` (the choice of axis is piecewise constant in ``scales``).
    """
    rot = quat_to_rotmat(quats)  # [N, 3, 3]
    idx = torch.argmin(scales.detach(), dim=-1)  # [N]
    n = torch.gather(rot, 2, idx.view(-1, 1, 1).expand(-1, 3, 1)).squeeze(-1)  # [N, 3]
    side = (n * omega_o).sum(-1, keepdim=True)  # [N, 1]
    sign = torch.where(side < 0, -1.0, 1.0).to(n.dtype)
    return n * sign


def shading_normals(
    quats: Tensor,  # [N, 4] (w, x, y, z)
    scales: Tensor,  # [N, 3] m
    omega_o: Tensor,  # [N, 3] unit, toward the camera
    normals: Tensor | None = None,  # [N, 3] learned normals (any length, any sign) or None
) -> Tensor:  # [N, 3] unit, n·ω_o ≥ 0
    """Normals n_k used by the reflectance head (eqs 20–23), facing ω_o.

    ``normals``: the model's learned shading normals (stage 2, ``TrainConfig.learn_normals``),
    normalised here; None: the geometric normal, the smallest axis (:func:`gaussian_normals`).
    """
    if normals is None:
        return gaussian_normals(quats, scales, omega_o)
    n = normals / torch.linalg.vector_norm(normals, dim=-1, keepdim=True).clamp_min(1e-12)  # [N, 3]
    side = (n * omega_o).sum(-1, keepdim=True)  # [N, 1]
    return torch.where(side < 0, -n, n)


def view_directions(
    means: Tensor,  # [N, 3] m, ENU
    camera_centre: Tensor,  # [3] m, ENU
) -> Tensor:  # [N, 3] unit
    """ω_o: unit vectors from each Gaussian centre toward the camera centre (norm clamped at 1e-12)."""
    v = camera_centre.to(means.dtype).reshape(1, 3) - means  # [N, 3]
    return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min(1e-12)


def sun_direction(
    sun_zenith_deg: float,  # deg from +z
    sun_azimuth_deg: float,  # deg clockwise from north (+y)
    dtype: torch.dtype = torch.float32,
) -> Tensor:  # [3] unit, ENU, toward the sun
    """ω_i = (sin θ sin φ, sin θ cos φ, cos θ), computed in float64 by
    :func:`brfgs.data.angles.direction_from_angles_deg` and cast to ``dtype``."""
    return torch.as_tensor(np.asarray(direction_from_angles_deg(sun_zenith_deg, sun_azimuth_deg)), dtype=dtype)
