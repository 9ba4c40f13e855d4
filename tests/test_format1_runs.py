"""Run folders written by brfgs 0.1.0 (config format 1, tests/data/format1/README.md) still evaluate,
render and resume with today's code, and resuming gives 0.1.0's own uninterrupted model bit for bit."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch

from brfgs.cli import main
from brfgs.model import TrainedModel
from brfgs.model.io import load
from test_train_scene import make_plane_scene

DATA = Path(__file__).parent / "data" / "format1"
# the options generate.py trained both runs with (the tiny preset plus these)
OPTIONS = ["--preset", "tiny", "--threads", "1", "--stage1-steps", "12", "--stage2-steps", "6", "--ae-steps", "40",
           "--init-fill-points", "150", "--checkpoint-every", "5", "--backend", "torch", "--quiet"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("f1") / "scene", w=48, h=32, n_bands=8, n_views=13)


def _copy(name: str, tmp_path: Path) -> Path:
    out = tmp_path / name
    shutil.copytree(DATA / name, out)
    return out


def test_the_fixture_is_format_1():
    cfg = json.loads((DATA / "finished" / "config.json").read_text())
    assert "format_version" not in cfg and cfg["densify"]["mode"] == "adc" and "far_field_plane" in cfg


def test_a_finished_run_evaluates_and_renders(scene, tmp_path, capsys):
    run = _copy("finished", tmp_path)
    tm = TrainedModel.load(run)
    assert tm.render_settings.decode_order == "pixel" and tm.render_settings.supersample == 1
    assert main(["evaluate", str(run), "--scene", str(scene), "--no-images", "--quiet", "--backend", "torch"]) == 0
    m = json.loads((run / "metrics.json").read_text())
    assert m["split"]["test"] and m["against"]["truth"]["mean"]["psnr"] > 10
    # the split is the one 0.1.0 trained with (its run folder recorded it)
    assert m["split"]["test"] == json.loads((DATA / "finished" / "split.json").read_text())["test"]
    assert main(["render", str(run), "--view-zenith", "20", "--view-azimuth", "45", "--out", str(tmp_path / "r"),
                 "--quiet", "--backend", "torch"]) == 0
    assert (tmp_path / "r" / "render.json").is_file()


def test_an_interrupted_run_resumes_to_the_uninterrupted_model(scene, tmp_path):
    run = _copy("interrupted", tmp_path)
    assert json.loads((run / "run.json").read_text())["status"] != "finished"
    assert main(["train", str(scene), str(run), *OPTIONS, "--no-evaluate"]) == 0
    ta, tb = load(run / "model.safetensors")[0], load(DATA / "finished" / "model.safetensors")[0]
    assert ta.keys() == tb.keys()
    assert [k for k in ta if not torch.equal(ta[k], tb[k])] == []
    assert json.loads((run / "config.json").read_text())["format_version"] == 2


def test_a_format_1_config_reruns_and_a_stage_1_checkpoint_starts_stage_2(scene, tmp_path):
    out = tmp_path / "again"
    assert main(["train", str(scene), str(out), "--config", str(DATA / "finished" / "config.json"), "--quiet",
                 "--no-evaluate"]) == 0
    ta, tb = load(out / "model.safetensors")[0], load(DATA / "finished" / "model.safetensors")[0]
    assert [k for k in ta if not torch.equal(ta[k], tb[k])] == []
    sh = tmp_path / "sh"
    assert main(["train", str(scene), str(sh), *OPTIONS, "--variant", "sh", "--from-stage1",
                 str(DATA / "finished" / "checkpoints" / "stage1.safetensors"), "--no-evaluate"]) == 0
    assert TrainedModel.load(sh).appearance == "sh"
