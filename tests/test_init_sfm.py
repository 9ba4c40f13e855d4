"""Initialisation: known-pose triangulation, SfM + ENU alignment, failures, zlib safety, CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from test_init_toy_scene import height_m, make_toy_scene, sigma_profile, spectra

from brfgs.data import read_scene
from brfgs.errors import UserError
from brfgs.init.align import umeyama, umeyama_robust
from brfgs.init.features import dedupe_keypoints


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    root = make_toy_scene(tmp_path_factory.mktemp("init") / "toy", size=96, n_bands=8, n_views=13)
    return read_scene(root)


def _mid_bands(scene):
    return [int(np.argmin(np.abs(scene.wavelengths_nm - w))) for w in (800, 720)]


# ----------------------------------------------------------------------------------- pure helpers
def test_umeyama_recovers_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(20, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R = q * np.sign(np.linalg.det(q))
    dst = 2.5 * src @ R.T + np.array([1.0, -2.0, 3.0])
    sim = umeyama(src, dst)
    assert sim.scale == pytest.approx(2.5) and np.allclose(sim.R, R) and np.allclose(sim.t, [1, -2, 3])
    dst_bad = dst.copy()
    dst_bad[3] += 50.0  # one mis-registered camera
    sim2, inl = umeyama_robust(src, dst_bad)
    assert not inl[3] and inl.sum() == 19 and sim2.scale == pytest.approx(2.5)
    c2w = np.eye(4)
    c2w[:3, 3] = src[0]
    assert np.allclose(sim.apply_c2w(c2w)[:3, 3], dst[0]) and np.allclose(sim.apply_c2w(c2w)[:3, :3], R)


def test_dedupe_keeps_strongest():
    xy = np.array([[10.0, 10.0], [10.5, 10.2], [20.0, 20.0], [10.0, 11.2], [30, 30]])
    resp = np.array([0.5, 0.9, 0.1, 0.2, 0.3])
    keep = dedupe_keypoints(xy, resp, 1.5)
    assert keep.tolist() == [1, 4, 2]  # 0 and 3 lie within 1.5 px of the stronger 1
    # with descriptors: only alike descriptors are duplicates (0 is unlike 1, 3 is like 1)
    desc = np.zeros((5, 4))
    desc[[1, 3, 2, 4], 0] = 1.0
    desc[0, 1] = 1.0
    assert dedupe_keypoints(xy, resp, 1.5, desc).tolist() == [1, 0, 4, 2]


# ----------------------------------------------------------------------------------- known poses
def test_known_poses(toy, tmp_path):
    from brfgs.init import initialize

    bands = _mid_bands(toy)
    res = initialize(toy, bands, poses="known", out_dir=tmp_path / "known")
    r = res.report
    assert r["poses"] == "known" and r["registered_views"] == 13
    assert res.points.shape[1] == 3 and len(res.points) >= 100 and res.colors.shape == (len(res.points), 2)
    # cameras are exactly those of transforms.json
    assert np.allclose(res.c2w, np.stack([f.c2w for f in toy.frames]))
    # points lie on the analytic height field (pixel footprint here ~0.23 m)
    dz = np.abs(res.points[:, 2] - height_m(res.points[:, 0], res.points[:, 1]))
    assert np.median(dz) < 0.05
    assert r["truth"]["point_to_surface_rel"]["median"] < 0.005
    assert r["mean_reprojection_error_px"] < 1.0 and r["mean_track_length"] > 2
    # colours: reflectance between the two end-member spectra (plus a little noise)
    veg, soil = spectra(toy.wavelengths_nm[bands])
    lo, hi = np.minimum(veg, soil), np.maximum(veg, soil)
    tol = 4 * sigma_profile(toy.wavelengths_nm[bands])
    assert np.all(res.colors >= lo - tol) and np.all(res.colors <= hi + tol)
    g = r["geometry"]
    assert 0 < g["verified_matches"] <= g["putative_matches"]
    assert g["matching_success_rate"] == pytest.approx(g["verified_matches"] / g["putative_matches"])
    # outputs
    out = tmp_path / "known"
    from plyfile import PlyData

    ply = PlyData.read(str(out / "points.ply"))
    assert ply["vertex"].count == len(res.points)
    assert np.allclose(ply["vertex"][f"refl_{bands[0]}"], res.colors[:, 0])
    cams = json.loads((out / "cameras.json").read_text())
    assert len(cams["frames"]) == 13 and not (out / "colmap").exists()
    assert "matching success rate" in (out / "init_report.md").read_text()
    # the cameras and points as a COLMAP model that pycolmap opens, poses as in cameras.json
    from brfgs.init.colmap_io import read_colmap_model

    rec = read_colmap_model(out / "sparse" / "0")
    assert rec.num_images() == int(res.registered.sum()) and rec.num_points3D() == len(res.points)
    im = rec.find_image_with_name(toy.frames[4].name)
    w2c = np.eye(4)
    w2c[:3, :] = im.cam_from_world().matrix()
    np.testing.assert_allclose(np.linalg.inv(w2c) @ np.diag([1.0, -1.0, -1.0, 1.0]), res.c2w[4], atol=1e-6)


# ----------------------------------------------------------------------------------- SfM
def test_sfm_aligned_to_enu(toy, tmp_path):
    from brfgs.init import initialize

    res = initialize(toy, _mid_bands(toy), poses="sfm")
    r = res.report
    assert r["poses"] == "sfm" and r["registered_views"] >= 12
    t = r["truth"]
    # 96 px images, 13 views: one pixel spans 0.76 % of the camera distance at the scene centre; the
    # nadir camera's height is the least constrained (it sees a nearly flat scene head-on)
    assert t["camera_centre_error_rel"]["median"] < 0.006 and t["camera_centre_error_rel"]["max"] < 0.05
    assert t["point_to_surface_rel"]["median"] < 0.005
    # the similarity is a real one (SfM's arbitrary scale): not the identity
    assert r["alignment"]["scale"] != pytest.approx(1.0, abs=1e-3)
    # rotation of the cameras matches too (angles meaningful)
    ang = [np.degrees(np.arccos(np.clip(np.dot(res.c2w[i][:3, 2], toy.frames[i].c2w[:3, 2]), -1, 1)))
           for i in np.flatnonzero(res.registered)]
    assert np.median(ang) < 0.5 and np.max(ang) < 3.0, ang


def test_sfm_determinism(toy):
    from brfgs.init import initialize

    a = initialize(toy, _mid_bands(toy)[:1], poses="sfm")
    b = initialize(toy, _mid_bands(toy)[:1], poses="sfm")
    assert np.array_equal(a.points, b.points) and np.array_equal(a.c2w, b.c2w)


def test_sfm_failure_is_a_user_error(tmp_path):
    from brfgs.init import initialize

    root = make_toy_scene(tmp_path / "flat", size=32, n_bands=4, n_views=13, flat=True, noise=False)
    sc = read_scene(root)
    with pytest.raises(UserError) as err:
        initialize(sc, [1], poses="sfm")
    msg = str(err.value)
    assert "--poses known" in msg and "v000" in msg and "SfM failed" in msg and "too little texture" in msg
    # with the known poses a texture-less scene starts from the ground plane the cameras look at
    res = initialize(sc, [1], poses="known")
    assert "too little texture" in res.report["fallback"] and len(res.points) >= 100
    assert np.abs(res.points[:, 2] - np.median(res.points[:, 2])).max() < 1e-6  # one horizontal plane


def test_the_plane_start_lies_where_the_cameras_look():
    from brfgs.data.cameras import Intrinsics, pose_from_view_angles
    from brfgs.init.plane import look_at_point, plane_arrays

    target = np.array([2.0, -3.0, 5.0])
    c2w = np.stack([pose_from_view_angles(z, a, 60.0) for z, a in ((0, 0), (30, 0), (30, 120), (30, 240))])
    c2w[:, :3, 3] += target
    np.testing.assert_allclose(look_at_point(c2w), target, atol=1e-9)
    arr = plane_arrays(c2w, Intrinsics.from_fov(35.0, 32, 24))
    assert len(arr.points) > 50 and np.allclose(arr.points[:, 2], 5.0) and (arr.track_len >= 2).all()
    assert len(arr.obs_point) == arr.track_len.sum() and arr.obs_point.max() == len(arr.points) - 1


def test_auto_uses_sfm_for_nominal_poses(tmp_path):
    from brfgs.init import initialize

    root = make_toy_scene(tmp_path / "nominal", size=96, n_bands=4, n_views=13, poses=False)
    sc = read_scene(root)
    res = initialize(sc, [2], poses="auto")
    assert res.report["poses"] == "sfm" and res.report["registered_views"] >= 12


# ----------------------------------------------------------------------------------- zlib trap
def test_pycolmap_does_not_break_zlib(tmp_path):
    code = f"""
