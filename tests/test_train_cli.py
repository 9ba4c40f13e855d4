"""CLI: brfgs train / evaluate / ablate in-process on a tiny scene; metrics.json schema."""

import json

import pytest
import torch

from brfgs.cli import main
from test_train_scene import make_plane_scene

KEYS = ("psnr", "ssim", "lpips", "sam", "psnr_spectral")
TINY = ["--preset", "tiny", "--quiet", "--threads", "1", "--stage1-steps", "6", "--stage2-steps", "4"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("cli") / "scene", w=64, h=48, n_bands=12)


def _check_block(block, n_test, spectral=True):
    assert len(block["views"]) == n_test
    for m in [block["mean"], *block["views"]]:
        for k in KEYS:
            assert k in m
            if m[k] is None:
                assert m[f"{k}_reason"]
        if spectral:
            assert m["sam"] is not None and 0 <= m["sam"] < 1.6
        assert m["psnr"] is not None and m["ssim"] is not None


def test_train_evaluate_cli(scene, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", str(scene), str(out), *TINY]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["scene"] == "scene" and m["model"] == "BRF-GS"
    assert m["split"]["test"] == ["view_02", "view_10"]
    _check_block(m["against"]["observed"], 2)
    _check_block(m["against"]["truth"], 2)
    assert m["settings"]["config"]["stage1_steps"] == 6
    assert (out / "eval" / "renders" / "view_02.hdr").is_file()
    assert (out / "eval" / "cir" / "view_02_vs_truth.png").is_file()
    # a finished run is never overwritten without --overwrite (exit status 2, message)
    assert main(["train", str(scene), str(out), *TINY]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["evaluate", str(out), "--quiet", "--no-images", "--backend", "torch"]) == 0
    # 3DGS-on-CIR baseline: no spectra, SAM null with reason
    out2 = tmp_path / "cir"
    assert main(["train", str(scene), str(out2), *TINY, "--variant", "cir"]) == 0
    m2 = json.loads((out2 / "metrics.json").read_text())
    _check_block(m2["against"]["truth"], 2, spectral=False)
    assert m2["against"]["truth"]["mean"]["sam"] is None and "CIR" in m2["against"]["truth"]["mean"]["sam_reason"]


def test_bad_options_are_user_errors(scene, tmp_path, capsys):
    assert main(["train", str(scene), str(tmp_path / "x"), "--variant", "nope", "--quiet"]) == 2
    assert "variant" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing"), "--quiet"]) == 2
    for opts, field in ((["--stage1-sh-degree", "4"], "stage1_sh_degree"), (["--lambda-normal", "-1"], "lambda_normal"),
                        (["--lambda-flat", "-0.1"], "lambda_flat"), (["--lambda-depth-smooth", "-1"], "lambda_depth_smooth"),
                        (["--lambda-depth-conc", "-1"], "lambda_depth_conc"), (["--lr-spec", "0"], "lr_spec")):
        capsys.readouterr()
        assert main(["train", str(scene), str(tmp_path / "y"), *opts, "--quiet"]) == 2
        assert field in capsys.readouterr().err
        assert not (tmp_path / "y" / "run.json").exists()


def test_ablate_training_cli(scene, tmp_path):
    out = tmp_path / "abl"
    assert main(["ablate", str(scene), str(out), "--study", "training", "--preset", "tiny", "--quiet",
                 "--threads", "1", "--stage1-steps", "4", "--stage2-steps", "4"]) == 0
    md = (out / "table_training.md").read_text()
    assert "Joint optimization" in md and "BRF-GS (Full)" in md
    csv = (out / "table_training.csv").read_text().splitlines()
    assert len(csv) == 3 and "sam_truth" in csv[0]
