"""Dense plane-sweep stereo (brfgs.init.mvs): each piece against a simple reference, and the whole
against a synthetic textured terrain whose depth is known exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from brfgs.data.cameras import Intrinsics, pixel_rays, pose_from_view_angles, project_points
from brfgs.init import mvs, plane_sweep

INTR = Intrinsics.from_fov(35.0, 48, 48)
ANGLES = [(0.0, 0.0)] + [(20.0, a) for a in range(0, 360, 45)] + [(40.0, a) for a in range(0, 360, 60)]


def _texture(xy: np.ndarray) -> np.ndarray:  # [N, 2] m -> [N, 3] reflectance-like, band-limited
    x, y = xy[:, 0], xy[:, 1]
    a = 0.3 + 0.1 * np.sin(1.3 * x) * np.cos(0.9 * y) + 0.06 * np.sin(0.37 * x + 2.1 * y)
    b = 0.25 + 0.08 * np.cos(0.7 * x - 1.1 * y) + 0.05 * np.sin(2.3 * x) * np.sin(0.5 * y)
    c = 0.2 + 0.07 * np.sin(0.8 * y + 0.3) * np.cos(1.7 * x)
    return np.stack([a, b, c], 1)


def _height(xy: np.ndarray) -> np.ndarray:  # [N, 2] m -> [N] m: a smooth hill
    return 4.0 * np.exp(-((xy[:, 0] - 5.0) ** 2 + (xy[:, 1] + 3.0) ** 2) / 120.0)


def _render(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image [H, W, 3] and true camera depth [H, W] of the textured hill, by marching each ray
    (1 cm steps near the surface after a coarse search), independent of brfgs.init.mvs."""
    o, d = pixel_rays(c2w, INTR)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    t = (0.0 - o[:, 2]) / d[:, 2] - 20.0 / np.abs(d[:, 2])  # start well above the terrain
    for step in (1.0, 0.1, 0.01, 0.001):
        for _ in range(400):
            p = o + t[:, None] * d
            above = p[:, 2] > _height(p[:, :2])
            if not above.any():
                break
            t = np.where(above, t + step, t)
        t = t - step  # back above, refine with a finer step
    t = t + 0.0005
    p = o + t[:, None] * d
    fwd = -c2w[:3, 2]
    depth = (t * (d @ fwd)).reshape(INTR.h, INTR.w)
    return _texture(p[:, :2]).reshape(INTR.h, INTR.w, 3).astype(np.float32), depth


@pytest.fixture(scope="module")
def terrain():
    torch.set_num_threads(1)
    c2w = [pose_from_view_angles(z, a, 60.0) for z, a in ANGLES]
    rendered = [_render(m) for m in c2w]
    return c2w, [r[0] for r in rendered], [r[1] for r in rendered]


def test_box_mean_is_avg_pool_without_padding():
    x = torch.rand(2, 3, 17, 23, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    for k in (1, 3, 5, 7):
        ref = F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=False)
        assert torch.allclose(plane_sweep.box_mean(x, k), ref, atol=1e-12)


def test_windowed_ncc_against_a_loop():
    g = np.random.default_rng(1)
    a, b = g.random((1, 2, 9, 11)), g.random((1, 2, 9, 11))
    got = plane_sweep.windowed_ncc(torch.as_tensor(a), torch.as_tensor(b), 3)[0].numpy()
    ref = np.zeros((9, 11))
    for i in range(9):
        for j in range(11):
            pa = a[0, :, max(i - 1, 0):i + 2, max(j - 1, 0):j + 2]
            pb = b[0, :, max(i - 1, 0):i + 2, max(j - 1, 0):j + 2]
            da = pa - pa.mean(axis=(1, 2), keepdims=True)
            db = pb - pb.mean(axis=(1, 2), keepdims=True)
            ref[i, j] = (da * db).sum() / np.sqrt((da * da).sum() * (db * db).sum())
    np.testing.assert_allclose(got, ref, atol=1e-10)
    # limit cases: gain and offset do not matter; a negative copy scores -1; a flat window 0
    ta = torch.as_tensor(a)
    assert torch.allclose(plane_sweep.windowed_ncc(ta, 3.0 * ta + 0.5, 3), torch.ones(1, 9, 11, dtype=torch.float64))
    assert torch.allclose(plane_sweep.windowed_ncc(ta, -ta, 3), -torch.ones(1, 9, 11, dtype=torch.float64))
    assert float(plane_sweep.windowed_ncc(ta, torch.zeros_like(ta), 3).abs().max()) == 0.0


