"""brfgs train --spectral-basis linear: the option and its validation, options files that predate it,
and a tiny run that trains, evaluates, renders and writes the exact kernel weights as products."""

import json

import numpy as np
import pytest
import torch

from brfgs.cli import main
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.spectral.decoders import SPECTRAL_BASES
from brfgs.spectral.linear_basis import LinearBasis
from brfgs.train import config as C
from brfgs.train.config import TrainConfig
from brfgs.train.presets import preset
from test_train_scene import make_plane_scene

TINY = ["--preset", "tiny", "--quiet", "--threads", "1", "--stage1-steps", "6", "--stage2-steps", "4"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("lin") / "scene", w=48, h=32, n_bands=12)


def test_the_option_its_validation_and_files_that_predate_it():
    assert C.SPECTRAL_BASES == SPECTRAL_BASES
    assert TrainConfig().spectral_basis == "autoencoder" and preset("paper").spectral_basis == "autoencoder"
    assert preset("paper-fast").spectral_basis == "autoencoder"
    with pytest.raises(UserError) as e:
        TrainConfig(spectral_basis="pca").validate()
    assert e.value.field == "spectral_basis"
    d = TrainConfig(spectral_basis="linear").to_dict()
    assert TrainConfig.from_written(d).spectral_basis == "linear"
    del d["spectral_basis"]  # a format-2 file written before the option: the default
    assert TrainConfig.from_written(d).spectral_basis == "autoencoder"
    fmt1 = {k: v for k, v in d.items() if k != "format_version"}  # format 1 (no format_version)
    assert TrainConfig.from_written(fmt1).spectral_basis == "autoencoder"


def test_a_linear_run_trains_evaluates_renders_and_writes_exact_kernel_weights(scene, tmp_path):
    out = tmp_path / "run"
    assert main(["train", str(scene), str(out), *TINY, "--spectral-basis", "linear", "--decode", "gaussian"]) == 0
    tm = TrainedModel.load(out)
    assert isinstance(tm.decoder, LinearBasis) and tm.meta["spectral_basis"] == "linear"
    assert tm.render_settings.decode_order == "pixel"  # the same spectra, latents blended
    assert json.loads((out / "config.json").read_text())["spectral_basis"] == "linear"
    report = json.loads((out / "autoencoder.json").read_text())
    assert report["config"]["spectral_basis"] == "linear" and report["test"]["sam_mean_rad"] < 0.05
    m = json.loads((out / "metrics.json").read_text())
    assert 0 < m["against"]["truth"]["mean"]["sam"] < 1.6
    assert main(["render", str(out), "--view-zenith", "20", "--view-azimuth", "45", "--out", str(tmp_path / "r"),
                 "--quiet", "--backend", "torch"]) == 0
    assert main(["products", str(out), "--out", str(tmp_path / "p"), "--size", "12", "--quiet", "--backend", "torch",
                 "--no-check-decoder"]) == 0
    info = json.loads((tmp_path / "p" / "products.json").read_text())
    assert info["settings"]["mcd43"]["method"] == "exact"
    assert {"f_iso", "f_vol", "f_geo", "f_spec", "fit_rmse", "nbar_mcd43"} <= set(info["files"])
    assert (tmp_path / "p" / "f_spec.hdr").is_file()


def test_a_linear_basis_needs_as_many_bands_as_components(scene, tmp_path, capsys):
    assert main(["train", str(scene), str(tmp_path / "x"), *TINY, "--spectral-basis", "linear",
                 "--latent-dim", "13"]) == 2
    assert "latent_dim" in capsys.readouterr().err


@pytest.mark.parametrize("extra", [["--joint"], ["--variant", "sh"], ["--finetune-decoder"]])
def test_the_baselines_and_decoder_finetuning_train_with_a_linear_basis(scene, tmp_path, extra):
    out = tmp_path / "run"
    assert main(["train", str(scene), str(out), *TINY, "--spectral-basis", "linear", *extra]) == 0
    w = TrainedModel.load(out).decoder.weight.detach()
    assert np.isfinite(w.numpy()).all()
    if "--finetune-decoder" in extra:  # stage 2 moved the basis (a frozen run keeps the fitted one)
        frozen = tmp_path / "frozen"
        assert main(["train", str(scene), str(frozen), *TINY, "--spectral-basis", "linear"]) == 0
        assert not torch.equal(TrainedModel.load(frozen).decoder.weight.detach(), w)
