"""Damaged run files (run.json, config.json, checkpoints, models, with or without their checksum) are
refused in one line naming the file and the way out; nothing renders from a model missing a tensor."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from brfgs.cli import main
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.train.state import TrainState
from test_format1_runs import DATA, OPTIONS, scene  # noqa: F401  (the fixture)


def _rewrite(path: Path, drop: str | None = None, meta_edit=None, keep_checksum: bool = False) -> None:
    """Rewrite a safetensors file without tensor ``drop`` and/or with its JSON metadata edited, its
    checksum removed (as a hand-edited file would be) unless ``keep_checksum``."""
    with safe_open(str(path), framework="pt") as f:
        md = dict(f.metadata())
        tensors = {k: f.get_tensor(k) for k in f.keys() if k != drop}
    if meta_edit is not None:
        meta = json.loads(md["brfgs"])
        meta_edit(meta)
        md["brfgs"] = json.dumps(meta)
    if not keep_checksum:
        md.pop("sha256", None)
    save_file(tensors, str(path), metadata=md)


@pytest.mark.parametrize("tensor", ["param.z_spec", "param.rho_raw", "param.z_iso", "decoder.dec_lin.weight",
                                    "param.quats"])
@pytest.mark.parametrize("keep_checksum", [False, True])
def test_a_model_missing_a_tensor_is_refused(tmp_path, capsys, tensor, keep_checksum):
    model = tmp_path / "model.safetensors"
    shutil.copy(DATA / "finished" / "model.safetensors", model)
    _rewrite(model, drop=tensor, keep_checksum=keep_checksum)
    with pytest.raises(UserError) as err:
        TrainedModel.load(model)
    assert str(model) in str(err.value)
    assert main(["render", str(model), "--view-zenith", "10", "--view-azimuth", "0", "--out", str(tmp_path / "r"),
                 "--quiet"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1 and not (tmp_path / "r" / "render.json").exists()


@pytest.mark.parametrize("edit", ["no_optim", "bad_phase", "no_rng", "no_densify", "no_step"])
def test_a_checkpoint_without_its_resume_state_is_refused(tmp_path, edit):
    ckpt = tmp_path / "last.safetensors"
    shutil.copy(DATA / "interrupted" / "checkpoints" / "last.safetensors", ckpt)
    drop = {"no_rng": "rng.torch", "no_densify": "densify.grad2d"}.get(edit)
    meta_edit = {"no_optim": lambda m: m.pop("optim"), "bad_phase": lambda m: m.update(phase="stage9"),
                 "no_step": lambda m: m.pop("step")}.get(edit)
    _rewrite(ckpt, drop=drop, meta_edit=meta_edit)
    from brfgs.train.presets import preset

    with pytest.raises(UserError, match="delete it") as err:
        TrainState(preset("tiny")).load_checkpoint(ckpt)
    assert str(ckpt) in str(err.value)


def test_damaged_run_folder_files_are_one_line_errors(scene, tmp_path, capsys):  # noqa: F811
    run = tmp_path / "run"
    shutil.copytree(DATA / "interrupted", run)
    (run / "run.json").write_text("{broken")
    assert main(["train", str(scene), str(run), *OPTIONS]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "run.json" in err and "--overwrite" in err
    (run / "run.json").write_text(json.dumps({"status": "interrupted"}))
    (run / "config.json").write_text("[1, 2]")
    assert main(["train", str(scene), str(run), *OPTIONS]) == 2
    assert "config.json" in capsys.readouterr().err
    # both checkpoints damaged: one line naming the newest and the way out
    shutil.copytree(DATA / "interrupted", tmp_path / "run2")
    for name in ("last", "previous"):
        _rewrite(tmp_path / "run2" / "checkpoints" / f"{name}.safetensors", meta_edit=lambda m: m.pop("optim"))
    assert main(["train", str(scene), str(tmp_path / "run2"), *OPTIONS]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--overwrite" in err


def test_a_finished_run_without_its_status_file_is_not_reentered(scene, tmp_path, capsys):  # noqa: F811
    run = tmp_path / "run"
    shutil.copytree(DATA / "finished", run)
    (run / "run.json").unlink()
    before = (run / "model.safetensors").read_bytes()
    assert main(["train", str(scene), str(run), *OPTIONS]) == 2
    assert "finished" in capsys.readouterr().err and (run / "model.safetensors").read_bytes() == before
    assert torch.equal(TrainedModel.load(run).gaussians.means, TrainedModel.load(DATA / "finished").gaussians.means)
