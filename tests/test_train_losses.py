"""Training losses against the float64 evaluation metrics."""

import math

import numpy as np
import pytest
import torch

from brfgs.evaluation.metrics import sam, ssim
from brfgs.spectral.autoencoder import spectral_angle_torch
from brfgs.train.losses import masked_cos, masked_l1, masked_psnr, ssim_torch, stage1_loss, stage2_loss


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


def test_stage1_loss_dssim_grayscale_and_per_band():
    """Eq. 24: (1 − α) L1 + α (1 − SSIM), SSIM on the band-mean image (paper) or the mean over bands,
    each image scaled by the target's valid maximum; checked against the float64 metric."""
    rng = np.random.default_rng(1)
    x = rng.random((24, 22, 3)) * np.array([0.05, 0.2, 0.5])  # dark, mid and bright bands
    y = np.clip(x + 0.02 * rng.standard_normal(x.shape), 0, None)
    valid = np.ones((24, 22), bool)
    valid[:6, :6] = False
    l1 = np.abs(x - y)[valid].mean()
    gx, gy = x.mean(-1, keepdims=True), y.mean(-1, keepdims=True)
    gray = 0.8 * l1 + 0.2 * (1 - ssim(gx / gy[valid].max(), gy / gy[valid].max(), valid))
    mx = y[valid].max(0)
    per_band = 0.8 * l1 + 0.2 * (1 - np.mean([ssim(x[..., [b]] / mx[b], y[..., [b]] / mx[b], valid) for b in range(3)]))
    args = (torch.from_numpy(x), torch.from_numpy(y), torch.from_numpy(valid), 0.2)
    assert stage1_loss(*args).item() == pytest.approx(gray, abs=1e-10)
    assert stage1_loss(*args, per_band=True).item() == pytest.approx(per_band, abs=1e-10)
    assert abs(per_band - gray) > 1e-3  # the dark band's structure counts in the per-band form


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


def test_spectral_tv_loss_against_numpy_brightness_free_and_edges():
    from brfgs.train.losses import spectral_tv_loss

    rng = np.random.default_rng(2)
    n, b = 50, 30
    rp, rq = rng.random((n, b)) + 0.05, rng.random((n, b)) + 0.05
    ip, iq = rng.random(n) * 0.3, rng.random(n) * 0.3
    valid = rng.random(n) > 0.2
    scale = 0.2
    # float64 numpy reference: mean over the valid pairs of exp(-|I_p - I_q| / (0.05 scale)) * angle
    ang = np.arccos(np.clip((rp * rq).sum(-1) / np.linalg.norm(rp, axis=-1) / np.linalg.norm(rq, axis=-1), -1, 1))
    ref = (np.exp(-np.abs(ip - iq) / (0.05 * scale)) * ang)[valid].mean()
    t = [torch.from_numpy(a) for a in (rp, rq, ip, iq)]
    got = spectral_tv_loss(*t, torch.from_numpy(valid), scale)
    assert got.item() == pytest.approx(ref, rel=1e-9)
    # brightness is free: a neighbour that is a scaled copy costs nothing (up to acos's clamp)
    same = spectral_tv_loss(t[0], 3.7 * t[0], t[2], t[2], torch.ones(n, dtype=torch.bool), scale)
    assert same.item() <= math.acos(1 - 1e-6) + 1e-9
    # an edge in the observed brightness switches it off; none valid gives 0 with a gradient path
    edge = spectral_tv_loss(t[0], t[1], torch.zeros(n, dtype=torch.float64), torch.ones(n, dtype=torch.float64),
                            torch.ones(n, dtype=torch.bool), scale)
    assert edge.item() < 1e-30
    assert spectral_tv_loss(t[0], t[1], t[2], t[3], torch.zeros(n, dtype=torch.bool), scale).item() == 0.0


