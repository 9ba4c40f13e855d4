"""Multi-view photometric consistency (brfgs.train.multiview): the plane homography against a
point-by-point reference, NCC against a loop, the loss's pull toward the true depth on a
synthetic textured terrain, and training with it in every phase that trains geometry."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from brfgs.data.cameras import pose_from_view_angles, project_points
from brfgs.init import mvs, plane_sweep
from brfgs.model.camera import camera_from_intrinsics
from brfgs.model.io import load
from brfgs.train.presets import preset
from brfgs.train.multiview import multiview_loss, patch_ncc, patch_offsets, plane_warp, relative_pose
from brfgs.train.trainer import train
from test_init_mvs import INTR, _render
from test_train_scene import make_plane_scene


def _cam(z, a, d=60.0):
    return camera_from_intrinsics(pose_from_view_angles(z, a, d), INTR)


def test_plane_warp_against_points_on_the_plane():
    ref, nbr = _cam(10.0, 30.0), _cam(35.0, 150.0)
    rot, trans = relative_pose(ref, nbr)
    g = torch.Generator().manual_seed(0)
    xy = torch.rand(20, 2, generator=g) * 40 + 4
    depth = 55 + 5 * torch.rand(20, generator=g)
    normal = torch.nn.functional.normalize(torch.randn(20, 3, generator=g) + torch.tensor([0, 0, -3.0]), dim=-1)
    offs = patch_offsets(2)
    uv, z = plane_warp(xy, depth, normal, offs, ref.K, nbr.K, rot, trans)
    # reference: intersect each patch ray with the plane in reference camera coordinates, go to the world, project
    kinv = np.linalg.inv(ref.K.double().numpy())
    c2w_ref = np.linalg.inv(ref.viewmat.double().numpy())
    for n in range(20):
        x_c = np.append(xy[n].double().numpy(), 1.0) @ kinv.T * float(depth[n])
        nn = normal[n].double().numpy()
        for p in range(offs.shape[0]):
            ray = np.append((xy[n] + offs[p]).double().numpy(), 1.0) @ kinv.T
            pt = ray * (nn @ x_c) / (nn @ ray)
            world = c2w_ref[:3, :3] @ pt + c2w_ref[:3, 3]
            want, _ = project_points(world[None], pose_from_view_angles(35.0, 150.0, 60.0), INTR)
            np.testing.assert_allclose(uv[n, p].double().numpy(), want[0], atol=2e-3)
    assert bool((z > 0).all())


def test_patch_ncc_against_a_loop():
    g = torch.Generator().manual_seed(1)
    a, b = torch.rand(3, 9, 2, generator=g, dtype=torch.float64), torch.rand(3, 9, 2, generator=g, dtype=torch.float64)
    got, _ = patch_ncc(a, b)
    for n in range(3):
        da, db = (a[n] - a[n].mean(0)).numpy(), (b[n] - b[n].mean(0)).numpy()
        assert float(got[n]) == pytest.approx((da * db).sum() / np.sqrt((da * da).sum() * (db * db).sum()), abs=1e-9)
    assert torch.allclose(patch_ncc(a, 2 * a + 1)[0], torch.ones(3, dtype=torch.float64))


def test_loss_is_lowest_at_the_true_depth_and_pulls_toward_it():
    angles = [(0.0, 0.0), (20.0, 0.0), (20.0, 90.0), (20.0, 180.0)]
    c2w = [pose_from_view_angles(z, a, 60.0) for z, a in angles]
    rendered = [_render(m) for m in c2w]
    cams = [camera_from_intrinsics(m, INTR) for m in c2w]
    target = torch.as_tensor(rendered[0][0])
    depth = torch.as_tensor(rendered[0][1]).float()
    # the terrain's normals, in camera axes of the nadir view, from the true depth map
    pts = plane_sweep.backproject(depth.double(), INTR, *plane_sweep.cv_pose(c2w[0]))
    n_world = mvs.depth_normals(pts, plane_sweep.cv_pose(c2w[0])[1])
    n_cam = (n_world @ plane_sweep.cv_pose(c2w[0])[0]).float()  # world -> camera axes: Rᵀ n
    alpha = torch.ones_like(depth)
    valid = torch.ones_like(depth, dtype=torch.bool)
    nbrs = [(cams[j], torch.as_tensor(rendered[j][0])) for j in (1, 2, 3)]

    def loss(shift):
        d = (depth + shift).requires_grad_(True)
        out = multiview_loss(d, n_cam, alpha, target, valid, cams[0], nbrs, torch.Generator().manual_seed(0),
                             n_pixels=600)
        out.backward()
        return float(out.detach()), float(d.grad.sum())

    l0, _ = loss(0.0)
    lp, gp = loss(0.6)
    lm, gm = loss(-0.6)
    assert l0 < 0.05 and lp > 2 * l0 and lm > 2 * l0
    assert gp > 0 > gm  # descent moves a surface that is too far back nearer, and one too near back


@pytest.mark.parametrize("kw", [{}, {"joint": True}, {"variant": "cir"}], ids=["decoupled", "joint", "cir"])
def test_training_with_the_loss_in_each_geometry_phase(tmp_path, kw):
    """The neighbours' images come from the same store as the batch's target (stage-1 bands, all
    bands or CIR composites), so each phase that trains geometry runs with the loss on."""
    torch.set_num_threads(1)
    scene = make_plane_scene(tmp_path / "scene", w=48, h=40, n_bands=12)
    cfg = preset("tiny", threads=1, stage1_steps=8, stage2_steps=4, lambda_multiview=0.1, normal_start=0.0, **kw)
    tensors = load(train(scene, tmp_path / "run", cfg, progress=False, log=None))[0]
    assert all(bool(torch.isfinite(t).all()) for t in tensors.values() if t.is_floating_point())
