"""The sparse-depth loss (brfgs.train.sparse_depth): projection against a float64 pinhole
reference, bilinear sampling against scipy, the loss against a loop reference with gradients,
its pull on a ground placed at the wrong height, and reading the tracks of an initialisation."""

import numpy as np
import pytest
import torch
from scipy.ndimage import map_coordinates

from brfgs.data.cameras import Intrinsics, pose_from_view_angles, viewmat_from_c2w
from brfgs.errors import UserError
from brfgs.init.outputs import write_points_ply, write_tracks
from brfgs.model.camera import camera_from_c2w
from brfgs.model.features import camera_depth_normals
from brfgs.model.gaussians import init_from_points
from brfgs.model.rendering import rasterize_features
from brfgs.train.sparse_depth import (SparseDepth, load_sparse_depth, project_points, sample_bilinear,
                                      sparse_depth_loss)


def _camera(zenith=35.0, azimuth=60.0, size=(24, 18)):
    intr = Intrinsics.from_fov(40.0, *size)
    c2w = pose_from_view_angles(zenith, azimuth, 30.0)
    return camera_from_c2w("v", c2w, intr.K(), size[0], size[1]), c2w, intr


def test_projection_matches_a_float64_pinhole():
    cam, c2w, intr = _camera()
    rng = np.random.default_rng(0)
    pts = rng.uniform(-12, 12, (400, 3)) * [1, 1, 0.2]
    xy, z = project_points(torch.as_tensor(pts, dtype=torch.float32), cam)
    vm = viewmat_from_c2w(c2w)  # OpenCV world -> camera, float64
    pc = pts @ vm[:3, :3].T + vm[:3, 3]
    uv = pc[:, :2] / pc[:, 2:] @ intr.K()[:2, :2].T + intr.K()[:2, 2]
    inside = (pc[:, 2] > 0) & (uv[:, 0] >= 0.5) & (uv[:, 0] <= 23.5) & (uv[:, 1] >= 0.5) & (uv[:, 1] <= 17.5)
    assert 50 < inside.sum() < 400
    np.testing.assert_allclose(xy.numpy(), uv[inside], atol=2e-3)
    np.testing.assert_allclose(z.numpy(), pc[inside, 2], rtol=1e-5)


def test_bilinear_sampling_matches_scipy_and_has_gradients():
    rng = np.random.default_rng(1)
    img = torch.tensor(rng.normal(size=(7, 9, 2)), dtype=torch.float64, requires_grad=True)
    xy = torch.tensor(rng.uniform(0.5, [8.5, 6.5], (40, 2)), dtype=torch.float64)
    got = sample_bilinear(img, xy)  # [40, 2]
    for c in range(2):  # scipy's order-1 map_coordinates takes (row, col) with pixel centres at integers
        ref = map_coordinates(img.detach().numpy()[..., c], [xy[:, 1].numpy() - 0.5, xy[:, 0].numpy() - 0.5], order=1)
        np.testing.assert_allclose(got[:, c].detach().numpy(), ref, atol=1e-12)
    assert torch.autograd.gradcheck(lambda im: sample_bilinear(im, xy), (img,))


def test_loss_matches_a_loop_reference_and_gradients():
    rng = np.random.default_rng(2)
    alpha = torch.tensor(rng.uniform(0.2, 1.0, (6, 8)), dtype=torch.float64, requires_grad=True)
    depth = torch.tensor(rng.uniform(20, 40, (6, 8)), dtype=torch.float64)
    prem = (depth * alpha).detach().requires_grad_(True)
    xy = torch.tensor(rng.uniform(0.5, [7.5, 5.5], (30, 2)), dtype=torch.float64)
    target = torch.tensor(rng.uniform(20, 40, 30), dtype=torch.float64)
    got = sparse_depth_loss(prem, alpha, xy, target)
    vals = []
    for (x, y), t in zip(xy.numpy(), target.numpy()):
        def bil(a):
            return map_coordinates(a, [[y - 0.5], [x - 0.5]], order=1)[0]
        a = bil(alpha.detach().numpy())
        if a > 0.5:
            vals.append(abs(bil(prem.detach().numpy()) / a - t) / t)
    assert float(got.detach()) == pytest.approx(np.mean(vals), rel=1e-10)
    assert torch.autograd.gradcheck(lambda p, a: sparse_depth_loss(p, a, xy, target), (prem, alpha))
    # the limit case: a rendered depth equal to every point's depth costs nothing
    ones = torch.ones(6, 8, dtype=torch.float64)
    assert float(sparse_depth_loss(depth, ones, xy, sample_bilinear(depth[..., None], xy)[:, 0])) < 1e-12


def test_loss_pulls_a_ground_placed_too_high_onto_the_sparse_points():
    """Flat Gaussians 0.5 m above the sparse points' plane z = 0: the loss alone moves them down."""
    g = (np.arange(10) + 0.5) / 10 * 12 - 6
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    m = init_from_points(np.concatenate([xy, np.full((len(xy), 1), 0.5)], 1), np.full((len(xy), 3), 0.5), latent_dim=2)
    with torch.no_grad():
        m.params["log_scales"].copy_(torch.log(torch.tensor([[0.8, 0.8, 0.05]])).expand(len(xy), 3))
        m.params["opacity_logits"].fill_(3.0)
    rng = np.random.default_rng(3)
    sparse = np.concatenate([rng.uniform(-4, 4, (60, 2)), np.zeros((60, 1))], 1)
    cams = [_camera(z, a, (20, 20))[0] for z, a in [(0, 0), (30, 90), (40, 200)]]
    sd = SparseDepth.from_tracks(sparse, np.repeat(np.arange(3), 60), np.tile(np.arange(60), 3), [0, 1, 2])

    def loss(k):
        out = rasterize_features(m, camera_depth_normals(m, cams[k])[:, :1], cams[k], backend="cpu")
        return sparse_depth_loss(out.image[..., 0], out.alpha, *sd.targets(k, cams[k]))

    before = float(loss(0))
    opt = torch.optim.Adam([m.params["means"]], lr=0.02)
    for step in range(40):
        opt.zero_grad()
        loss(step % 3).backward()
        opt.step()
    assert before > 0.01 and float(loss(0)) < 0.35 * before
    assert abs(float(m.means[:, 2].mean())) < 0.2


def test_tracks_round_trip_and_errors(tmp_path):
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5], [3.0, -1.0, 0.2]])
    write_points_ply(tmp_path / "points.ply", pts, np.full((3, 1), 0.1), [550.0], [3])
    # frames of the file in another order than the scene's: mapped by name
    write_tracks(tmp_path / "tracks.npz", [0, 0, 1, 2], [0, 1, 1, 2], ["b", "a", "c"])
    sd = load_sparse_depth(tmp_path, ["a", "b", "c"], train_indices=[0, 1])
    assert sorted(sd.by_frame) == [0, 1]  # "c" is not a training frame
    assert sd.by_frame[1].tolist() == [0, 1] and sd.by_frame[0].tolist() == [1]
    np.testing.assert_allclose(sd.points.numpy(), pts, atol=1e-6)
    write_tracks(tmp_path / "tracks.npz", [0], [7], ["a"])
    with pytest.raises(UserError, match="tracks.npz.*obs_point"):
        load_sparse_depth(tmp_path, ["a"], [0])
    (tmp_path / "tracks.npz").unlink()
    with pytest.raises(UserError, match="lambda_sparse_depth"):
        load_sparse_depth(tmp_path, ["a"], [0])
