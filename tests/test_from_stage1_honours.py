"""`brfgs train SCENE OUT --from-stage1 CKPT` takes only the geometry from the checkpoint: the scene's
frames and fields (root, diffuse fraction ...) and this command's options (the spectral basis) are
the ones trained and recorded; a scene whose frames are not the checkpoint's is refused in one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from brfgs.cli import main
from brfgs.model import TrainedModel, render
from brfgs.model.io import load
from brfgs.spectral.autoencoder import SpectralAutoencoder
from brfgs.spectral.linear_basis import LinearBasis
from test_train_scene import make_plane_scene
from tiny_runs import OPTIONS, STAGE1, run, scene

LINEAR_TENSORS = {"decoder.weight", "decoder.bias", "decoder.noise_sigma"}


def _copy_scene(tmp_path: Path, name: str, edit) -> Path:
    """A copy of the tiny runs' scene with transforms.json changed by ``edit(meta)``."""
    out = tmp_path / name
    shutil.copytree(scene(), out)
    meta = json.loads((out / "transforms.json").read_text())
    edit(meta)
    (out / "transforms.json").write_text(json.dumps(meta, indent=1))
    return out


def _decoder_names(path: Path) -> set[str]:
    return {k for k in load(path)[0] if k.startswith("decoder.")}


@pytest.fixture(scope="module")
def hazy(tmp_path_factory) -> tuple[Path, Path, list[float]]:
    """(scene copy with a diffuse fraction, its --shadows run from the original's stage 1, the field)."""
    tmp = tmp_path_factory.mktemp("hazy")
    field = [round(0.55 + 0.02 * b, 3) for b in range(8)]
    copy = _copy_scene(tmp, "scene_hazy", lambda m: m.update(diffuse_fraction=field))
    out = tmp / "run"
    assert main(["train", str(copy), str(out), *OPTIONS, "--shadows", "--from-stage1", str(run("brf") / STAGE1)]) == 0
    return copy, out, field


def test_the_scene_copy_s_diffuse_fraction_is_recorded(hazy):
    copy, out, field = hazy
    tm = TrainedModel.load(out)
    assert tm.scene_root == str(copy.resolve()) and tm.scene["diffuse_fraction"] == field
    assert np.allclose(tm.diffuse_fraction().numpy(), field, atol=1e-6)
    assert tm.meta["stage1_from"] == str((run("brf") / STAGE1).resolve())
    assert json.loads((out / "run.json").read_text())["scene"] == str(copy.resolve())
    # the original's stage 1 held the original scene's description, without the field
    assert "diffuse_fraction" not in load(run("brf") / STAGE1)[1]["scene"]


def test_the_scene_copy_s_diffuse_fraction_lights_training_and_renders(hazy):
    _, out, field = hazy
    tm = TrainedModel.load(out)
    # trained under that sky: the head differs from the same run under the clear-sky default
    plain, lit = load(run("shadows") / "model.safetensors")[0], load(out / "model.safetensors")[0]
    assert torch.equal(lit["param.means"], plain["param.means"])  # the same geometry
    assert not torch.equal(lit["param.z_iso"], plain["param.z_iso"])
    assert not torch.equal(lit["extra.bg_latent"], plain["extra.bg_latent"])
    # and rendered under it: the cube is the decoded latent times (1 - f_b) V + f_b with the field's f_b
    rv = render(tm, tm.cameras[0], backend="torch")
    f_b = np.asarray(field, np.float32)
    light = (1 - f_b) * rv.sun_lit[..., None] + f_b
    np.testing.assert_allclose(rv.cube, tm.decode(rv.latent) * light, rtol=1e-4, atol=1e-5)
    other = TrainedModel.load(run("shadows"))
    assert not np.allclose(other.diffuse_fraction().numpy(), f_b, atol=0.05)


def test_a_linear_stage_2_from_an_autoencoder_stage_1_trains_the_linear_basis():
    out = run("brf_linear")
    tm = TrainedModel.load(out)
    assert isinstance(tm.decoder, LinearBasis) and tm.meta["spectral_basis"] == "linear"
    assert _decoder_names(out / "model.safetensors") == LINEAR_TENSORS
    assert json.loads((out / "config.json").read_text())["spectral_basis"] == "linear"
    assert json.loads((out / "autoencoder.json").read_text())["config"]["spectral_basis"] == "linear"
    assert tm.meta["autoencoder_report"]["config"]["spectral_basis"] == "linear"
    # the geometry is the stage-1 run's
    assert torch.equal(tm.gaussians.means, load(run("brf") / STAGE1)[0]["param.means"])
    r = render(tm, tm.cameras[1], backend="torch")
    assert np.isfinite(r.cube).all()


def test_an_autoencoder_stage_2_from_a_linear_stage_1_trains_the_autoencoder():
    out = run("linear_ae")
    tm = TrainedModel.load(out)
    assert isinstance(tm.decoder, SpectralAutoencoder) and tm.meta["spectral_basis"] == "autoencoder"
    names = _decoder_names(out / "model.safetensors")
    assert names == {f"decoder.{k}" for k in tm.decoder.state_dict()} and not names & LINEAR_TENSORS
    assert _decoder_names(run("linear") / STAGE1) == LINEAR_TENSORS
    assert json.loads((out / "config.json").read_text())["spectral_basis"] == "autoencoder"
    assert json.loads((out / "autoencoder.json").read_text())["config"]["steps"] == 40  # trained here
    assert torch.equal(tm.gaussians.means, load(run("linear") / STAGE1)[0]["param.means"])


def test_the_same_basis_reuses_the_stage_1_decoder():
    """The checkpoint's basis asked for again: its decoder is reused as it is (today's behaviour)."""
    ae = load(run("brf") / STAGE1)[0]
    sh = load(run("sh") / "model.safetensors")[0]
    assert {k for k in ae if k.startswith("decoder.")} == {k for k in sh if k.startswith("decoder.")}
    assert all(torch.equal(ae[k], sh[k]) for k in ae if k.startswith("decoder."))


def _drop_last_frame(meta):
    meta["frames"] = meta["frames"][:-1]


def _swap_first_frames(meta):
    meta["frames"][0], meta["frames"][1] = meta["frames"][1], meta["frames"][0]


def _hold_out_first(meta):
    meta["frames"][0]["split"] = "test"


@pytest.mark.parametrize("edit, field", [(_drop_last_frame, "scene.frames"),
                                         (_swap_first_frames, "scene.frames[0].name"),
                                         (_hold_out_first, "scene.split.train")])
def test_other_frames_are_refused_in_one_line(tmp_path, capsys, edit, field):
    other = _copy_scene(tmp_path, "other", edit)
    _refused(other, tmp_path / "out", field, capsys)


@pytest.mark.parametrize("kw, field", [(dict(w=40), "scene.intrinsics"), (dict(n_bands=6), "scene.wavelengths_nm")])
def test_another_camera_or_other_bands_are_refused_in_one_line(tmp_path, capsys, kw, field):
    other = make_plane_scene(tmp_path / "other", **{"w": 48, "h": 32, "n_bands": 8, "n_views": 13, **kw})
    _refused(other, tmp_path / "out", field, capsys)


def _refused(other: Path, out: Path, field: str, capsys) -> None:
    ckpt = run("brf") / STAGE1
    capsys.readouterr()
    assert main(["train", str(other), str(out), *OPTIONS, "--variant", "sh", "--from-stage1", str(ckpt)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(ckpt) in err[0] and f"'{field}'" in err[0], err
    assert not (out / "model.safetensors").exists() and not (out / "checkpoints").exists()
