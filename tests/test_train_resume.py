"""Resume bookkeeping: the newest two checkpoints are kept and a damaged one is skipped, no log row
is written twice, run.json shows the progress, and evaluation digits do not depend on the command."""

from __future__ import annotations

import csv
import json

import pytest
import torch

from brfgs.train.config_format import REMOVED
from brfgs.cli import main
from brfgs.errors import UserError
from brfgs.model.io import load
from brfgs.train.presets import preset
from brfgs.train.trainer import train
from test_train_scene import make_plane_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("resume") / "scene", w=48, h=32, n_bands=12)


def _cfg(**kw):
    return preset("tiny", **{"threads": 1, "stage1_steps": 12, "stage2_steps": 8, "checkpoint_every": 5, **kw})


def _interrupt_at(phase_step, run=None, seen=None):
    """Training callback: record run.json after every step (when ``seen``), Ctrl-C at ``phase_step``."""
    def cb(phase, step):
        if seen is not None:
            seen.append(json.loads((run / "run.json").read_text()))
        if (phase, step) == phase_step:
            raise KeyboardInterrupt
    return cb


def _log_keys(run):
    with open(run / "train_log.csv", newline="") as fh:
        return [(r["phase"], int(r["step"])) for r in csv.DictReader(fh)]


def test_damaged_newest_checkpoint_resumes_from_the_previous_one(scene, tmp_path):
    ref = train(scene, tmp_path / "ref", _cfg(), progress=False, log=None)
    run = tmp_path / "run"
    seen = []
    with pytest.raises(KeyboardInterrupt):
        train(scene, run, _cfg(), progress=False, callback=_interrupt_at(("stage2", 3), run, seen), log=None)
    # run.json showed the phase and the step while the run was going
    assert any(s["status"] == "running" and s["phase"] == "stage1" and s["step"] >= 5 for s in seen)
    assert json.loads((run / "run.json").read_text())["status"] == "interrupted"
    ckpts = run / "checkpoints"
    assert (ckpts / "last.safetensors").is_file() and (ckpts / "previous.safetensors").is_file()
    assert load(ckpts / "last.safetensors")[1]["step"] == 3
    # damage the newest checkpoint's tensor bytes: it is detected, reported and skipped
    data = bytearray((ckpts / "last.safetensors").read_bytes())
    data[-100] ^= 0xFF
    (ckpts / "last.safetensors").write_bytes(bytes(data))
    messages = []
    out = train(scene, run, _cfg(), progress=False, log=messages.append)
    assert any("damaged checkpoint" in m and "last.safetensors" in m for m in messages), messages
    ta, tb = load(ref)[0], load(out)[0]
    assert ta.keys() == tb.keys() and all(torch.equal(ta[k], tb[k]) for k in ta)
    # every (phase, step) row once, in order, as in the uninterrupted run
    assert _log_keys(run) == _log_keys(tmp_path / "ref")
    assert len(set(_log_keys(run))) == len(_log_keys(run))


def test_no_readable_checkpoint_is_a_user_error(scene, tmp_path):
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train(scene, run, _cfg(), progress=False, callback=_interrupt_at(("stage1", 7)), log=None)
    for name in ("last.safetensors", "previous.safetensors"):
        p = run / "checkpoints" / name
        p.write_bytes(p.read_bytes()[:200])
    with pytest.raises(UserError, match="no checkpoint of this run can be read"):
        train(scene, run, _cfg(), progress=False, log=None)


