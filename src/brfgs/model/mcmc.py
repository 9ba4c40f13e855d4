"""Densification as Markov-chain Monte Carlo (Kheradmand et al. 2024, "3D Gaussian Splatting as
Markov Chain Monte Carlo"; gsplat's ``MCMCStrategy`` as the idea).

Instead of cloning by screen-space gradient, splitting, pruning and resetting opacities (3DGS
adaptive density control, :mod:`brfgs.model.densify`), the Gaussians are samples of the scene's
opacity distribution:

- **relocation** — "dead" Gaussians (opacity <= ``min_opacity``) are moved onto live ones drawn
  with probability ∝ opacity; a Gaussian that ends up with N copies (itself included) gets opacity
  o' and scales s' such that the N copies composite like the original (paper eq. 9,
  :func:`relocation_opacity_scale`);
- **growth** — a fixed fraction more Gaussians each refinement, drawn the same way, up to a cap;
- **noise** — every step the means of nearly transparent Gaussians take a random step shaped by
  their own covariance (the SGLD exploration term, :func:`perturb_means`);
- **regularisers** — L1 of the opacities and the scales (:func:`mcmc_regulariser`), so that
  Gaussians that do not earn their place die and are relocated.
The optimiser moments of every row that was moved or re-weighted restart at zero.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import Tensor

from brfgs.model.gaussians import GaussianModel
from brfgs.model.optim import NamedAdam
from brfgs.render.geometry import quat_to_rotmat

MAX_COPIES = 51  # a Gaussian drawn more often than this keeps the weights of 51 copies (as gsplat)


@lru_cache(maxsize=1)
def _binomial_table(n: int) -> Tensor:  # [n, n] float64, C(i, k) (built once; callers must not write to it)
    return torch.tensor([[math.comb(i, k) for k in range(n)] for i in range(n)], dtype=torch.float64)


def relocation_opacity_scale(opacity: Tensor, scales: Tensor, copies: Tensor) -> tuple[Tensor, Tensor]:
    """Opacity [M] and scales [M, 3] of each of N = ``copies`` [M] (>= 1) copies of a Gaussian
    (paper eq. 9): o' = 1 − (1 − o)^(1/N) and s' = o s / Σ_{i=1}^{N} Σ_{k=0}^{i−1} C(i−1, k) (−1)^k
    o'^(k+1) / sqrt(k+1), so that the N copies, alpha-composited, integrate to the original's
    opacity profile along each axis. N = 1 leaves both unchanged."""
    n = copies.clamp(1, MAX_COPIES).to(torch.long)  # [M]
    o = opacity.to(torch.float64).clamp(1e-12, 1 - 1e-12)
    o_new = 1.0 - (1.0 - o) ** (1.0 / n.to(torch.float64))  # [M]
    table = _binomial_table(MAX_COPIES)  # [i, k]
    k = torch.arange(MAX_COPIES, dtype=torch.float64)  # [K]
    sign = torch.where(k % 2 == 0, 1.0, -1.0).to(torch.float64)
    # term[m, i, k] = C(i, k) (-1)^k o'^(k+1) / sqrt(k+1) for i < N_m (i = index i-1 of the formula), k <= i
    powers = o_new[:, None] ** (k[None] + 1) / torch.sqrt(k + 1)[None]  # [M, K]
    inner = (table[None] * sign[None, None] * powers[:, None, :]).sum(-1)  # [M, I]
    used = torch.arange(MAX_COPIES)[None] < n[:, None]  # [M, I]
    denom = (inner * used).sum(-1)  # [M]
    s_new = scales.to(torch.float64) * (o / denom)[:, None]
    return o_new.to(opacity.dtype), s_new.to(scales.dtype)


def _reset_moments(opt: NamedAdam, model: GaussianModel, rows: Tensor) -> None:
    """Zero the Adam moments of ``rows`` of every per-Gaussian tensor."""
    n = model.n

    def fix(name, mom):
        if name in model.params and mom.shape[0] == n:
            mom = mom.clone()
            mom[rows] = 0
        return mom

    opt.edit_rows(fix)


def _reweight(model: GaussianModel, sources: Tensor, copies: Tensor) -> None:
    """Give each row of ``sources`` [M] (unique) the opacity and scales of one of ``copies`` [M]."""
    p = model.params
    o_new, s_new = relocation_opacity_scale(torch.sigmoid(p["opacity_logits"][sources]),
                                            torch.exp(p["log_scales"][sources]), copies)
    o_new = o_new.clamp(1e-6, 1 - 1e-6)
    p["opacity_logits"].data[sources] = torch.log(o_new / (1 - o_new))
    p["log_scales"].data[sources] = torch.log(s_new.clamp_min(1e-12))


def _draw(model: GaussianModel, candidates: Tensor, n: int, gen: torch.Generator) -> tuple[Tensor, Tensor]:
    """``n`` draws from ``candidates`` ∝ opacity, with replacement: (drawn rows [n], and for the
    unique drawn rows [M] their number of copies after the move, draws + 1)."""
    w = torch.sigmoid(model.params["opacity_logits"].detach()[candidates]).double()
    drawn = candidates[torch.multinomial(w, n, replacement=True, generator=gen)]
    uniq, counts = torch.unique(drawn, return_counts=True)
    return drawn, (uniq, counts + 1)


@torch.no_grad()
def relocate_dead(model: GaussianModel, opt: NamedAdam, min_opacity: float, gen: torch.Generator) -> int:
    """Move every Gaussian with opacity <= ``min_opacity`` onto a live one (drawn ∝ opacity);
    returns how many moved."""
    opa = model.opacities.detach()
    dead = torch.nonzero(opa <= min_opacity).squeeze(1)
    alive = torch.nonzero(opa > min_opacity).squeeze(1)
    if dead.numel() == 0 or alive.numel() == 0:
        return 0
    drawn, (uniq, copies) = _draw(model, alive, dead.numel(), gen)
    _reweight(model, uniq, copies)
    for v in model.params.values():
        v.data[dead] = v.data[drawn]
    _reset_moments(opt, model, torch.cat([uniq, dead]))
    return int(dead.numel())


@torch.no_grad()
def add_gaussians(model: GaussianModel, opt: NamedAdam, n_new: int, gen: torch.Generator) -> int:
    """Append ``n_new`` copies of Gaussians drawn ∝ opacity (the drawn ones re-weighted so that
    source and copies composite like the source); returns how many were added."""
    if n_new <= 0:
        return 0
    n = model.n
    drawn, (uniq, copies) = _draw(model, torch.arange(n), n_new, gen)
    _reweight(model, uniq, copies)
    model.replace({k: torch.cat([v.detach(), v.detach()[drawn]], 0) for k, v in model.params.items()})

    def grow(name, mom):
        if name in model.params and mom.shape[0] == n:
            mom = torch.cat([mom, torch.zeros((n_new, *mom.shape[1:]), dtype=mom.dtype)], 0)
            mom[uniq] = 0
        return mom

    opt.edit_rows(grow)
    return n_new


@torch.no_grad()
def perturb_means(model: GaussianModel, lr_means_m: float, extent_m: float, noise_lr: float, gen: torch.Generator,
                  sharpness: float = 100.0, threshold: float = 0.995) -> None:
    """The exploration noise (paper eq. 7): means += lr · noise_lr · σ(sharpness ((1 − o) − threshold)) Σ ε,
    ε ~ N(0, I), in units of the scene extent.

    ``lr_means_m``: this step's learning rate of the means (m); Σ [N, 3, 3] each Gaussian's covariance;
    lengths are divided by ``extent_m`` first (the paper's scenes are normalised to about unit size),
    so the step in metres is lr · noise_lr · Σ / extent². The gate σ(·) leaves Gaussians with an
    opacity above ~0.05 in place.
    """
    p = model.params
    scales = torch.exp(p["log_scales"].detach())  # [N, 3] m
    rot = quat_to_rotmat(p["quats"].detach())  # [N, 3, 3]
    cov = rot @ torch.diag_embed(scales**2) @ rot.transpose(1, 2)  # [N, 3, 3] m²
    gate = torch.sigmoid(sharpness * ((1 - torch.sigmoid(p["opacity_logits"].detach())) - threshold))  # [N]
    eps = torch.randn(model.n, 3, generator=gen)
    step = lr_means_m * noise_lr / extent_m**2
    p["means"].data += step * gate[:, None] * torch.einsum("nij,nj->ni", cov, eps)


def mcmc_regulariser(model: GaussianModel, opacity_weight: float, scale_weight: float, extent_m: float) -> Tensor:
    """λ_o mean(o) + λ_s mean(s) / extent (paper eq. 8, scales in units of the scene extent): the L1
    pulls that make unneeded Gaussians die."""
    s = torch.exp(model.params["log_scales"])
    return opacity_weight * torch.sigmoid(model.params["opacity_logits"]).mean() + scale_weight * s.mean() / extent_m