import brfgs.init.colmap  # imports pycolmap (through brfgs.init.pycolmap_safe: zlib first)
import numpy as np
np.savez_compressed({str(tmp_path / 'a.npz')!r}, x=np.arange(1000))
import cv2
ok, buf = cv2.imencode('.png', np.zeros((8, 8), np.uint8)); assert ok
import matplotlib; matplotlib.use('Agg'); import matplotlib.pyplot as plt
plt.plot([0, 1]); plt.savefig({str(tmp_path / 'a.png')!r})
print('ok')
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.strip().endswith("ok") and (tmp_path / "a.png").stat().st_size > 0
    assert np.load(tmp_path / "a.npz")["x"].sum() == 499500


@pytest.mark.parametrize("module", ["brfgs.init.colmap", "brfgs.init.colmap_io", "brfgs.init.colmap_project"])
def test_pycolmap_leaves_sigterm_alone(module):
    """glog's failure handler (installed by pycolmap) turns SIGTERM into a native stack trace on stderr:
    a training rank that the distributed launcher stops printed one. After importing any module that
    loads pycolmap, SIGTERM ends the process quietly with the default status."""
    code = f"import os, signal, {module}; os.kill(os.getpid(), signal.SIGTERM); print('survived')"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == -15 and p.stdout == "" and p.stderr == "", (p.returncode, p.stderr[-2000:])


