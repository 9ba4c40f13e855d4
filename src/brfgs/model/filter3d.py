"""Mip-Splatting's 3D smoothing filter (Yu et al. 2024, sec. 4.1, eqs. 7-8).

A Gaussian should not be sharper than the finest sampling any training view gave it: each one
is convolved with an isotropic Gaussian whose standard deviation is sqrt(s) times the footprint
of one pixel at its depth in the training view that sees it closest,

    σ²_k = s · (d_k / f)²,  d_k = min over training views whose frustum holds μ_k of its depth,

so Σ'_k = Σ_k + σ²_k I (each standard deviation s_i → sqrt(s_i² + σ²_k)) and the opacity is
compensated, α'_k = α_k · sqrt(det Σ_k / det Σ'_k), so that the Gaussian's integral is kept.
Gaussians that no training view holds get the largest σ_k of those that are held (as the
paper's code does). The 2D mip filter (``--antialias``) is the other half of Mip-Splatting
(:func:`brfgs.render.rasterize.antialias_opacities`).

Training keeps σ²_k beside the Gaussians (:attr:`brfgs.model.GaussianModel.filter_var`,
recomputed after each densification) and renders the filtered Gaussians; at the end of the
geometry phase the filter is baked into the scales and opacities (:func:`bake_filter`), so the
saved model renders the same without knowing about it.
"""

from __future__ import annotations

import torch
from torch import Tensor

from brfgs.model.camera import Camera
from brfgs.render.geometry import project_pinhole

FRUSTUM_MARGIN = 0.15  # the paper's code: a mean within 1.15x the image (around its centre) counts as seen
FILTER_S = 0.2  # s: the filter's variance in squared pixels (the paper's 0.2)


@torch.no_grad()
def filter_variance_m2(
    means: Tensor,  # [N, 3] m
    cams: list[Camera],  # the training views
    s: float = FILTER_S,
) -> Tensor:  # [N] m², σ²_k
    """σ²_k = s · (d_k / f)² of eq. 7 (d_k: the smallest depth of μ_k in a training view whose
    frustum, grown by 15 %, holds it; f: that view's focal length in px)."""
    best = torch.full((means.shape[0],), float("inf"), dtype=torch.float64)  # [N] m per px
    for cam in cams:
        uv, z = project_pinhole(means.double(), cam.viewmat.double(), cam.K.double())  # [N, 2], [N]
        w, h = cam.width, cam.height
        mu, mv = FRUSTUM_MARGIN * w / 2, FRUSTUM_MARGIN * h / 2
        inside = (z > 0.01) & (uv[:, 0] >= -mu) & (uv[:, 0] <= w + mu) & (uv[:, 1] >= -mv) & (uv[:, 1] <= h + mv)
        px_m = z / float(cam.K[0, 0])  # [N] m: one pixel's footprint at the mean's depth
        best = torch.where(inside, torch.minimum(best, px_m), best)
    seen = torch.isfinite(best)
    if not bool(seen.any()):
        return torch.zeros(means.shape[0], dtype=means.dtype)
    best = torch.where(seen, best, best[seen].max())
    return (s * best**2).to(means.dtype)


def filtered_scales(
    scales: Tensor,  # [N, 3] m, standard deviations
    var_m2: Tensor,  # [N] m², σ²_k
) -> Tensor:  # [N, 3] m
    """Standard deviations of Σ' = Σ + σ² I (eq. 8)."""
    return torch.sqrt(scales * scales + var_m2[:, None])


def opacity_factor(
    scales: Tensor,  # [N, 3] m, standard deviations
    var_m2: Tensor,  # [N] m², σ²_k
) -> Tensor:  # [N] in (0, 1]
    """sqrt(det Σ / det Σ') (eq. 8): what the filter multiplies each opacity by."""
    s2 = scales * scales  # [N, 3]
    return torch.sqrt((s2 / (s2 + var_m2[:, None])).prod(-1))


def filtered_scales_opacities(
    scales: Tensor,  # [N, 3] m, standard deviations
    opacities: Tensor,  # [N] in (0, 1)
    var_m2: Tensor,  # [N] m², σ²_k
) -> tuple[Tensor, Tensor]:  # scales [N, 3] m, opacities [N]
    """Σ' = Σ + σ² I and α' = α · sqrt(det Σ / det Σ') (eq. 8), with gradients to both inputs."""
    return filtered_scales(scales, var_m2), opacities * opacity_factor(scales, var_m2)


@torch.no_grad()
def bake_filter(params: dict[str, Tensor], var_m2: Tensor) -> None:
    """Write the filtered Gaussians into ``params`` (log_scales, opacity_logits), in place: the
    model then renders the same without the filter."""
    s, o = filtered_scales_opacities(torch.exp(params["log_scales"]), torch.sigmoid(params["opacity_logits"]), var_m2)
    params["log_scales"].copy_(torch.log(s))
    params["opacity_logits"].copy_(torch.logit(o, eps=1e-7))
