"""Training losses (paper eqs. 24-27) and geometry regularisers, all masked: invalid (NaN/Inf) target pixels never count.

Masking: invalid target pixels are replaced by the (detached) prediction so they give
zero L1/cosine error and do not disturb the SSIM windows; means are over valid pixels.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from brfgs.render.geometry import normals_from_depth
from brfgs.spectral import spectral_angle_torch


def fill_invalid(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """target [H,W,C] with invalid pixels (valid [H,W] False) set to pred.detach()."""
    return torch.where(valid[..., None], target, pred.detach())


def masked_l1(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor, filled: bool = False) -> torch.Tensor:
    """Mean |pred - target| over valid pixels and channels (eq. 26 when C = B); ``filled``: ``target``
    is already :func:`fill_invalid`'s."""
    n = valid.sum().clamp_min(1) * pred.shape[-1]
    t = target if filled else fill_invalid(pred, target, valid)
    return (pred - t).abs().sum() / n


def masked_cos(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor, eps: float = 1e-8,
               filled: bool = False) -> torch.Tensor:
    """Mean (1 - cosine similarity) of per-pixel spectra over valid pixels (eq. 27); ``filled``:
    ``target`` is already :func:`fill_invalid`'s."""
    t = target if filled else fill_invalid(pred, target, valid)
    cos = (pred * t).sum(-1) / (pred.norm(dim=-1) * t.norm(dim=-1)).clamp_min(eps)
    return ((1 - cos) * valid).sum() / valid.sum().clamp_min(1)


def _gauss_window(size: int = 11, sigma: float = 1.5, dtype=torch.float32) -> torch.Tensor:
    x = torch.arange(size, dtype=dtype) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def ssim_torch(x: torch.Tensor, y: torch.Tensor, data_range: float = 1.0, valid: torch.Tensor | None = None) -> torch.Tensor:
    """Differentiable mean SSIM of [H, W, C] images (11x11 Gaussian window, sigma 1.5, 'valid').

    With ``valid`` [H, W], only windows whose 11x11 support is entirely valid are averaged
    (invalid pixels then get no gradient at all).
    """
    c = x.shape[-1]
    g = _gauss_window(dtype=x.dtype)
    wx = g.view(1, 1, 1, -1).repeat(c, 1, 1, 1)
    wy = g.view(1, 1, -1, 1).repeat(c, 1, 1, 1)

    def filt(img):
        return F.conv2d(F.conv2d(img, wx, groups=c), wy, groups=c)

    X = x.permute(2, 0, 1)[None]
    Y = y.permute(2, 0, 1)[None]
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    mx, my = filt(X), filt(Y)
    sxx = filt(X * X) - mx * mx
    syy = filt(Y * Y) - my * my
    sxy = filt(X * Y) - mx * my
    m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    if valid is None or bool(valid.all()):
        return m.mean()
    inv = (~valid).to(x.dtype)[None, None]
    box = torch.ones(1, 1, 11, 11, dtype=x.dtype)
    ok = (F.conv2d(inv, box) < 0.5).expand_as(m)  # [1, C, H-10, W-10]
    if not ok.any():
        return m.sum() * 0 + 1.0
    return torch.where(ok, m, torch.zeros_like(m)).sum() / ok.sum()


def stage1_loss(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor, alpha: float,
                per_band: bool = False) -> torch.Tensor:
    """(1 - alpha) L1 + alpha D-SSIM (eq. 24) of [H, W, k] images; D-SSIM on the grayscale (band
    mean) images as the paper, or with ``per_band`` the mean D-SSIM of the k bands (3DGS's per-channel
    SSIM; not in the paper).

    D-SSIM = 1 - SSIM; each image compared (the grayscale one, or each band) is scaled by the
    target's valid maximum so SSIM's constants see a [0, 1] range.
    """
    t = fill_invalid(pred, target, valid)
    l1 = masked_l1(pred, t, valid, filled=True)
    if alpha <= 0 or min(pred.shape[0], pred.shape[1]) < 11:
        return l1
    gp, gt = (pred, t) if per_band else (pred.mean(-1, keepdim=True), t.mean(-1, keepdim=True))  # [H, W, k or 1]
    scale = gt.detach()[valid].amax(0).clamp_min(1e-6) if valid.any() else torch.ones(gt.shape[-1])  # [k or 1]
    dssim = 1 - ssim_torch(gp / scale, gt / scale, valid=valid)
    return (1 - alpha) * l1 + alpha * dssim