@pytest.mark.parametrize("option", ["stage1_kernels", "dssim_per_band"])
def test_a_run_started_before_a_default_changed_resumes_with_its_own_method(scene, tmp_path, option):
    """A config.json of brfgs 0.1 written before ``option`` existed trained its old value (False: flat
    stage-1 colours, the grayscale D-SSIM): resuming it with today's default is refused naming the
    option, and resuming with the old value works."""
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train(scene, run, _cfg(**{option: False}), progress=False, callback=_interrupt_at(("stage1", 7)), log=None)
    cfg = json.loads((run / "config.json").read_text())
    del cfg[option], cfg["format_version"], cfg["mcmc"], cfg["strategy"]  # as brfgs 0.1 wrote it, before the option
    cfg["densify"].update(mode="adc", max_gaussians=cfg.pop("max_gaussians"))
    cfg.update({k: (0.2 if v is None else v) for k, v in REMOVED.items()})  # format 1 listed the removed options
    (run / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(UserError, match=option):
        train(scene, run, _cfg(), progress=False, log=None)
    (run / "config.json").write_text("{not json")
    with pytest.raises(UserError, match="unreadable run options"):
        train(scene, run, _cfg(), progress=False, log=None)
    (run / "config.json").write_text(json.dumps(cfg))
    assert train(scene, run, _cfg(**{option: False}), progress=False, log=None).is_file()


def test_evaluate_gives_the_digits_of_training(scene, tmp_path):
    run = tmp_path / "run"
    assert main(["train", str(scene), str(run), "--preset", "tiny", "--threads", "1", "--stage1-steps", "6",
                 "--stage2-steps", "4", "--quiet"]) == 0
    first = json.loads((run / "metrics.json").read_text())
    assert first["settings"]["backend"] == "torch"  # the tiny preset's
    assert main(["evaluate", str(run), "--quiet", "--no-images"]) == 0
    again = json.loads((run / "metrics.json").read_text())
    assert again["settings"]["backend"] == "torch"
    assert again["against"] == first["against"]


def test_full_disk_is_one_line_exit_3_and_no_half_file(scene, tmp_path, capsys, monkeypatch):
    """No space left while writing the model file: one line naming the path, exit status 3, no
    model.safetensors (nor its temporary file) left behind; the checkpoints survive for a resume."""
    import errno

    import safetensors.torch

    real = safetensors.torch.save_file

    def full_disk(tensors, filename, metadata=None):
        if "model" in str(filename):
            with open(filename, "wb") as fh:  # a partly written file, then the disk is full
                fh.write(b"\0" * 100)
            raise OSError(errno.ENOSPC, "No space left on device", str(filename))
        return real(tensors, filename, metadata=metadata)

    monkeypatch.setattr("brfgs.model.io.save_file", full_disk)
    run = tmp_path / "run"
    args = ["train", str(scene), str(run), "--preset", "tiny", "--threads", "1", "--stage1-steps", "4",
            "--stage2-steps", "2", "--quiet"]
    assert main(args) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "No space left on device" in err and "model" in err
    assert not (run / "model.safetensors").exists()
    assert not [p for p in run.iterdir() if "partial" in p.name]
    monkeypatch.setattr("brfgs.model.io.save_file", real)
    assert main(args) == 0 and (run / "model.safetensors").is_file()


def test_read_only_output_folder_is_exit_3(scene, tmp_path, capsys, monkeypatch):
    """A read-only file system (EROFS; injected, since tests run as root, which ignores permissions)."""
    import errno
    import pathlib

    ro = tmp_path / "ro"
    real_mkdir = pathlib.Path.mkdir

    def mkdir(self, *a, **k):
        if str(self).startswith(str(ro)):
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_mkdir(self, *a, **k)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    assert main(["train", str(scene), str(ro / "run"), "--preset", "tiny", "--quiet"]) == 3
    err = capsys.readouterr().err.strip()
    assert err == f"brfgs: error: {ro / 'run'}: Read-only file system"
    assert not ro.exists()


def test_a_run_started_with_a_fixed_cap_resumes_with_it_under_the_image_following_default(scene, tmp_path):
    """An unfinished run started with a fixed Gaussian cap (every run before the cap followed the image
    recorded 60,000) resumes under today's default (``max_gaussians`` 0) with its own cap: the model
    equals the uninterrupted run's, and config.json keeps the cap. Another fixed cap is still refused."""
    run, ref = tmp_path / "run", tmp_path / "ref"
    with pytest.raises(KeyboardInterrupt):
        train(scene, run, _cfg(max_gaussians=60000), progress=False, callback=_interrupt_at(("stage1", 7)), log=None)
    with pytest.raises(UserError, match="max_gaussians"):
        train(scene, run, _cfg(max_gaussians=6000), progress=False, log=None)
    train(scene, run, _cfg(max_gaussians=0), progress=False, log=None)
    assert json.loads((run / "config.json").read_text())["max_gaussians"] == 60000
    train(scene, ref, _cfg(max_gaussians=60000), progress=False, log=None)
    ta, tb = load(run / "model.safetensors")[0], load(ref / "model.safetensors")[0]
    assert ta.keys() == tb.keys() and [k for k in ta if not torch.equal(ta[k], tb[k])] == []
