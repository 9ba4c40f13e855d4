"""Training losses against the float64 evaluation metrics."""

import numpy as np
import pytest
import torch

from brfgs.analysis.metrics import sam, ssim
from brfgs.spectral.autoencoder import spectral_angle_torch
from brfgs.train.losses import masked_cos, masked_l1, masked_psnr, ssim_torch, stage2_loss


def test_ssim_torch_matches_metric():
    rng = np.random.default_rng(0)
    x = rng.random((30, 26, 2))
    y = np.clip(x + 0.2 * rng.standard_normal(x.shape), 0, 1)
    got = ssim_torch(torch.from_numpy(x), torch.from_numpy(y)).item()
    assert got == pytest.approx(ssim(x, y), abs=1e-10)
    valid = np.ones((30, 26), bool)
    valid[:8, :8] = False
    got = ssim_torch(torch.from_numpy(x), torch.from_numpy(y), valid=torch.from_numpy(valid)).item()
    assert got == pytest.approx(ssim(x, y, valid), abs=1e-10)


def test_l1_cos_psnr_hand_values():
    p = torch.zeros(2, 2, 3)
    t = torch.full((2, 2, 3), 0.1)
    v = torch.ones(2, 2, dtype=torch.bool)
    assert masked_l1(p, t, v).item() == pytest.approx(0.1)
    assert masked_psnr(p, t, v) == pytest.approx(20.0, abs=1e-4)
    a = torch.tensor([[[1.0, 0.0, 0.0]]])
    b = torch.tensor([[[1.0, 1.0, 0.0]]])
    one = torch.ones(1, 1, dtype=torch.bool)
    assert masked_cos(a, b, one).item() == pytest.approx(1 - np.sqrt(0.5), abs=1e-6)
    assert stage2_loss(a, b, one, 0.0).item() == pytest.approx(1 / 3, abs=1e-6)
    ang = spectral_angle_torch(a, b).item()
    assert ang == pytest.approx(sam(a.numpy(), b.numpy()), abs=1e-3)


def test_coverage_loss_is_the_uncovered_fraction():
    from brfgs.train.losses import coverage_loss
    alpha = torch.tensor([[1.0, 0.5], [0.0, 0.25]], requires_grad=True)
    valid = torch.tensor([[True, True], [False, True]])
    loss = coverage_loss(alpha, valid)
    assert float(loss) == pytest.approx((0.0 + 0.5 + 0.75) / 3)
    loss.backward()
    np.testing.assert_allclose(alpha.grad.numpy(), [[-1 / 3, -1 / 3], [0.0, -1 / 3]])
    assert float(coverage_loss(alpha, torch.zeros(2, 2, dtype=bool))) == 0.0
