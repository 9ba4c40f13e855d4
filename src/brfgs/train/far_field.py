"""The far field: Gaussians beyond the area of interest, which few training views see.

Oblique views (58° in AIR-BRF) see the terrain beyond the area the flight was planned over.
Each such point is seen by a handful of views from one side, so its depth is barely
constrained: densification fills the rays with floaters that reproduce those views and float in
front of the ground from any other. With the option ``far_field_plane`` the Gaussians that less
than :data:`FAR_FRACTION` of the training views can see are marked at initialisation (children
inherit the mark) and kept on the ground surface: after every geometry step their height is reset
to the ground height under them (the 2.5-D surface through the sparse points, as the surface
fill uses). Their xy position, shape, opacity and colour train as usual.

Per-Gaussian tensors (rows like every other, never optimised): ``far`` [N] (1 = far field) and
``far_ground_z`` [N] (m).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
from torch import Tensor

from brfgs.model.camera import Camera
from brfgs.model.gaussians import GaussianModel
from brfgs.render.geometry import project_pinhole

FAR_FRACTION = 0.3  # seen by fewer than this fraction of the training views -> far field
FAR_KEYS = ("far", "far_ground_z")


def visibility_fraction(
    means: Tensor,  # [N, 3] m
    cams: list[Camera],
) -> Tensor:  # [N] in [0, 1]
    """Fraction of ``cams`` whose image contains each centre (in front of the camera; no occlusion test)."""
    seen = torch.zeros(means.shape[0])
    for cam in cams:
        uv, z = project_pinhole(means, cam.viewmat.to(means.dtype), cam.K.to(means.dtype))  # [N, 2], [N]
        seen += ((z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < cam.width)
                 & (uv[:, 1] < cam.height)).float()
    return seen / max(len(cams), 1)


def ground_height(
    points: np.ndarray,  # [P, 3] m, sparse points
    xy: np.ndarray,  # [M, 2] m
) -> np.ndarray:  # [M] m
    """Height of the 2.5-D surface through ``points`` at ``xy``: linear over their Delaunay
    triangulation, the nearest point's height outside it."""
    p = np.asarray(points, np.float64)
    q = np.asarray(xy, np.float64)
    if p.shape[0] == 0:
        return np.zeros(q.shape[0])
    z = np.full(q.shape[0], np.nan)
    if p.shape[0] >= 4:
        try:
            z = LinearNDInterpolator(p[:, :2], p[:, 2])(q)
        except Exception:  # degenerate (collinear) points: nearest only  # noqa: BLE001
            z = np.full(q.shape[0], np.nan)
    out = ~np.isfinite(z)
    if out.any():
        z[out] = NearestNDInterpolator(p[:, :2], p[:, 2])(q[out])
    return z


@torch.no_grad()
def mark_far_field(gm: GaussianModel, cams: list[Camera], points: np.ndarray, fraction: float = FAR_FRACTION) -> int:
    """Add ``far`` and ``far_ground_z`` to ``gm`` (see the module docstring); returns how many are far."""
    means = gm.means.detach()
    far = visibility_fraction(means, cams) < fraction  # [N]
    gz = torch.as_tensor(ground_height(points, means[:, :2].double().numpy()), dtype=means.dtype)
    gm.params["far"] = far.to(means.dtype)
    gm.params["far_ground_z"] = torch.where(far, gz, means[:, 2])
    project_far_field(gm)
    return int(far.sum())


@torch.no_grad()
def project_far_field(gm: GaussianModel) -> None:
    """Reset the height of the far-field Gaussians to the ground under them (no-op without marks)."""
    if "far" not in gm:
        return
    far = gm["far"] > 0.5  # [N]
    if bool(far.any()):
        gm.params["means"].data[far, 2] = gm["far_ground_z"][far]
