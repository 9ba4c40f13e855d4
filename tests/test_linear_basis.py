"""The linear spectral basis (brfgs.spectral.linear_basis): the noise-weighted PCA against a float64
numpy reference, exact reconstruction of a d-dimensional affine subspace, what the weighting does,
determinism, its file state; the numba decoder against F.linear with finite-difference gradients; the
dispatch of decode_image and decode_bands."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from brfgs.model.rendering import decode_image
from brfgs.spectral.band_decode import decode_bands
from brfgs.spectral.decoders import decoder_from_state, decoder_state
from brfgs.spectral.fast_decode import reference_decoding
from brfgs.spectral.fast_linear import linear_decode
from brfgs.spectral.linear_basis import LinearBasis, fit_linear_basis, linear_basis_from_state, linear_basis_state


def _spectra(n: int = 2000, n_bands: int = 30, rank: int = 5, noise=0.0, seed: int = 0) -> np.ndarray:
    """Smooth spectra: a mean plus ``rank`` random smooth components, plus Gaussian noise (σ per band)."""
    rng = np.random.default_rng(seed)
    wl = np.linspace(0, 1, n_bands)
    comps = np.stack([np.sin((k + 1) * np.pi * wl + k) for k in range(rank)])  # [rank, B]
    coef = rng.normal(0, 1, (n, rank)) * (0.1 / (1 + np.arange(rank)))
    x = 0.3 + 0.2 * wl + coef @ comps
    return x + rng.normal(0, 1, x.shape) * np.asarray(noise)


def _reference(x: np.ndarray, d: int, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(W [B, d], b [B]) by the eigen-decomposition of the whitened covariance (float64, numpy)."""
    mean = x.mean(0)
    y = (x - mean) / sigma
    lam, vec = np.linalg.eigh(y.T @ y / (len(x) - 1))
    order = np.argsort(lam)[::-1][:d]
    v = vec[:, order]
    v *= np.sign(v[np.argmax(np.abs(v), 0), np.arange(d)])
    return sigma[:, None] * v * np.sqrt(lam[order])[None], mean


@pytest.mark.parametrize("weighted", [False, True])
def test_fit_equals_a_float64_reference(weighted):
    x = _spectra(noise=0.01)
    sigma = np.linspace(0.005, 0.03, x.shape[1]) if weighted else np.ones(x.shape[1])
    basis = fit_linear_basis(x, 6, sigma if weighted else None)
    w_ref, b_ref = _reference(x, 6, sigma)
    np.testing.assert_allclose(basis.weight.detach().double().numpy(), w_ref, rtol=1e-4,
                               atol=1e-6 * np.abs(w_ref).max())
    np.testing.assert_allclose(basis.bias.detach().double().numpy(), b_ref, rtol=1e-6)
    z = basis.encode(torch.from_numpy(x)).numpy()  # standardised PCA scores: unit variance, uncorrelated
    np.testing.assert_allclose(np.cov(z.T), np.eye(6), atol=1e-4)
    np.testing.assert_allclose(z.mean(0), 0.0, atol=1e-5)


def test_spectra_in_a_d_dimensional_affine_subspace_are_reconstructed_exactly():
    x = _spectra(n=500, rank=4)  # mean + 4 components: exactly an affine 4-dim subspace
    for sigma in (None, np.linspace(0.01, 0.05, x.shape[1])):
        basis = fit_linear_basis(x, 4, sigma)
        r, _ = basis(torch.from_numpy(x.astype(np.float32)))
        np.testing.assert_allclose(r.detach().numpy(), x, atol=2e-6)
    # more components than the data's rank: the basis is completed, reconstruction stays exact
    basis = fit_linear_basis(x[:3], 6)
    r, _ = basis(torch.from_numpy(x[:3].astype(np.float32)))
    np.testing.assert_allclose(r.detach().numpy(), x[:3], atol=2e-6)
    assert np.isfinite(basis.weight.detach().numpy()).all()


def test_the_noise_weighting_follows_the_quiet_bands():
    """Bands 0-9 quiet (σ 0.001), bands 10-29 loud (σ 0.2): with one component, the σ-weighted fit
    finds the signal's direction and reconstructs the quiet bands far better than the unweighted fit,
    which chases the loud bands' noise; encoding is the σ-weighted least-squares projection."""
    n_bands = 30
    sigma = np.r_[np.full(10, 0.001), np.full(20, 0.2)]
    signal = _spectra(n=4000, n_bands=n_bands, rank=1, seed=1)
    x = signal + np.random.default_rng(2).normal(0, 1, signal.shape) * sigma
    plain, weighted = fit_linear_basis(x, 1), fit_linear_basis(x, 1, sigma)
    quiet = slice(0, 10)

    def quiet_error(basis):
        r, _ = basis(torch.from_numpy(x.astype(np.float32)))
        return float(np.sqrt(np.mean((r.detach().double().numpy() - signal)[:, quiet] ** 2)))

    assert quiet_error(weighted) < 0.2 * quiet_error(plain)
    truth = np.linalg.svd(signal - signal.mean(0), full_matrices=False)[2][0]
    w = weighted.weight.detach().double().numpy()[:, 0]
    assert abs(w @ truth) / np.linalg.norm(w) > 0.99
    xt = torch.from_numpy(x[:50])
    z = weighted.encode(xt).numpy()
    a = weighted.weight.detach().double().numpy() / sigma[:, None]
    ref = np.linalg.lstsq(a, ((x[:50] - weighted.bias.detach().double().numpy()) / sigma).T, rcond=None)[0].T
    np.testing.assert_allclose(z, ref, rtol=1e-6, atol=1e-9)


