"""Coarse-to-fine geometry (``--coarse-levels``): the block-averaged photometric loss and its schedule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from brfgs.cli import main
from brfgs.train import step as step_mod
from brfgs.train.config import TrainConfig
from brfgs.train.losses import area_pool
from brfgs.train.phases import Phase
from test_train_scene import make_plane_scene


def _pool_reference(pred, target, valid, f):
    """float64 loops: the mean of each complete f x f block; a block is valid when all its pixels are."""
    h, w = pred.shape[0] // f, pred.shape[1] // f
    p = np.zeros((h, w, pred.shape[2]))
    t = np.zeros_like(p)
    v = np.zeros((h, w), dtype=bool)
    for i in range(h):
        for j in range(w):
            blk = (slice(i * f, (i + 1) * f), slice(j * f, (j + 1) * f))
            p[i, j] = pred[blk].reshape(-1, pred.shape[2]).mean(0)
            v[i, j] = valid[blk].all()
            if v[i, j]:
                t[i, j] = target[blk].reshape(-1, pred.shape[2]).mean(0)
    return p, t, v


@pytest.mark.parametrize("f", [2, 3, 4])
def test_area_pool_matches_a_float64_loop(f):
    rng = np.random.default_rng(f)
    pred, target = rng.random((11, 13, 3)), rng.random((11, 13, 3))
    valid = rng.random((11, 13)) > 0.15
    target[~valid] = np.nan  # invalid pixels may hold anything
    p, t, v = area_pool(torch.tensor(pred), torch.tensor(target), torch.tensor(valid), f)
    rp, rt, rv = _pool_reference(pred, target, valid, f)
    assert p.shape == (11 // f, 13 // f, 3) and v.shape == (11 // f, 13 // f)
    np.testing.assert_allclose(p.numpy(), rp, rtol=1e-12)
    np.testing.assert_array_equal(v.numpy(), rv)
    np.testing.assert_allclose(t.numpy()[rv], rt[rv], rtol=1e-12)
    assert np.isfinite(t.numpy()).all()


def test_area_pool_gradient_and_identity():
    rng = np.random.default_rng(0)
    pred = torch.tensor(rng.random((8, 6, 2)), requires_grad=True)
    target = torch.tensor(rng.random((8, 6, 2)))
    valid = torch.ones(8, 6, dtype=torch.bool)
    assert torch.autograd.gradcheck(lambda x: area_pool(x, target, valid, 2)[0], (pred,))
    same = area_pool(pred, target, valid, 1)
    assert same[0] is pred and same[1] is target and same[2] is valid


def test_pooled_loss_has_a_wider_basin_for_a_shifted_texture():
    """Pixel-scale (white) texture shifted by two pixels: at full resolution the error is that of an
    unrelated image (correlation 0); the 4 x 4 block means still share half their pixels."""
    rng = np.random.default_rng(1)
    tex = torch.tensor(rng.random((64, 66, 1)))
    truth, shifted = tex[:, 2:66], tex[:, :64]
    valid = torch.ones(64, 64, dtype=torch.bool)

    def corr(f):  # correlation of the pooled images
        pa, pb, _ = area_pool(shifted, truth, valid, f)
        return float(np.corrcoef(pa.numpy().ravel(), pb.numpy().ravel())[0, 1])

    assert abs(corr(1)) < 0.1 and 0.35 < corr(4) < 0.65


def test_coarse_schedule_falls_to_full_resolution():
    cfg = TrainConfig(coarse_levels=2, coarse_until=0.2)
    f = [step_mod.coarse_factor_now(cfg, Phase.STAGE1, k, 100) for k in (0, 9, 10, 19, 20, 99)]
    assert f == [4, 4, 2, 2, 1, 1]
    assert step_mod.coarse_factor_now(cfg, Phase.STAGE2, 0, 100) == 1  # geometry phases only
    assert step_mod.coarse_factor_now(cfg, Phase.CIR, 0, 100) == 4
    assert step_mod.coarse_factor_now(TrainConfig(), Phase.STAGE1, 0, 100) == 1  # off by default
    three = TrainConfig(coarse_levels=3, coarse_until=0.3)
    assert [step_mod.coarse_factor_now(three, Phase.STAGE1, k, 100) for k in (0, 10, 20, 30)] == [8, 4, 2, 1]


def test_coarse_run_pools_early_stage_1_only(tmp_path, monkeypatch):
    torch.set_num_threads(1)
    scene = make_plane_scene(tmp_path / "scene", w=48, h=40, n_bands=8)
    seen, orig = [], step_mod.area_pool
    monkeypatch.setattr(step_mod, "area_pool", lambda p, t, v, f: seen.append(f) or orig(p, t, v, f))
    assert main(["train", str(scene), str(tmp_path / "run"), "--preset", "tiny", "--stage1-steps", "10",
                 "--stage2-steps", "2", "--coarse-levels", "2", "--coarse-until", "0.4", "--threads", "1",
                 "--quiet", "--no-evaluate"]) == 0
    assert seen == [4, 4, 2, 2] + [1] * 6
    for bad in (["--coarse-levels", "-1"], ["--coarse-levels", "9"], ["--coarse-until", "0"]):
        assert main(["train", str(scene), str(tmp_path / "bad"), "--quiet", *bad]) == 2
    assert not (tmp_path / "bad").exists()
