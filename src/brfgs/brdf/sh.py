"""Real spherical harmonics of degree 0–3 (the 3DGS view-dependence baseline, Table 3).

Same basis, ordering and signs as 3DGS / gsplat (``eval_sh``), but the sum is returned
as is (no +0.5 offset, no clamping): coefficients live in the spectral latent space of
the autoencoder, like the hybrid head's z terms.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["SH_C0", "num_sh_bases", "sh_basis", "eval_sh"]

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def num_sh_bases(degree: int) -> int:
    """Number of basis functions of degree 0..``degree``: (degree + 1)²."""
    return (degree + 1) ** 2


def sh_basis(
    degree: int,  # 0..3
    dirs: Tensor,  # [N, 3] unit directions
) -> Tensor:  # [N, (degree + 1)²]
    """Real SH basis values at ``dirs`` (3DGS/gsplat ordering and signs)."""
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    n = dirs.shape[0]
    cols = [torch.full((n,), SH_C0, dtype=dirs.dtype, device=dirs.device)]
    if degree > 0:
        x, y, z = dirs.unbind(-1)
        cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
        if degree > 1:
            xx, yy, zz = x * x, y * y, z * z
            xy, yz, xz = x * y, y * z, x * z
            cols += [
                SH_C2[0] * xy,
                SH_C2[1] * yz,
                SH_C2[2] * (2.0 * zz - xx - yy),
                SH_C2[3] * xz,
                SH_C2[4] * (xx - yy),
            ]
            if degree > 2:
                cols += [
                    SH_C3[0] * y * (3.0 * xx - yy),
                    SH_C3[1] * xy * z,
                    SH_C3[2] * y * (4.0 * zz - xx - yy),
                    SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                    SH_C3[4] * x * (4.0 * zz - xx - yy),
                    SH_C3[5] * z * (xx - yy),
                    SH_C3[6] * x * (xx - 3.0 * yy),
                ]
    return torch.stack(cols, -1)  # [N, K]


def eval_sh(
    degree: int,  # 0..3
    coeffs: Tensor,  # [N, ≥ (degree + 1)², d] latent SH coefficients (index 0 = DC)
    dirs: Tensor,  # [N, 3] unit (the head passes ω_o, Gaussian → camera); ignored for degree 0
) -> Tensor:  # [N, d]
    """Σ_k Y_k(dirs)·coeffs[:, k], the SH baseline of Table 3 in latent space (no offset, no clamp)."""
    k = num_sh_bases(degree)
    if coeffs.shape[-2] < k:
        raise ValueError(f"eval_sh: need {k} coefficients for degree {degree}, got {coeffs.shape[-2]}")
    if degree == 0:
        return SH_C0 * coeffs[:, 0]
    basis = sh_basis(degree, dirs)  # [N, K]
    return torch.matmul(basis.unsqueeze(-2), coeffs[:, :k]).squeeze(-2)  # [N, d]