def test_best_half_mean_against_a_loop():
    g = np.random.default_rng(2)
    s, v = g.uniform(-1, 1, (5, 40)), g.random((5, 40)) > 0.3
    got = plane_sweep.best_half_mean(torch.as_tensor(s), torch.as_tensor(v)).numpy()
    for j in range(40):
        vals = np.sort(s[v[:, j], j])[::-1]
        want = vals[: (len(vals) + 1) // 2].mean() if len(vals) >= 2 else -1.0
        assert got[j] == pytest.approx(want, abs=1e-12)


def test_plane_depths_and_backprojection_land_on_the_plane():
    pose = plane_sweep.cv_pose(pose_from_view_angles(30.0, 70.0, 50.0))
    rays = plane_sweep.reference_rays(INTR, pose)
    normal = torch.tensor([0.2, -0.1, 0.97], dtype=torch.float64)
    normal = normal / normal.norm()
    d = plane_sweep.plane_depths(rays, pose[1], normal, torch.tensor([1.5], dtype=torch.float64))[0]
    pts = plane_sweep.backproject(d, INTR, *pose)
    assert torch.allclose(pts @ normal, torch.full_like(d, 1.5), atol=1e-9)
    uv, z = plane_sweep.project(pts, INTR, *pose)  # back to the same pixels and depths
    assert torch.allclose(uv, plane_sweep.pixel_grid(INTR)[..., :2], atol=1e-7) and torch.allclose(z, d, atol=1e-9)
    uv_np, z_np = project_points(pts.reshape(-1, 3).numpy(), pose_from_view_angles(30.0, 70.0, 50.0), INTR)
    np.testing.assert_allclose(uv_np, uv.reshape(-1, 2).numpy(), atol=1e-7)


def test_depth_map_recovers_a_textured_hill(terrain):
    c2w, images, truth = terrain
    poses = [plane_sweep.cv_pose(m) for m in c2w]
    views = mvs._prepare(images, 1)
    heights = torch.linspace(-1.0, 5.0, 64, dtype=torch.float64)
    for r, nb in ((0, [1, 3, 5, 7]), (9, [0, 1, 2, 10])):
        d, s = plane_sweep.depth_map(views[r], views[nb], INTR, poses[r], [poses[j] for j in nb],
                             [plane_sweep.horizontal(heights)], window_px=5)
        inner = (slice(4, -4), slice(4, -4))
        err = np.abs(d.numpy() - truth[r])[inner]
        sure = np.isfinite(err) & (s[inner].numpy() > 0.8)  # no depth where fewer than two neighbours see
        assert sure.mean() > 0.85
        err = err[sure]
        assert np.median(err) < 0.05 and np.percentile(err, 95) < 0.3, (r, np.median(err), np.percentile(err, 95))


def test_dense_cloud_keeps_consistent_depths_and_fills_the_rest(terrain):
    c2w, images, truth = terrain
    sparse = np.array([[x, y, float(_height(np.array([[x, y]]))[0])] for x in range(-15, 16, 5)
                       for y in range(-15, 16, 5)])
    cloud = mvs.dense_cloud(images, c2w, INTR, sparse, mvs.MVSConfig(planes=48, level_planes=64, max_points=4000))
    assert len(cloud.points) <= 4000 and cloud.normals.shape == cloud.points.shape
    for d, t in zip(cloud.depths, truth):  # kept stereo depths are right
        ok = np.isfinite(d)
        assert ok.mean() > 0.5
        assert np.median(np.abs(d[ok] - t[ok])) < 0.05
    # every fused point (stereo or hole-filled) lies on the terrain; normals point up
    dz = cloud.points[:, 2] - _height(cloud.points[:, :2])
    assert np.percentile(np.abs(dz), 90) < 0.3
    up = cloud.normals[:, 2]
    assert np.median(up) > 0.95
    assert cloud.report["points_fused"] >= cloud.report["points"]


def test_fill_holes_meets_a_level_height_field():
    pose = plane_sweep.cv_pose(pose_from_view_angles(50.0, 200.0, 80.0))
    depth = torch.full((INTR.h, INTR.w), float("nan"), dtype=torch.float64)
    full = mvs.fill_holes(depth, INTR, pose, lambda xy: np.full(len(xy), 2.0))
    want = plane_sweep.plane_depths(plane_sweep.reference_rays(INTR, pose), pose[1], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
                            torch.tensor([2.0], dtype=torch.float64))[0]
    assert torch.allclose(full, want, atol=1e-6)


def test_consistent_views_counts_agreeing_maps():
    c2w = [pose_from_view_angles(z, a, 50.0) for z, a in ((0, 0), (20, 0), (20, 180))]
    poses = [plane_sweep.cv_pose(m) for m in c2w]
    level = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    maps = [plane_sweep.plane_depths(plane_sweep.reference_rays(INTR, p), p[1], level, torch.tensor([0.0], dtype=torch.float64))[0]
            for p in poses]
    counts = mvs.consistent_views(maps, poses, INTR, [[1, 2], [0, 2], [0, 1]], tol=0.01)
    assert int(counts[0][20:28, 20:28].min()) == 2
    maps[2] = maps[2] * 1.05  # a view 5 % off disagrees with the others
    counts = mvs.consistent_views(maps, poses, INTR, [[1, 2], [0, 2], [0, 1]], tol=0.01)
    assert int(counts[0][20:28, 20:28].max()) == 1 and int(counts[2].max()) == 0


def test_voxel_thin_and_neighbours():
    g = np.random.default_rng(3)
    p = g.random((5000, 3)) * [10, 10, 1]
    n = np.tile([0.0, 0.0, 1.0], (5000, 1))
    tp, tn = mvs.voxel_thin(p, n, 700)
    assert 350 < len(tp) <= 700 and np.allclose(tn, [0, 0, 1])
    assert tp.min(0).min() >= 0 and (tp.max(0) <= [10, 10, 1]).all()
    centres = np.array([pose_from_view_angles(z, a, 10.0)[:3, 3] for z, a in ANGLES])
    nb = mvs.view_neighbours(centres, np.zeros(3), 4)
    assert all(r not in nb[r] and len(nb[r]) == 4 for r in range(len(ANGLES)))
    assert set(nb[1][:2]) <= {0, 2, 8}  # the 20° view at 0° azimuth: nadir and its ring neighbours first


def test_parallax_spaced_planes_move_the_image_by_about_the_step():
    ref = plane_sweep.cv_pose(pose_from_view_angles(0.0, 0.0, 60.0))
    nbrs = [plane_sweep.cv_pose(pose_from_view_angles(20.0, a, 60.0)) for a in (0, 120, 240)]
    fine = plane_sweep.horizontal(torch.linspace(-3.0, 6.0, 2048, dtype=torch.float64))
    fam = plane_sweep.parallax_spaced(fine, INTR, ref, nbrs, 0.5, 400)
    assert fam.offsets[0] == fine.offsets[0] and fam.offsets[-1] == fine.offsets[-1]
    # the image centre's motion between consecutive planes, largest over the neighbours: about 0.5 px
    ray = plane_sweep.reference_rays(INTR, ref)[INTR.h // 2, INTR.w // 2]
    t = (fam.offsets - ref[1][2]) / ray[2]
    pts = ray[None] * t[:, None] + ref[1]
    motion = torch.stack([torch.linalg.vector_norm(torch.diff(plane_sweep.project(pts, INTR, *p)[0], dim=0), dim=-1)
                          for p in nbrs]).max(0).values
    assert float(motion.max()) < 0.55 and float(motion.median()) > 0.3
    few = plane_sweep.parallax_spaced(fine, INTR, ref, nbrs, 0.5, 12)
    assert len(few.offsets) <= 12
