"""Models with a linear spectral basis: the model file records the basis (files without the record,
such as brfgs 0.1's, hold the autoencoder), damaged records are named, and rendering blends latents in
either decode order with the spectra of decoding each Gaussian."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors import safe_open

from brfgs.errors import UserError
from brfgs.model import TrainedModel, render
from brfgs.model import io
from brfgs.model.view import pixel_spectra, spectral_features
from brfgs.spectral.autoencoder import SpectralAutoencoder
from brfgs.spectral.linear_basis import LinearBasis, fit_linear_basis
from test_model_file import small_model

FORMAT1_MODEL = Path(__file__).parent / "data" / "format1" / "finished" / "model.safetensors"


def linear_model(bg: float = 0.3, decode: str = "pixel") -> TrainedModel:
    """tests/test_model_file.py's small model with a linear basis fitted to random smooth spectra."""
    tm = small_model()
    rng = np.random.default_rng(1)
    wl = np.linspace(0, 1, 8)
    pix = 0.2 + rng.normal(0, 0.05, (400, 4)) @ np.stack([np.cos(k * np.pi * wl) for k in range(4)])
    tm.decoder = fit_linear_basis(pix, 4, np.full(8, 0.01)).requires_grad_(False)
    tm.extra["bg_latent"] = torch.full((4,), bg)
    tm.config = {"variant": "brf", "decode": decode}
    return tm


def _meta(path: Path) -> dict:
    with safe_open(str(path), framework="pt") as f:
        return json.loads(f.metadata()["brfgs"])


def test_a_file_without_the_record_holds_the_autoencoder(tmp_path):
    assert "spectral_basis" not in _meta(FORMAT1_MODEL)  # written by brfgs 0.1
    old = TrainedModel.load(FORMAT1_MODEL)
    assert type(old.decoder) is SpectralAutoencoder
    assert _meta(old.save(tmp_path / "again.safetensors"))["spectral_basis"] == "autoencoder"
    tm = small_model()  # the previous layout: today's file less the record
    tensors, meta = tm.tensors(), tm.metadata()
    assert meta.pop("spectral_basis") == "autoencoder"
    io.save(tmp_path / "prev.safetensors", tensors, meta)
    back = TrainedModel.load(tmp_path / "prev.safetensors")
    assert type(back.decoder) is SpectralAutoencoder
    assert np.array_equal(render(back, back.cameras[0], backend="torch").cube,
                          render(tm, tm.cameras[0], backend="torch").cube)


def test_linear_model_round_trip(tmp_path):
    tm = linear_model()
    path = tm.save(tmp_path / "model.safetensors")
    meta = _meta(path)
    assert meta["spectral_basis"] == "linear" and "autoencoder" not in meta
    assert json.loads(meta["linear_basis"]) == {"n_bands": 8, "latent_dim": 4}
    back = TrainedModel.load(path)
    assert isinstance(back.decoder, LinearBasis)
    assert torch.equal(back.decoder.weight, tm.decoder.weight)
    assert torch.equal(back.decoder.noise_sigma, tm.decoder.noise_sigma)
    for cam in back.cameras:
        assert np.array_equal(render(back, cam, backend="torch").cube, render(tm, cam, backend="torch").cube)


@pytest.mark.parametrize("change, field", [({"spectral_basis": "pca"}, "spectral_basis"),
                                           ({"spectral_basis": "linear"}, "linear_basis"),
                                           ({"linear_basis": "not json"}, "linear_basis")])
def test_a_damaged_record_is_named(tmp_path, change, field):
    tm = linear_model() if "linear_basis" in change else small_model()
    meta = tm.metadata()
    meta.update(change)
    io.save(tmp_path / "m.safetensors", tm.tensors(), meta)
    with pytest.raises(UserError) as e:
        TrainedModel.load(tmp_path / "m.safetensors")
    assert e.value.field == field and "m.safetensors" in str(e.value)


def test_both_decode_orders_give_the_same_spectra():
    """Decoding each Gaussian then blending spectra (eq. 13 literally, the background's spectrum
    composited) equals what render gives a linear model: latents blended, then decoded."""
    tm = linear_model(decode="gaussian")
    assert tm.render_settings.decode_order == "pixel"
    omega_i = tm.sun_direction()
    for cam in tm.cameras:
        rv = render(tm, cam, backend="torch")
        assert rv.latent is not None and (rv.alpha < 0.99).any() and (rv.alpha > 0.5).any()
        assert np.array_equal(render(tm, cam, backend="torch", decode_order="gaussian").cube, rv.cube)
        per_gaussian = render(tm, cam, features=spectral_features(tm, omega_i, "gaussian"), backend="torch")
        literal = pixel_spectra(tm, per_gaussian.image, torch.as_tensor(per_gaussian.alpha), "gaussian")
        np.testing.assert_allclose(literal, rv.cube, atol=2e-6 * np.abs(rv.cube).max())


def test_bench_view_times_the_linear_basis_beside_the_autoencoder(tmp_path, capsys):
    """`brfgs bench view` (what it reports, not speed): the linear basis in the same rounds, its source
    stated; a model that has a linear basis is timed against an autoencoder of the same size."""
    from brfgs.analysis.bench import bench_view
    from brfgs.cli import main

    out = tmp_path / "view.json"
    assert main(["bench", "view", "--gaussians", "400", "--size", "16", "--repeats", "1", "--threads", "1",
                 "--json", str(out)]) == 0
    assert "linear basis:" in capsys.readouterr().out
    res = json.loads(out.read_text())
    v = res["views"][0]
    assert v["linear"]["median_s"] > 0 and v["linear"]["median_decode_s"] > 0
    assert v["linear_decode_speedup_vs_fused"] == v["fused"]["median_decode_s"] / v["linear"]["median_decode_s"]
    assert "z_iso" in res["bases"]["linear_basis"] and 0 <= res["bases"]["linear_fit_sam_mean_rad"] < 0.1
    own = bench_view(linear_model().save(tmp_path / "lin.safetensors"), sizes=(12,), repeats=1, backend="torch")
    assert "untrained" in own["bases"]["autoencoder"] and own["views"][0]["linear"]["median_s"] > 0
