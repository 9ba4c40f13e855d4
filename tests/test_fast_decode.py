"""The fused decoder (brfgs.spectral.fast_decode) against the reference SpectralAutoencoder.decode:
values, latent gradients (gradcheck in float64), groups of lanes, its vectorised erf/exp against math,
and dispatch."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from brfgs.model.rendering import decode_image
from brfgs.spectral.autoencoder import AutoencoderConfig, SpectralAutoencoder, train_autoencoder
from brfgs.spectral.fast_decode import can_fast_decode, fast_decode


def _decoder(n_bands: int, seed: int = 0, dtype=torch.float32) -> SpectralAutoencoder:
    """A decoder with random, non-trivial weights (the trained one starts with dec_up2 = 0)."""
    torch.manual_seed(seed)
    m = SpectralAutoencoder(n_bands, 16)
    with torch.no_grad():
        for p in m.parameters():
            p.normal_(0.0, 0.3)
        m.band_std.uniform_(0.05, 0.2)
        m.band_mean.uniform_(0.0, 0.4)
    return m.to(dtype).eval().requires_grad_(False)


@pytest.mark.parametrize("n_bands", [164, 50, 16, 7])
def test_fast_decode_equals_the_reference(n_bands):
    m = _decoder(n_bands)
    z = torch.randn(1000, 16, generator=torch.Generator().manual_seed(1)) * 2.0
    ref = m.decode(z)
    np.testing.assert_allclose(fast_decode(m, z).numpy(), ref.numpy(), atol=1e-5, rtol=0)
    m64 = _decoder(n_bands, dtype=torch.float64)
    np.testing.assert_allclose(fast_decode(m64, z.double()).numpy(), m64.decode(z.double()).numpy(), atol=1e-6)


def test_fast_decode_equals_a_trained_decoder():
    """A decoder trained on smooth spectra (its convolutional residual no longer zero)."""
    rng = np.random.default_rng(0)
    wl = np.linspace(0, 1, 40)
    pix = (0.1 + 0.3 * rng.random((3000, 1)) * wl + 0.05 * rng.random((3000, 1)) * np.sin(6 * wl)).astype(np.float32)
    m, _ = train_autoencoder(pix, AutoencoderConfig(latent_dim=8, steps=150, batch_size=256, seed=0))
    m.requires_grad_(False)
    assert m.dec_up2.weight.abs().max() > 0
    z = m.encode(torch.from_numpy(pix[:500]))
    np.testing.assert_allclose(fast_decode(m, z).numpy(), m.decode(z).numpy(), atol=1e-5)


def test_fast_decode_latent_gradient():
    m = _decoder(23, dtype=torch.float64)
    z = (torch.randn(40, 16, dtype=torch.float64) * 1.5).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda q: fast_decode(m, q), (z,), eps=1e-6, atol=1e-5)
    g = torch.randn(40, 23, dtype=torch.float64)
    (m.decode(z) * g).sum().backward()
    ref = z.grad.clone()
    z.grad = None
    (fast_decode(m, z) * g).sum().backward()
    np.testing.assert_allclose(z.grad.numpy(), ref.numpy(), rtol=0, atol=1e-6 * float(ref.abs().max()))
    m32 = _decoder(164)
    z32 = torch.randn(300, 16).requires_grad_(True)
    g32 = torch.randn(300, 164)
    (m32.decode(z32) * g32).sum().backward()
    ref32 = z32.grad.clone()
    z32.grad = None
    (fast_decode(m32, z32) * g32).sum().backward()
    np.testing.assert_allclose(z32.grad.numpy(), ref32.numpy(), atol=1e-5 * float(ref32.abs().max()))


def test_vectorised_erf_and_exp_against_math():
    from numba import njit

    from brfgs.spectral.fast_math import erf as _erf
    from brfgs.spectral.fast_math import exp_neg as _exp_neg

    @njit
    def ev(x, e, p):
        for i in range(x.shape[0]):
            e[i] = _erf(x[i])
            p[i] = _exp_neg(-0.5 * x[i] * x[i])

    x = np.linspace(-9.0, 9.0, 20001)
    e, p = np.empty_like(x), np.empty_like(x)
    ev(x, e, p)
    np.testing.assert_allclose(e, [math.erf(v) for v in x], atol=1e-7)
    assert np.abs(x * (p - np.exp(-0.5 * x * x))).max() < 1e-9          # x·φ(x) in the GELU derivative


def test_decode_image_takes_the_fast_path_only_when_it_may():
    m = _decoder(30)
    z = torch.randn(5, 7, 16)
    assert can_fast_decode(m, z)
    np.testing.assert_allclose(decode_image(m, z).numpy(), m.decode(z).numpy(), atol=1e-5)
    m.dec_lin.weight.requires_grad_(True)                   # a decoder being fine-tuned: the reference
    assert not can_fast_decode(m, z)
    out = decode_image(m, z)
    out.sum().backward()
    assert m.dec_lin.weight.grad is not None
    with torch.no_grad():
        assert can_fast_decode(m, z)
    assert not can_fast_decode(m, z.to(torch.float16))


def test_the_plan_follows_weight_updates():
    m = _decoder(20)
    z = torch.randn(10, 16)
    before = fast_decode(m, z)
    with torch.no_grad():
        m.dec_lin.bias.add_(1.0)                            # an in-place update (as an optimiser step)
    np.testing.assert_allclose(fast_decode(m, z).numpy(), before.numpy() + m.band_std.numpy(), atol=1e-5)


def test_bench_view_times_both_decoders_in_one_run(tmp_path):
    """`brfgs bench view` (correctness of what it reports, not speed): both decoders timed, the same cube."""
    import json

    from brfgs.cli import main

    out = tmp_path / "view.json"
    assert main(["bench", "view", "--gaussians", "400", "--size", "16,24", "--repeats", "1",
                 "--threads", "1", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [v["size"] for v in res["views"]] == [[16, 16], [24, 24]] and res["bands"] == 164
    for v in res["views"]:
        assert v["fused"]["median_s"] > 0 and v["reference"]["median_s"] > 0
        assert v["max_abs_diff_vs_reference"] < 1e-5
        assert v["speedup_vs_reference"] == v["reference"]["median_s"] / v["fused"]["median_s"]
    assert res["machine"]["backend"] == "cpu" and "gpu" in res["machine"]
    assert main(["bench", "view", "--json", str(tmp_path)]) == 2
    assert main(["bench", "view", "--backend", "metal", "--size", "16"]) == 2


def test_a_pixel_decodes_the_same_in_any_group_of_lanes():
    """The kernels decode 16 pixels at a time: a pixel's spectrum and latent gradient do not depend on
    which pixels share its group, nor on a partial last group (1, 15, 17 and 33 pixels)."""
    m = _decoder(40)
    z = torch.randn(33, 16)
    g = torch.randn(33, 40)
    zz = z.clone().requires_grad_(True)
    (fast_decode(m, zz) * g).sum().backward()
    full_out, full_grad = fast_decode(m, z), zz.grad
    for n in (1, 15, 17):
        for start in (0, 33 - n):
            part = z[start:start + n].clone().requires_grad_(True)
            out = fast_decode(m, part)
            (out * g[start:start + n]).sum().backward()
            np.testing.assert_allclose(out.detach().numpy(), full_out[start:start + n].numpy(), rtol=0, atol=1e-6)
            np.testing.assert_allclose(part.grad.numpy(), full_grad[start:start + n].numpy(), rtol=0, atol=1e-6)


@pytest.mark.parametrize("n_bands", [164, 50, 16, 7])
def test_fused_encoder_equals_the_reference(n_bands):
    from brfgs.spectral.fast_encode import encode_spectra

    m = _decoder(n_bands)
    r = torch.rand(3, 300, n_bands, generator=torch.Generator().manual_seed(2)) * 0.5
    ref = m.encode(r)
    out = encode_spectra(m, r)
    assert out.shape == ref.shape == (3, 300, 16)
    np.testing.assert_allclose(out.numpy(), ref.numpy(), rtol=0, atol=2e-6 * float(ref.abs().max()))
    rg = r.clone().requires_grad_(True)                          # a gradient wanted: the reference, differentiable
    encode_spectra(m, rg).sum().backward()
    assert rg.grad is not None and rg.grad.abs().sum() > 0
