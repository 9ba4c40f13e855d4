"""Mip-Splatting's 2D filter (``antialias_opacities`` before ``rasterize``; what the option
``antialias`` does in training and rendering): the compensation factor against
a float64 numpy reference, its gradients, the backends against each other, and the limit cases
that define it (a Gaussian's integrated opacity survives the 0.3 px² low-pass)."""

from __future__ import annotations

import math

import numpy as np
import torch

from brfgs.render import rasterize
from brfgs.render.rasterize import antialias_opacities
from brfgs.render.scenes import random_scene


def _numpy_compensation(means, quats, scales, viewmat, K):
    """sqrt(det Σ2D / det(Σ2D + 0.3 I)) with Σ2D = J W R S² Rᵀ Wᵀ Jᵀ, all float64 numpy; the Jacobian
    at x/z, y/z clamped to 1.3× the half field of view (3DGS/gsplat)."""
    out = []
    W = viewmat[:3, :3]
    width, height = 2 * K[0, 2], 2 * K[1, 2]
    for m, q, s in zip(means, quats, scales):
        p = W @ m + viewmat[:3, 3]
        p = np.array([p[2] * np.clip(p[0] / p[2], -1.3 * K[0, 2] / K[0, 0], 1.3 * (width - K[0, 2]) / K[0, 0]),
                      p[2] * np.clip(p[1] / p[2], -1.3 * K[1, 2] / K[1, 1], 1.3 * (height - K[1, 2]) / K[1, 1]), p[2]])
        w, x, y, z = q / np.linalg.norm(q)
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        J = np.array([[K[0, 0] / p[2], 0, -K[0, 0] * p[0] / p[2] ** 2],
                      [0, K[1, 1] / p[2], -K[1, 1] * p[1] / p[2] ** 2]])
        cov = J @ W @ R @ np.diag(s ** 2) @ R.T @ W.T @ J.T
        out.append(math.sqrt(np.linalg.det(cov) / np.linalg.det(cov + 0.3 * np.eye(2))))
    return np.array(out)


def _scene(n=60, seed=0):
    sc = random_scene(n, 48, 40, 3, seed=seed, behind_fraction=0.0, offscreen=0.0)
    return {k: (v.double() if torch.is_tensor(v) and v.is_floating_point() else v) for k, v in sc.items()}


def test_compensation_matches_numpy_reference():
    sc = _scene()
    got = antialias_opacities(sc["means"], sc["quats"], sc["scales"], torch.ones(60, dtype=torch.float64),
                              sc["viewmat"], sc["K"], 48, 40)
    ref = _numpy_compensation(sc["means"].numpy(), sc["quats"].numpy(), sc["scales"].numpy(), sc["viewmat"].numpy(),
                              sc["K"].numpy())
    assert np.abs(got.numpy() - ref).max() < 1e-10
    assert (ref < 1).all() and (ref > 0).all() and ref.min() < 0.9  # some are sub-pixel in this scene


def test_compensation_gradients():
    sc = _scene(12, seed=3)
    args = [sc[k].clone().requires_grad_(True) for k in ("means", "quats", "scales", "opacities")]
    assert torch.autograd.gradcheck(lambda *a: antialias_opacities(*a, sc["viewmat"], sc["K"], 48, 40), args)


def test_cpu_matches_torch_when_antialiased():
    sc = random_scene(300, 40, 30, 4, seed=11, behind_fraction=0.1, offscreen=0.2)
    outs = {}
    for be in ("torch", "cpu"):
        p = {k: sc[k].clone().requires_grad_(True) for k in ("means", "quats", "scales", "opacities", "features")}
        op = antialias_opacities(p["means"], p["quats"], p["scales"], p["opacities"], sc["viewmat"], sc["K"], 40, 30)
        o = rasterize(p["means"], p["quats"], p["scales"], op, p["features"], sc["viewmat"], sc["K"], 40, 30,
                      backend=be)
        w = torch.linspace(-1, 1, o.image.numel()).reshape(o.image.shape).to(o.image.dtype)
        ((o.image * w).sum() + o.alpha.sum()).backward()
        outs[be] = (o, {k: v.grad for k, v in p.items()})
    (ot, gt), (oc, gc) = outs["torch"], outs["cpu"]
    assert (oc.image - ot.image).abs().max() < 1e-4 * ot.image.abs().max()
    for k in gt:
        assert gt[k].abs().max() > 0, k
        assert (gc[k] - gt[k]).abs().max() < 1e-4 * gt[k].abs().max(), k


def _one_gaussian_alpha_sum(sigma_px: float, antialiased: bool, opacity=0.5) -> tuple[float, float]:
    """Sum of alpha over the image of one isotropic Gaussian of std ``sigma_px`` pixels facing the
    camera at 10 m, and what it should be: the splat's peak A = o' (o' = o, or o·σ²/(σ² + 0.3) with
    the filter), variance v = σ² + 0.3 px², and pairs below α = 1/255 skipped, so
    Σα ≈ ∫_{A·g ≥ 1/255} A·g = 2π·v·(A − 1/255)."""
    f, d, W = 100.0, 10.0, 64
    s_m = sigma_px * d / f
    K = torch.tensor([[f, 0, W / 2], [0, f, W / 2], [0, 0, 1]], dtype=torch.float64)
    view = torch.eye(4, dtype=torch.float64)
    means = torch.tensor([[0.013, -0.021, d]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64)
    scales = torch.full((1, 3), s_m, dtype=torch.float64)
    op = torch.tensor([opacity], dtype=torch.float64)
    if antialiased:
        op = antialias_opacities(means, quats, scales, op, view, K, W, W)
    out = rasterize(means, quats, scales, op, torch.ones(1, 1, dtype=torch.float64), view, K, W, W, backend="cpu")
    v = sigma_px ** 2 + 0.3
    peak = opacity * sigma_px ** 2 / v if antialiased else opacity
    return out.alpha.sum().item(), 2 * math.pi * v * (peak - 1 / 255)


def test_integrated_opacity_survives_the_low_pass():
    """With the filter, a sub-pixel Gaussian's splat integrates to about o·2π·det(Σ2D)^½ (the
    low-pass only spreads it); without it, to o·2π·det(Σ2D + 0.3 I)^½, several times more. For a
    large Gaussian the two agree."""
    for sigma in (0.15, 0.3):
        with_aa, expected_aa = _one_gaussian_alpha_sum(sigma, True)
        without, expected = _one_gaussian_alpha_sum(sigma, False)
        assert abs(with_aa / expected_aa - 1) < 0.03, (sigma, with_aa, expected_aa)
        assert abs(without / expected - 1) < 0.03, (sigma, without, expected)
        assert without / with_aa > 1.9
        no_lowpass = 0.5 * 2 * math.pi * sigma ** 2  # o·2π·σ²: the integral the filter preserves
        assert abs((with_aa + 2 * math.pi * (sigma ** 2 + 0.3) / 255) / no_lowpass - 1) < 0.03
    big_aa, _ = _one_gaussian_alpha_sum(6.0, True)
    big, _ = _one_gaussian_alpha_sum(6.0, False)
    assert abs(big / big_aa - 1) < 0.02
