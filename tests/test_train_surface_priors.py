"""Surface priors of the geometry-training phases: ray-wise depth concentration and the
edge-aware second-order smoothness of the rendered inverse depth."""

import math

import numpy as np
import torch

from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.model.gaussians import init_from_points
from brfgs.model.camera import camera_from_c2w
from brfgs.model.features import camera_depth_normals
from brfgs.model.rendering import rasterize_features
from brfgs.train.losses import depth_smoothness_loss


def _layers(h=6, w=7, k=4, seed=0):
    """Random per-pixel layer depths [H, W, K] (m) and blending weights [H, W, K] (sum < 1)."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(80.0, 120.0, (h, w, k))
    wts = rng.uniform(0.0, 1.0, (h, w, k))
    wts *= rng.uniform(0.55, 0.99, (h, w, 1)) / wts.sum(-1, keepdims=True)
    return t, wts


def _concentration_reference(t, wts, min_alpha=0.5):
    """float64 numpy: mean over pixels with alpha > min_alpha of alpha · std_w(t) / mean_w(t)."""
    vals = []
    for i in range(t.shape[0]):
        for j in range(t.shape[1]):
            a = wts[i, j].sum()
            if a <= min_alpha:
                continue
            p = wts[i, j] / a
            m = float(np.sum(p * t[i, j]))
            sd = math.sqrt(float(np.sum(p * (t[i, j] - m) ** 2)))
            vals.append(a * sd / m)
    return float(np.mean(vals))


def _fd_grad(f, x: torch.Tensor, eps: float) -> torch.Tensor:
    """Central finite differences of the scalar f at x (float64)."""
    g = torch.zeros_like(x)
    flat, gflat = x.view(-1), g.view(-1)
    for k in range(flat.numel()):
        old = float(flat[k])
        flat[k] = old + eps
        fp = float(f(x))
        flat[k] = old - eps
        fm = float(f(x))
        flat[k] = old
        gflat[k] = (fp - fm) / (2 * eps)
    return g


def _plane_inverse_depth(h, w, seed=0):
    """Inverse camera depth of a tilted plane: affine in the pixel coordinates (1/m)."""
    rng = np.random.default_rng(seed)
    v, u = np.meshgrid(np.arange(h, dtype=float), np.arange(w, dtype=float), indexing="ij")
    a, b = rng.uniform(-2e-4, 2e-4, 2)
    return 0.01 + a * u + b * v


def _smoothness_reference(depth, alpha, target, edge_rel=0.05, min_alpha=0.5):
    """float64 loops over the pixel triples along x and y."""
    h, w, c = target.shape
    scale = edge_rel * np.abs(target.reshape(-1, c)).mean(0)
    ok = alpha > min_alpha
    inv = 1.0 / depth
    total, n = 0.0, 0
    for i in range(h):
        for j in range(w):
            for di, dj in ((1, 0), (0, 1)):
                i0, j0, i2, j2 = i - di, j - dj, i + di, j + dj
                if min(i0, j0) < 0 or i2 >= h or j2 >= w or not (ok[i0, j0] and ok[i, j] and ok[i2, j2]):
                    continue
                g = np.maximum(np.abs(target[i, j] - target[i0, j0]), np.abs(target[i2, j2] - target[i, j])) / scale
                wgt = math.exp(-g.max())
                total += wgt * abs(inv[i0, j0] - 2 * inv[i, j] + inv[i2, j2]) / inv[i, j]
                n += 1
    return total / max(n, 1)


def test_depth_smoothness_zero_on_planes_and_matches_a_loop_reference():
    h, w = 9, 11
    rng = np.random.default_rng(2)
    alpha = rng.uniform(0.6, 1.0, (h, w))
    depth = 1.0 / _plane_inverse_depth(h, w)
    flat = np.full((h, w, 3), 0.3)
    valid = torch.ones(h, w, dtype=torch.bool)
    prem = torch.as_tensor(alpha * depth)
    assert float(depth_smoothness_loss(prem, torch.as_tensor(alpha), torch.as_tensor(flat), valid)) < 1e-12
    # a bumpy surface under texture and low alpha here and there
    bumpy = depth + rng.normal(0.0, 0.5, (h, w))
    alpha[2, 3] = 0.3
    target = 0.3 + rng.normal(0.0, 0.01, (h, w, 3))
    got = float(depth_smoothness_loss(torch.as_tensor(alpha * bumpy), torch.as_tensor(alpha), torch.as_tensor(target), valid))
    ref = _smoothness_reference(bumpy, alpha, target)
    assert ref > 0 and math.isclose(got, ref, rel_tol=1e-9), (got, ref)
    # an image edge through the bump switches the prior off there
    edge = target.copy()
    edge[:, w // 2:] += 0.3
    bump = depth.copy()
    bump[:, w // 2:] += 5.0  # a 5 m step along the image edge (a wall, a roof)
    on_edge = float(depth_smoothness_loss(torch.as_tensor(alpha * bump), torch.as_tensor(alpha), torch.as_tensor(edge), valid))
    no_edge = float(depth_smoothness_loss(torch.as_tensor(alpha * bump), torch.as_tensor(alpha), torch.as_tensor(flat), valid))
    assert on_edge < 1e-3 * no_edge, (on_edge, no_edge)


def test_depth_smoothness_gradients_and_invalid_pixels():
    h, w = 5, 6
    rng = np.random.default_rng(3)
    alpha = torch.as_tensor(rng.uniform(0.6, 1.0, (h, w)))
    target = torch.as_tensor(0.3 + rng.normal(0.0, 0.01, (h, w, 2)))
    target[1, 1, 0] = float("nan")
    valid = torch.isfinite(target).all(-1)
    prem = alpha * torch.as_tensor(1.0 / _plane_inverse_depth(h, w) + rng.normal(0, 0.5, (h, w)))
    val = depth_smoothness_loss(prem, alpha, target, valid)
    assert torch.isfinite(val)
    # the loss divides by the detached centre inverse depth: its gradient is that of the same sum
    # with those divisors held at their current values
    inv0 = alpha / prem
    ok = valid & (alpha > 0.5)
    scale = 0.05 * torch.nan_to_num(target)[valid].abs().mean(0)

    def fixed_scale(d):
        inv = alpha / d
        t = torch.nan_to_num(target)
        total, n = 0.0, 0
        for dim in (0, 1):
            m = inv.shape[dim] - 2
            a_, b_, c_ = (inv.narrow(dim, k, m) for k in range(3))
            i0 = inv0.narrow(dim, 1, m)
            ta, tb, tc = (t.narrow(dim, k, m) for k in range(3))
            okk = ok.narrow(dim, 0, m) & ok.narrow(dim, 1, m) & ok.narrow(dim, 2, m)
            wgt = torch.exp(-(torch.maximum((tb - ta).abs(), (tc - tb).abs()) / scale).max(-1).values)
            total = total + (wgt * (a_ - 2 * b_ + c_).abs() / i0)[okk].sum()
            n += int(okk.sum())
        return total / n

    x = prem.clone().requires_grad_(True)
    depth_smoothness_loss(x, alpha, target, valid).backward()
    fd = _fd_grad(fixed_scale, prem.clone(), 1e-4)
    assert torch.allclose(x.grad, fd, rtol=1e-5, atol=1e-12), (x.grad - fd).abs().max()
    assert float(x.grad[1, 1]) != 0.0 or not bool(ok[1, 1])  # NaN target pixel: no NaN gradient
    assert bool(torch.isfinite(x.grad).all())