# ----------------------------------------------------------------------------------- CLI
def test_cli_init_known_and_ablation(toy, tmp_path):
    from brfgs.cli import main

    out = tmp_path / "run"
    assert main(["init", str(toy.root), str(out), "--poses", "known", "--strategy", "efc-top1", "-q"]) == 0
    rep = json.loads((out / "init_report.json").read_text())
    bj = json.loads((out / "bands.json").read_text())
    assert rep["bands"]["indices"] == [s["index"] for s in bj["selected"]] and bj["strategy"] == "efc-top1"
    # a finished result is never overwritten without --overwrite; never inside the scene folder
    assert main(["init", str(toy.root), str(out), "--poses", "known", "-q"]) == 2
    assert main(["init", str(toy.root), str(toy.root / "x"), "-q"]) == 2
    # explicit bands and an unknown pose mode
    assert main(["init", str(toy.root), str(tmp_path / "r2"), "--bands", "1,5", "--poses", "known", "-q"]) == 0
    assert json.loads((tmp_path / "r2" / "init_report.json").read_text())["bands"]["indices"] == [1, 5]
    assert main(["init", str(toy.root), str(tmp_path / "r3"), "--poses", "maybe", "-q"]) == 2
    assert main(["init", str(toy.root), str(tmp_path / "r4"), "--match-threads", "0", "-q"]) == 2
    assert not (tmp_path / "r4").exists()


def test_strategy_ablation_rows(tmp_path, capsys):
    from brfgs.bands import TABLE2_STRATEGIES
    from brfgs.cli import main

    small = make_toy_scene(tmp_path / "small", size=48, n_bands=8, n_views=13)
    out = tmp_path / "abl"
    assert main(["init", str(small), str(out), "--strategy", "all-strategies", "--poses", "known", "-q"]) == 0
    printed = capsys.readouterr().out
    rep = json.loads((out / "init_report.json").read_text())
    rows = rep["strategies"]
    assert [r["strategy"] for r in rows] == list(TABLE2_STRATEGIES)
    assert "Matching success rate" in printed and "Matching success rate" in (out / "init_report.md").read_text()
    by = {r["strategy"]: r for r in rows}
    assert len(by["all"]["bands"]) == 8 and len(by["efc-top3"]["bands"]) == 3
    assert rep["bands"]["indices"] == by["efc-top3"]["bands"]  # the run itself uses EFC top-3
    for r in rows:
        assert r["mean_detected_features_per_view"] > 0
        assert 0 <= r["matching_success_rate"] <= 1
        assert r["verified_matches"] <= r["putative_matches"]
    # pooling bands (duplicates removed) gives at least as many features as the best single band in it
    assert by["all"]["mean_detected_features_per_view"] >= by["max-features"]["mean_detected_features_per_view"]
