"""Spectral autoencoder: shapes, round-trip tolerance on smooth spectra, checkpoint round trip."""

import numpy as np
import pytest
import torch

from brfgs.spectral.autoencoder import (AutoencoderConfig, SpectralAutoencoder, autoencoder_from_state,
                                        autoencoder_state, evaluate_autoencoder, sample_pixels,
                                        spectral_angle_torch, train_autoencoder)

# Stated tolerance of the decoder round trip on smooth mixtures of 4 spectra
# (164 bands, d = 8, 300 steps): mean SAM < 0.02 rad, RMSE < 0.006 reflectance.
SAM_TOL_RAD = 0.02
RMSE_TOL = 0.006


def _spectra(n, seed=0, B=164):
    rng = np.random.default_rng(seed)
    wl = np.linspace(350, 1000, B)
    ends = np.stack([0.05 + 0.4 / (1 + np.exp(-(wl - 720) / 15)), 0.1 + 0.2 * (wl - 350) / 650,
                     0.3 + 0.05 * np.sin(wl / 50), 0.02 + 0.03 * np.exp(-(wl - 550) ** 2 / 800)])
    w = rng.dirichlet(np.ones(4), size=n)
    s = rng.uniform(0.6, 1.4, (n, 1))
    return ((w @ ends) * s).astype(np.float32)


def test_shapes_and_latent_bounds():
    m = SpectralAutoencoder(164, 16)
    r = torch.rand(5, 7, 164)
    z = m.encode(r)
    assert z.shape == (5, 7, 16)
    assert m.decode(z).shape == (5, 7, 164)
    for B in (6, 17, 100):
        mm = SpectralAutoencoder(B, 4)
        assert mm(torch.rand(3, B))[0].shape == (3, B)
    with pytest.raises(ValueError):
        SpectralAutoencoder(164, 33)


def test_round_trip_within_stated_tolerance():
    torch.set_num_threads(1)
    X = _spectra(6000, 0)
    model, hist = train_autoencoder(X, AutoencoderConfig(latent_dim=8, steps=300, batch_size=512, seed=0))
    assert hist[-1] < hist[0] * 0.5
    rep = evaluate_autoencoder(model, _spectra(2000, 1))
    assert rep["sam_mean_rad"] < SAM_TOL_RAD, rep
    assert rep["rmse"] < RMSE_TOL, rep
    # the checkpoint form reproduces the decoder exactly
    t, meta = autoencoder_state(model)
    m2 = autoencoder_from_state(t, meta)
    z = torch.randn(10, 8)
    assert torch.equal(m2.decode(z), model.decode(z))


def test_training_is_deterministic():
    X = _spectra(1000, 2, B=32)
    cfg = AutoencoderConfig(latent_dim=4, steps=20, batch_size=128, seed=3)
    a, _ = train_autoencoder(X, cfg)
    b, _ = train_autoencoder(X, cfg)
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values()):
        assert torch.equal(va, vb), k


def test_spectral_angle_and_pixel_sampling():
    a = torch.tensor([[1.0, 0.0], [0.0, 2.0]])
    b = torch.tensor([[1.0, 1.0], [0.0, 5.0]])
    ang = spectral_angle_torch(a, b)
    assert ang[0].item() == pytest.approx(np.pi / 4, abs=1e-3)
    assert ang[1].item() == pytest.approx(0.0, abs=3e-3)
    cube = np.ones((4, 5, 3), np.float32)
    cube[0, 0, 1] = np.nan
    pix = sample_pixels([cube, cube], 100, 0)
    assert pix.shape == (38, 3) and np.isfinite(pix).all()
