"""Dense initialisation (--init-fill mvs) and the dense-depth loss: the loss against a loop
reference with gradients, the depth-map file, and a training run that uses both and resumes."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from plyfile import PlyData

from brfgs.errors import UserError
from brfgs.model.io import load
from brfgs.train.presets import preset
from brfgs.train.dense_depth import FILE, dense_depth_loss, load_dense_depth, save_dense_depths, upsample_nearest
from brfgs.train.trainer import train
from test_train_pipeline import _differing
from test_train_scene import make_plane_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("plane") / "scene", w=48, h=40, n_bands=12)


def test_dense_depth_loss_against_a_loop_with_gradients():
    g = torch.Generator().manual_seed(0)
    alpha = torch.rand(6, 7, dtype=torch.float64, generator=g)
    depth = (20 + 5 * torch.rand(6, 7, dtype=torch.float64, generator=g)) * alpha
    target = 20 + 5 * torch.rand(6, 7, dtype=torch.float64, generator=g)
    target[0, :3] = float("nan")
    want, n = 0.0, 0
    for i in range(6):
        for j in range(7):
            if np.isfinite(float(target[i, j])) and float(alpha[i, j]) > 0.5:
                want += abs(float(depth[i, j] / alpha[i, j]) - float(target[i, j])) / float(target[i, j])
                n += 1
    assert float(dense_depth_loss(depth, alpha, target)) == pytest.approx(want / n, rel=1e-12)
    d, a = depth.clone().requires_grad_(True), alpha.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x, y: dense_depth_loss(x, y, target), (d, a))
    none = torch.full_like(target, float("nan"))
    assert float(dense_depth_loss(depth, alpha, none)) == 0.0


def test_depth_maps_round_trip_and_resample(tmp_path):
    maps = [np.arange(6, dtype=np.float32).reshape(2, 3), np.full((2, 3), np.nan, np.float32)]
    save_dense_depths(tmp_path / FILE, ["a", "b"], maps)
    dd = load_dense_depth(tmp_path, ["x", "b", "a"], [1, 2], 4, 6)
    assert set(dd.by_frame) == {1, 2}
    np.testing.assert_array_equal(dd.by_frame[2].numpy(), upsample_nearest(maps[0], 4, 6))
    np.testing.assert_array_equal(upsample_nearest(maps[0], 4, 6)[::2, ::2], maps[0])
    (tmp_path / FILE).write_bytes(b"not a zip")
    with pytest.raises(UserError, match="stereo depth maps"):
        load_dense_depth(tmp_path, ["a"], [0], 2, 3)
    with pytest.raises(UserError, match="needs the stereo depth maps"):
        load_dense_depth(tmp_path / "none", ["a"], [0], 2, 3)


def test_option_needs_the_dense_fill():
    with pytest.raises(UserError, match="init-fill mvs"):
        preset("fast", lambda_dense_depth=1.0)
    with pytest.raises(UserError, match="init_fill"):
        preset("fast", init_fill="voxels")


def test_training_with_dense_init_and_depth_loss_resumes(scene, tmp_path):
    """A run seeded by dense stereo of the plane scene (every point near z = 0) with the dense-depth
    loss, interrupted in stage 1 (the depth maps reloaded from the run folder), ends where the
    uninterrupted run ends."""
    cfg = preset("tiny", threads=1, stage1_steps=30, stage2_steps=6, init_fill="mvs", init_fill_points=800,
                 lambda_dense_depth=1.0, normal_start=0.0, checkpoint_every=1000)
    b = tmp_path / "b"

    def copy_setup(phase, step):
        if (phase, step) == ("stage1", 1):
            shutil.copytree(tmp_path / "a", b)

    ref = train(scene, tmp_path / "a", cfg, progress=False, callback=copy_setup, log=None)
    init = tmp_path / "a" / "init"
    report = json.loads((init / "dense.json").read_text())
    assert 0 < report["points"] <= 800 and report["stereo_points"] > 0
    z = np.asarray(PlyData.read(str(init / "dense.ply"))["vertex"]["z"])
    assert len(z) == report["points"] and np.median(np.abs(z)) < 0.3  # the plane scene lies at z = 0
    with np.load(init / FILE) as f:
        assert f["depths"].shape[0] == len(f["names"]) > 0

    def stop(phase, step):
        if (phase, step) == ("stage1", 12):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(scene, b, cfg, progress=False, callback=stop, log=None)
    ta, tb = load(ref)[0], load(train(scene, b, cfg, progress=False, log=None))[0]
    assert ta.keys() == tb.keys()
    bad = _differing(ta, tb, lambda a, b: torch.allclose(a, b, atol=1e-6, rtol=1e-5))
    assert not bad, bad
