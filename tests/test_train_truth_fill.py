"""``--init-fill truth`` (training on a simulated scene's true geometry, an upper bound for a setting):
its points lie on the true surface, its dense-depth targets are the truth depth maps of the training
views, both are seeded, and it trains from the command line."""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest
from test_init_toy_scene import height_m, make_toy_scene

from brfgs.cli import main
from brfgs.data import read_scene
from brfgs.errors import UserError
from brfgs.train import setup as mod
from brfgs.train.dense_depth import load_dense_depth


def _fill(mod, scene, out: Path, n: int, seed: int = 0) -> np.ndarray:
    (out / "init").mkdir(parents=True, exist_ok=True)
    cfg = types.SimpleNamespace(init_fill_points=n, seed=seed)
    return mod.truth_fill(None, scene, cfg, types.SimpleNamespace(out=out), lambda msg: None)


def test_truth_fill_on_the_true_surface(tmp_path):
    scene = read_scene(make_toy_scene(tmp_path / "toy", size=32, n_bands=6, n_views=13))
    pts = _fill(mod, scene, tmp_path / "a", 500)  # [M, 3] m
    assert pts.shape == (500, 3)
    assert np.abs(pts[:, 2] - height_m(pts[:, 0], pts[:, 1])).max() < 0.02  # the analytic surface
    keys = np.floor(pts / mod.TRUTH_VOXEL_M).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(pts)  # one point per voxel
    np.testing.assert_array_equal(pts, _fill(mod, scene, tmp_path / "b", 500))  # seeded
    assert not np.array_equal(pts, _fill(mod, scene, tmp_path / "c", 500, seed=1))
    tr = list(scene.train_indices)
    dd = load_dense_depth(tmp_path / "a" / "init", [f.name for f in scene.frames], tr, scene.height, scene.width)
    assert sorted(dd.by_frame) == sorted(tr)
    for i in tr:  # the dense-depth targets are the truth maps
        truth = np.load(scene.truth_dir / "depth" / f"{scene.frames[i].name}.npy")
        np.testing.assert_array_equal(dd.by_frame[i].numpy(), truth.astype(np.float32))


def test_truth_fill_without_truth_is_a_user_error(tmp_path):
    scene = read_scene(make_toy_scene(tmp_path / "toy", size=32, n_bands=6, n_views=13, with_truth=False))
    with pytest.raises(UserError, match="truth depth"):
        _fill(mod, scene, tmp_path / "a", 500)


def test_training_on_the_true_geometry_from_the_command_line(tmp_path, capsys):
    root = make_toy_scene(tmp_path / "toy", size=32, n_bands=6, n_views=13)
    out = tmp_path / "run"
    assert main(["train", str(root), str(out), "--preset", "tiny", "--init-fill", "truth", "--init-fill-points", "300",
                 "--lambda-dense-depth", "1", "--stage1-steps", "6", "--stage2-steps", "2", "--threads", "1",
                 "--quiet", "--no-evaluate"]) == 0
    assert (out / "init" / "dense_depths.npz").is_file()
    assert main(["train", str(root), str(tmp_path / "bad"), "--preset", "tiny", "--lambda-dense-depth", "1",
                 "--quiet"]) == 2
    assert "lambda_dense_depth" in capsys.readouterr().err