def test_the_fit_is_deterministic_and_independent_of_pixel_order():
    x = _spectra(noise=0.01)
    a, b = fit_linear_basis(x, 5, np.full(30, 0.01)), fit_linear_basis(x, 5, np.full(30, 0.01))
    assert torch.equal(a.weight, b.weight) and torch.equal(a.bias, b.bias)
    c = fit_linear_basis(x[::-1].copy(), 5, np.full(30, 0.01))
    np.testing.assert_allclose(c.weight.detach().numpy(), a.weight.detach().numpy(), atol=1e-6)
    w = a.weight.detach().numpy()
    assert (w[np.argmax(np.abs(w), 0), np.arange(5)] > 0).all()  # the sign convention
    sub = fit_linear_basis(x, 5, max_pixels=500, seed=3)
    assert torch.equal(sub.weight, fit_linear_basis(x, 5, max_pixels=500, seed=3).weight)
    with pytest.raises(ValueError):
        fit_linear_basis(np.full((4, 30), np.nan), 2)
    with pytest.raises(ValueError):
        LinearBasis(8, 9)


def test_state_round_trip(tmp_path):
    basis = fit_linear_basis(_spectra(noise=0.01), 5, np.linspace(0.01, 0.02, 30))
    tensors, meta = linear_basis_state(basis, "decoder.")
    save_file(tensors, str(tmp_path / "b.safetensors"))
    back = linear_basis_from_state(load_file(str(tmp_path / "b.safetensors")), meta, "decoder.")
    for name in ("weight", "bias", "noise_sigma"):
        assert torch.equal(getattr(back, name), getattr(basis, name))
    t2, m2 = decoder_state(basis)
    assert m2["spectral_basis"] == "linear" and isinstance(decoder_from_state(t2, m2), LinearBasis)


def _random_basis(n_bands=23, d=6, dtype=torch.float64) -> LinearBasis:
    torch.manual_seed(0)
    basis = LinearBasis(n_bands, d).to(dtype)
    with torch.no_grad():
        basis.weight.normal_(0, 0.3)
        basis.bias.uniform_(0, 0.4)
    return basis


def test_the_kernel_equals_the_reference_and_its_gradients_finite_differences():
    b32 = _random_basis(164, 16, torch.float32).requires_grad_(False)
    z = torch.randn(5000, 16) * 2
    np.testing.assert_allclose(linear_decode(b32, z).numpy(), b32.decode(z).numpy(), atol=2e-6)
    b64 = _random_basis(7, 3)
    z64 = (torch.randn(8, 3, dtype=torch.float64) * 1.5).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda q, w, b: _decode_with(b64, q, w, b),
                                    (z64, b64.weight, b64.bias), eps=1e-6, atol=1e-7)
    b64 = _random_basis()
    z64 = (torch.randn(40, 6, dtype=torch.float64) * 1.5).requires_grad_(True)
    g = torch.randn(40, 23, dtype=torch.float64)
    (linear_decode(b64, z64) * g).sum().backward()
    np.testing.assert_allclose(z64.grad.numpy(), (g @ b64.weight).detach().numpy(), rtol=1e-12)
    np.testing.assert_allclose(b64.weight.grad.numpy(), (g.T @ z64).detach().numpy(), rtol=1e-12)
    np.testing.assert_allclose(b64.bias.grad.numpy(), g.sum(0).numpy(), rtol=1e-12)


def _decode_with(basis, z, w, b):
    """linear_decode with the basis' tensors as the given (differentiated) ones."""
    basis.weight, basis.bias = w, b
    return linear_decode(basis, z)


def test_decode_image_and_decode_bands_dispatch_to_the_basis():
    basis = _random_basis(40, 8, torch.float32).requires_grad_(False)
    z = torch.randn(7, 9, 8)
    ref = basis.decode(z)
    np.testing.assert_allclose(decode_image(basis, z).numpy(), ref.numpy(), atol=1e-6)
    with reference_decoding():
        assert torch.equal(decode_image(basis, z), ref.reshape(7, 9, 40))
    np.testing.assert_allclose(decode_bands(basis, z, [39, 3, 17]).numpy(), ref[..., [39, 3, 17]].numpy(), atol=1e-6)
    zg = torch.randn(30, 8, requires_grad=True)  # training: gradients reach the latent
    decode_image(basis, zg).sum().backward()
    np.testing.assert_allclose(zg.grad.numpy(), basis.weight.sum(0).expand(30, 8).numpy(), rtol=1e-5)