def test_spectral_tv_gradient_and_denoising_of_a_dark_uniform_surface():
    """Per-pixel spectra of a dark, uniform surface fitted (L1) to noisy observations scatter with
    the noise; the spectral TV pulls their shapes together and toward the truth, and its gradient
    matches finite differences."""
    from brfgs.train.losses import masked_l1
    from brfgs.train.step import _spectral_tv

    g = torch.Generator().manual_seed(0)
    h, w, b = 12, 12, 40
    truth = (0.01 + 0.02 * torch.linspace(0, 1, b, dtype=torch.float64) ** 2).expand(h, w, b)  # [H, W, B] dark
    obs = truth + 0.004 * torch.randn(h, w, b, generator=g, dtype=torch.float64)
    everywhere = torch.ones(h, w, dtype=torch.bool)

    def tv(img):  # every pixel against its right and lower neighbours, as stage 2 scores a whole image
        flat = img.reshape(-1, b)
        return _spectral_tv(lambda q: flat[q], obs, everywhere, torch.arange(h * w), flat)

    x = obs.clone().requires_grad_(True)
    tv(x).backward()
    k = (3, 4, 7)
    e = torch.zeros_like(obs)
    e[k] = 1e-7
    fd = (tv(obs + e) - tv(obs - e)) / 2e-7
    assert x.grad[k].item() == pytest.approx(fd.item(), rel=1e-4)

    def fit(lam):
        x = obs.clone().requires_grad_(True)
        opt = torch.optim.Adam([x], lr=5e-4)
        for _ in range(300):
            loss = masked_l1(x, obs, everywhere) + lam * tv(x)
            opt.zero_grad()
            loss.backward()
            opt.step()
        c = (x * truth).sum(-1) / (x.norm(dim=-1) * truth.norm(dim=-1))
        return torch.acos(c.clamp(-1, 1)).mean().item()

    plain, smooth = fit(0.0), fit(0.1)
    assert smooth < 0.3 * plain, (plain, smooth)  # 0.022 against 0.217 rad


def test_spectral_tv_of_a_whole_image_matches_the_gathered_pairs():
    """Stage 2 scores every pixel's spectral TV with shifted slices of the image
    (train.step._spectral_tv_image); the loss and its gradient are those of the reference that
    gathers each pixel's right and lower neighbour by index (train.step._spectral_tv over all
    pixels), with invalid pixels, a NaN target and an edge in the scene."""
    from brfgs.train.step import _spectral_tv, _spectral_tv_image

    g = torch.Generator().manual_seed(3)
    h, w, b = 10, 13, 17
    obs = 0.05 + 0.3 * torch.rand(h, w, b, generator=g, dtype=torch.float64)  # [H, W, B]
    obs[:, 7:] *= 3.0  # a brightness edge: its pairs weigh ~0
    valid = torch.rand(h, w, generator=g) > 0.15
    obs[~valid] = float("nan")
    img = obs.nan_to_num(0.2) + 0.02 * torch.randn(h, w, b, generator=g, dtype=torch.float64)

    def reference(x):
        flat = x.reshape(-1, b)
        return _spectral_tv(lambda q: flat[q], obs, valid, torch.arange(h * w), flat)

    out = []
    for fn in (reference, lambda x: _spectral_tv_image(x, obs, valid)):
        x = img.clone().requires_grad_(True)
        val = fn(x)
        val.backward()
        out.append((val.detach(), x.grad))
    assert out[0][0].item() > 0
    assert torch.allclose(out[0][0], out[1][0], rtol=1e-12, atol=0)
    assert torch.allclose(out[0][1], out[1][1], rtol=1e-10, atol=1e-18)
    assert out[1][1].abs().sum() > 0


def test_decode_once_matches_decoding_each_request_apart():
    """Stage 2's ray path decodes the scored pixels and their TV neighbours once each
    (train.step._decode_once); the loss and its gradient with respect to the latent image are
    those of decoding the scored pixels and each neighbour set separately (the reference), on a
    real (conv) decoder, with pixels on the right and bottom borders drawn."""
    from brfgs.spectral.autoencoder import SpectralAutoencoder
    from brfgs.train.step import _decode_once, _spectral_tv

    torch.manual_seed(0)
    ae = SpectralAutoencoder(n_bands=24, latent_dim=4)
    g = torch.Generator().manual_seed(1)
    h, w = 9, 7
    obs = 0.05 + 0.3 * torch.rand(h, w, 24, generator=g)  # [H, W, B]
    valid = torch.rand(h, w, generator=g) > 0.1
    idx = torch.cat([torch.randperm(h * w, generator=g)[:30], torch.tensor([w - 1, h * w - 1, (h - 1) * w])])

    def loss(lat, once):
        flat = lat.reshape(h * w, -1)
        if once:
            at = _decode_once(ae, flat, idx, w, h)
        else:
            at = lambda q: ae.decode(flat[q])  # noqa: E731
        pred = at(idx)
        return (pred - obs.reshape(h * w, -1)[idx]).abs().mean() + _spectral_tv(at, obs, valid, idx, pred)

    grads = []
    for once in (False, True):
        lat = torch.randn(h, w, 4, generator=torch.Generator().manual_seed(2)).requires_grad_(True)
        val = loss(lat, once)
        val.backward()
        grads.append((val.detach(), lat.grad.clone()))
    assert torch.allclose(grads[0][0], grads[1][0], rtol=1e-6, atol=1e-7)
    assert torch.allclose(grads[0][1], grads[1][1], rtol=1e-5, atol=1e-8)
    assert grads[1][1].abs().sum() > 0