def stage2_loss(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor, beta: float) -> torch.Tensor:
    """(1 - beta) L_refl + beta L_cos (eqs. 25-27) over all bands."""
    t = fill_invalid(pred, target, valid)  # [H, W, B], once for both terms
    return (1 - beta) * masked_l1(pred, t, valid, filled=True) + beta * masked_cos(pred, t, valid, filled=True)


@torch.no_grad()
def masked_psnr(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> float:
    """PSNR (data range 1) over valid pixels, for progress bars."""
    if not valid.any():
        return float("nan")
    se = ((pred - target) ** 2).sum(-1)  # [...] summed over the channels: no boolean gather of the whole image
    mse = (se[valid].sum() / (valid.sum() * pred.shape[-1])).clamp_min(1e-12)
    return float(-10 * torch.log10(mse))


def depth_normal_loss(geo: torch.Tensor, alpha: torch.Tensor, K: torch.Tensor, min_alpha: float = 0.5) -> torch.Tensor:
    """Depth-normal consistency in 2DGS's per-Gaussian form: mean over pixels of
    Σ_k w_k (1 − n_k · n_d) = alpha − N · n_d, N the premultiplied blended normal (not renormalised,
    so each Gaussian's misalignment counts with its blending weight and a minority of tilted discs in
    a stack is not hidden) and n_d the normal of the rendered depth map (:func:`normals_from_depth`),
    detached: the prior turns the Gaussians toward the depth's normal but never moves the depth.

    Args:
        geo: [H, W, 4] rasterized (premultiplied) camera depth and normal of
            :func:`brfgs.model.features.camera_depth_normals`.
        alpha: [H, W] accumulated opacity; pixels below ``min_alpha`` do not count.
        K: [3, 3] intrinsics of the rendered window.
    Flat, textureless surfaces (water, roofs) get normals from their neighbours' depths.
    """
    a = alpha.clamp_min(1e-6)
    depth = geo[..., 0] / a
    nd, valid = normals_from_depth(depth.detach(), K)
    valid = valid & (alpha > min_alpha)
    if not bool(valid.any()):
        return geo.sum() * 0.0
    err = alpha - (geo[..., 1:4] * nd).sum(-1)  # [H, W] sum_k w_k (1 - n_k . n_d)
    w = valid.to(err.dtype)
    return (err * w).sum() / w.sum().clamp_min(1e-12)


def depth_smoothness_loss(depth_premult: torch.Tensor, alpha: torch.Tensor, target: torch.Tensor,
                          valid: torch.Tensor, edge_rel: float = 0.05, min_alpha: float = 0.5) -> torch.Tensor:
    """Edge-aware second-order smoothness of the rendered inverse depth (a planar prior for
    textureless regions): mean over pixel triples along x and y of
    w · |d⁻¹(p−1) − 2 d⁻¹(p) + d⁻¹(p+1)| / d⁻¹(p), w = exp(−max_c |ΔI_c| / (edge_rel · Ī_c)).

    Args:
        depth_premult: [H, W] rasterized (premultiplied) camera depth (m); depth = it / alpha.
        alpha: [H, W]; target: [H, W, C] the observed image; valid: [H, W] its valid pixels.
        edge_rel: target contrast (relative to the channel mean Ī_c over the window) at which the
            weight drops to 1/e.
    The inverse camera depth of a plane is affine in the pixel coordinates, so planes cost
    nothing; where the image has no texture (w ≈ 1) the depth cannot be told by the photometric
    loss and is interpolated from the textured rim instead.
    """
    ok = valid & (alpha > min_alpha)
    if not bool(ok.any()):
        return depth_premult.sum() * 0.0
    inv = alpha.clamp_min(1e-6) / depth_premult.clamp_min(1e-6)  # [H, W] 1/depth (1/m)
    t = torch.nan_to_num(target, nan=0.0, posinf=0.0, neginf=0.0)  # [H, W, C]
    scale = edge_rel * t[valid].abs().mean(0).clamp_min(1e-6)  # [C]
    total = depth_premult.sum() * 0.0
    count = 0
    for dim in (0, 1):
        n = inv.shape[dim]
        if n < 3:
            continue
        a_, b_, c_ = (inv.narrow(dim, k, n - 2) for k in range(3))
        ta, tb, tc = (t.narrow(dim, k, n - 2) for k in range(3))
        oa, ob, oc = (ok.narrow(dim, k, n - 2) for k in range(3))
        grad = torch.maximum((tb - ta).abs(), (tc - tb).abs()) / scale  # [.., .., C]
        w = torch.exp(-grad.max(-1).values)
        m = oa & ob & oc
        if bool(m.any()):
            total = total + (w * (a_ - 2 * b_ + c_).abs() / b_.detach().clamp_min(1e-9))[m].sum()
            count += int(m.sum())
    return total / max(count, 1)


def flatten_loss(log_scales: torch.Tensor) -> torch.Tensor:
    """Mean ratio of each Gaussian's smallest to largest scale (0 for a flat disc): makes the
    normal n_k (the smallest axis) well defined, as in GaussianShader / 2DGS surfels."""
    s = torch.exp(log_scales)  # [N, 3]
    return (s.min(-1).values / s.max(-1).values.clamp_min(1e-12)).mean()


def normal_smoothness_loss(normals: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """Mean of 1 − (n_i · n̄_i)² over Gaussians: n_i the unit shading normal [N, 3] (any length and
    sign), n̄_i the unit mean of its neighbours' normals (``neighbours`` [N, k] row indices; normals
    turned to the upper hemisphere first, the mean detached). Flat surfaces get coherent normals,
    so a specular lobe seen in one view can be extrapolated to the next.
    """
    n = normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-12)  # [N, 3]
    n = n * torch.where(n[:, 2:3] < 0, -1.0, 1.0)
    m = n.detach()[neighbours].mean(1)  # [N, 3]
    m = m / m.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return (1.0 - (n * m).sum(-1) ** 2).mean()


def spectral_tv_loss(r_p: torch.Tensor, r_q: torch.Tensor, i_p: torch.Tensor, i_q: torch.Tensor,
                     valid: torch.Tensor, scale: torch.Tensor | float, edge_rel: float = 0.05) -> torch.Tensor:
    """Edge-aware spectral-angle smoothness of rendered spectra: mean over neighbouring pixel
    pairs (p, q) of w · angle(r_p, r_q) (rad), w = exp(−|I_p − I_q| / (edge_rel · scale)).

    Args:
        r_p, r_q: [R, B] the pairs' rendered spectra; i_p, i_q: [R] their observed band-mean
            reflectance (the noise of one band averages out over all of them); valid: [R] pairs
            to score; scale: the view's mean observed reflectance.
    Brightness (texture, shading) costs nothing, only spectral shape: on a dark, uniform surface
    (water, shadow) the decoded spectra of neighbouring pixels cannot scatter with the noise
    each fits, and where the observed brightness jumps (a material edge) w ≈ 0.
    """
    if not bool(valid.any()):
        return r_p.sum() * 0.0
    wgt = torch.exp(-(i_p - i_q).abs() / (edge_rel * scale))  # [R]
    return (wgt * spectral_angle_torch(r_p, r_q))[valid].sum() / valid.sum()
