"""Nadir rectification of oblique views for SfM feature detection (beyond the paper) and the robust
final refinement: geometry of the homography, keypoints mapped back to exact image positions,
per-view camera errors in the report."""

from __future__ import annotations

import numpy as np
import pytest

from brfgs.data.cameras import Intrinsics, pose_from_view_angles, project_points
from brfgs.init.features import extract_view_features, nadir_rectification


def _intr(size=96, fov_deg=35.0):
    f = 0.5 * size / np.tan(np.radians(0.5 * fov_deg))
    return Intrinsics(f, f, size / 2, size / 2, size, size)


def _rect(c2w, intr):  # OpenCV pixel convention (first pixel centre at 0)
    return nadir_rectification(c2w, intr.fl_x, intr.fl_y, intr.cx - 0.5, intr.cy - 0.5, intr.w, intr.h)


@pytest.mark.parametrize("zenith,azimuth", [(58.0, 300.0), (38.0, 90.0), (23.0, 150.0)])
def test_rectification_maps_the_ground_by_a_similarity(zenith, azimuth):
    intr = _intr()
    c2w = pose_from_view_angles(zenith, azimuth, 100.0)
    r = _rect(c2w, intr)
    assert r is not None and r.size[0] <= 2.5 * intr.w + 2 and r.size[1] <= 2.5 * intr.h + 2
    g = np.array([[x, y, 0.0] for x in np.linspace(-8, 8, 5) for y in np.linspace(-8, 8, 5)])
    uv = project_points(g, c2w, intr)[0] - 0.5
    q = np.concatenate([uv, np.ones((len(uv), 1))], 1) @ r.H.T
    q = q[:, :2] / q[:, 2:]
    A = np.concatenate([g[:, :2], np.ones((len(g), 1))], 1)
    sol = np.linalg.lstsq(A, q, rcond=None)[0]
    assert np.abs(A @ sol - q).max() < 1e-6  # ground → canvas is affine ...
    sv = np.linalg.svd(sol[:2], compute_uv=False)
    assert sv[0] == pytest.approx(sv[1], rel=1e-6)  # ... and a similarity: no foreshortening left
    # the nadir resolution: f / height of the virtual nadir camera at the image centre is kept or exceeded
    assert sv[0] >= intr.fl_x / 100.0 * 0.999
    assert np.allclose(r.to_image(q), uv, atol=1e-8)
    # local magnification = sqrt |det J| (finite differences)
    p = np.array([[40.0, 50.0]])
    e = 1e-3
    f = lambda x: (lambda h: h[:, :2] / h[:, 2:])(np.concatenate([x, np.ones((len(x), 1))], 1) @ r.H.T)  # noqa: E731
    J = np.stack([(f(p + [e, 0]) - f(p))[0] / e, (f(p + [0, e]) - f(p))[0] / e], 1)
    assert r.jacobian_scale(p)[0] == pytest.approx(np.sqrt(abs(np.linalg.det(J))), rel=1e-4)


def test_nadir_views_are_not_rectified():
    assert _rect(pose_from_view_angles(0.0, 0.0, 100.0), _intr()) is None
    assert _rect(pose_from_view_angles(8.0, 40.0, 100.0), _intr()) is None


def test_rectified_keypoints_land_on_the_blobs():
    """Gaussian blobs on the ground seen by a 58° camera: keypoints found on the rectified canvas and mapped
    back lie on the blobs' projections (pixel conventions of canvas, image and COLMAP agree)."""
    intr = _intr(size=128)
    c2w = pose_from_view_angles(58.0, 300.0, 100.0)
    rng = np.random.default_rng(3)
    centres = rng.uniform(-12, 12, size=(40, 2))
    # render: ray-cast each pixel onto z = 0, sum of Gaussian blobs (sigma 0.8 m) on the ground
    from brfgs.data.cameras import pixel_rays

    o, d = pixel_rays(c2w, intr)
    t = -o[..., 2] / d[..., 2]
    gx, gy = (o[..., 0] + t * d[..., 0]), (o[..., 1] + t * d[..., 1])
    img = np.zeros(gx.shape)
    for cx, cy in centres:
        img += np.exp(-((gx - cx) ** 2 + (gy - cy) ** 2) / (2 * 0.8 ** 2))
    img = (0.1 + 0.3 * img)[:, :, None].astype(np.float32)
    r = _rect(c2w, intr)
    f = extract_view_features(img, None, 0, rect=r)
    assert len(f.xy) >= 10
    truth = project_points(np.c_[centres, np.zeros(len(centres))], c2w, intr)[0]  # COLMAP convention
    dist = np.linalg.norm(f.xy[:, None, :] - truth[None], axis=2).min(1)
    near = dist < 2.0
    assert near.sum() >= 10 and np.median(dist[near]) < 0.3, np.sort(dist)[:20]
    assert np.all((f.xy >= 0) & (f.xy <= 128))


def test_sfm_report_lists_per_view_camera_errors(tmp_path):
    from test_init_toy_scene import make_toy_scene

    from brfgs.data import read_scene
    from brfgs.init import InitConfig, initialize

    sc = read_scene(make_toy_scene(tmp_path / "toy", size=64, n_bands=4, n_views=13))
    res = initialize(sc, [2], poses="sfm", config=InitConfig())
    t = res.report["truth"]
    per_view = t["camera_centre_error_rel_per_view"]
    assert len(per_view) == res.report["registered_views"] >= 12
    assert max(per_view.values()) == pytest.approx(t["camera_centre_error_rel"]["max"])
    assert t["views_above_1pct"] == [n for n, v in per_view.items() if v > 0.01]
    assert res.report["settings"]["rectify"] and res.report["settings"]["robust_refinement"]
