"""Metrics against hand-computed values and an independent float64 SSIM."""

import math

import numpy as np
import pytest

from brfgs.evaluation import metrics as M


def test_psnr_hand_computed():
    a = np.zeros((4, 4, 3))
    b = np.full((4, 4, 3), 0.1)  # MSE = 0.01 -> 20 dB
    assert M.psnr(a, b) == pytest.approx(20.0, abs=1e-9)
    # mask out half the pixels, which carry a different error
    b2 = b.copy()
    b2[:2] = 0.5
    mask = np.zeros((4, 4), bool)
    mask[2:] = True
    assert M.psnr(a, b2, mask) == pytest.approx(20.0, abs=1e-9)
    # NaN pixels in the target are excluded
    b3 = b.copy()
    b3[0, 0, 1] = np.nan
    assert M.psnr(a, b3) == pytest.approx(20.0, abs=1e-9)
    assert M.psnr_spectral(a, b) == pytest.approx(20.0, abs=1e-9)


def test_sam_hand_computed():
    a = np.zeros((1, 2, 3))
    b = np.zeros((1, 2, 3))
    a[0, 0] = [1, 0, 0]
    b[0, 0] = [1, 1, 0]  # 45 degrees
    a[0, 1] = [0, 2, 0]
    b[0, 1] = [0, 5, 0]  # 0 degrees (scale invariant)
    assert M.sam(a, b) == pytest.approx(math.pi / 8, abs=1e-12)
    mask = np.array([[True, False]])
    assert M.sam(a, b, mask) == pytest.approx(math.pi / 4, abs=1e-12)


def _ssim_reference(x, y, data_range=1.0):
    """Independent float64 SSIM: explicit 2-D Gaussian window over every valid position."""
    k = 11
    ax = np.arange(k) - 5.0
    w = np.exp(-(ax[:, None] ** 2 + ax[None, :] ** 2) / (2 * 1.5**2))
    w /= w.sum()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    vals = []
    for c in range(x.shape[2]):
        for i in range(x.shape[0] - k + 1):
            for j in range(x.shape[1] - k + 1):
                px = x[i : i + k, j : j + k, c]
                py = y[i : i + k, j : j + k, c]
                mx, my = (w * px).sum(), (w * py).sum()
                vx = (w * (px - mx) ** 2).sum()
                vy = (w * (py - my) ** 2).sum()
                cxy = (w * (px - mx) * (py - my)).sum()
                vals.append(((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def test_ssim_matches_independent_reference():
    rng = np.random.default_rng(0)
    x = rng.random((20, 23, 3))
    y = np.clip(x + 0.1 * rng.standard_normal(x.shape), 0, 1)
    ref = _ssim_reference(x, y)
    assert M.ssim(x, y) == pytest.approx(ref, abs=1e-10)
    assert M.ssim(x, x) == pytest.approx(1.0, abs=1e-12)
    assert M.ssim(x, y) < 0.99


def test_ssim_mask_excludes_windows():
    rng = np.random.default_rng(1)
    x = rng.random((30, 30, 1))
    y = x.copy()
    y[:12] = rng.random((12, 30, 1))  # corrupt the top rows
    mask = np.ones((30, 30), bool)
    mask[:12] = False
    # only windows fully inside rows 12..29 count: those are identical
    assert M.ssim(x, y, mask) == pytest.approx(1.0, abs=1e-12)
    assert M.ssim(x, y) < 0.9


def test_lpips_null_with_reason_when_unavailable():
    ok, reason = M.lpips_available()
    v, why = M.lpips_metric(np.zeros((16, 16, 3)), np.zeros((16, 16, 3)))
    if not ok:
        assert v is None and why == reason and why


def test_image_metrics_and_mean():
    rng = np.random.default_rng(2)
    cube = rng.random((16, 16, 5)) + 0.1
    cir = cube[..., :3] / 2
    m = M.image_metrics(cube * 1.1, cube, cir, cir)
    assert m["psnr"] is None or m["psnr"] > 100  # identical CIR -> infinite PSNR -> null
    assert m["sam"] == pytest.approx(0.0, abs=1e-7)
    m2 = M.image_metrics(None, None, cir * 0.9, cir, spectral=False, spectral_reason="RGB model")
    assert m2["sam"] is None and m2["sam_reason"] == "RGB model"
    mean = M.mean_metrics([m2, m2])
    assert mean["psnr"] == pytest.approx(m2["psnr"])
    assert mean["sam"] is None and mean["sam_reason"] == "RGB model"
