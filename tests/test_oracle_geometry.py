"""scripts/oracle_geometry.py (Session 50's upper bound): its points lie on the true surface, its
dense-depth targets are the truth depth maps of the training views, and both are seeded."""

from __future__ import annotations

import importlib.util
import types
from pathlib import Path

import numpy as np
import pytest
from test_init_toy_scene import height_m, make_toy_scene

from brfgs.data import read_scene
from brfgs.errors import UserError
from brfgs.train.dense_depth import load_dense_depth

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "oracle_geometry.py"


def _oracle():
    spec = importlib.util.spec_from_file_location("oracle_geometry", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _fill(mod, scene, out: Path, n: int, seed: int = 0) -> np.ndarray:
    (out / "init").mkdir(parents=True, exist_ok=True)
    cfg = types.SimpleNamespace(init_fill_points=n, seed=seed)
    return mod.truth_fill(None, scene, cfg, None, None, types.SimpleNamespace(out=out), lambda msg: None)


def test_truth_fill_on_the_true_surface(tmp_path):
    scene = read_scene(make_toy_scene(tmp_path / "toy", size=32, n_bands=6, n_views=13))
    mod = _oracle()
    pts = _fill(mod, scene, tmp_path / "a", 500)  # [M, 3] m
    assert pts.shape == (500, 3)
    assert np.abs(pts[:, 2] - height_m(pts[:, 0], pts[:, 1])).max() < 0.02  # the analytic surface
    keys = np.floor(pts / mod.VOXEL_M).astype(np.int64)
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
        _fill(_oracle(), scene, tmp_path / "a", 500)
