"""ROI BRF sampling: right area, right values, conventions of the principal plane, observations."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brfgs.analysis import brf as B
from brfgs.analysis import views as V
from brfgs.analysis.roi import PolygonROI, roi_from_view_mask, unproject_depth
from brfgs.data.cube_io import write_envi
from brfgs.errors import UserError
from brfgs.model import camera_from_intrinsics, render
from test_analysis_helpers import carpet_model

ZL = np.array([0.10, 0.20, 0.30, 0.40])
ZR = np.array([0.50, 0.35, 0.25, 0.05])


def test_view_angle_checks():
    for bad in (90.0, 95.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(UserError, match="zenith"):
            V.check_zenith_deg(bad, "--view-zenith")
    with pytest.raises(UserError, match="azimuth"):
        V.check_azimuth_deg(float("nan"), "--view-azimuth")
    assert V.check_azimuth_deg(-30.0, "a") == 330.0


def test_principal_plane_directions_follow_conventions():
    zen, az = V.principal_plane_directions([-40.0, 0.0, 40.0], 150.0)
    np.testing.assert_allclose(zen, [40, 0, 40])
    np.testing.assert_allclose(az, [330, 150, 150])
    # + side is the sun's side: relative azimuth 0 (backscatter)
    from brfgs.data.angles import relative_azimuth_deg, signed_principal_plane_zenith_deg

    s = signed_principal_plane_zenith_deg(zen, relative_azimuth_deg(az, 150.0))
    np.testing.assert_allclose(s, [-40, 0, 40])


def test_camera_looks_at_target():
    tgt = np.array([3.0, -2.0, 1.0])
    c2w, intr = V.view_camera(40.0, 250.0, 80.0, tgt, size=16, half_extent_m=5.0)
    zen, az = V.view_angles_from_points(c2w[:3, 3], tgt)
    assert zen == pytest.approx(40.0) and az == pytest.approx(250.0)
    np.testing.assert_allclose(-c2w[:3, 2], (tgt - c2w[:3, 3]) / 80.0, atol=1e-12)


def test_roi_brf_sees_the_right_material():
    """Isotropic carpet, two materials split at x = 0: an ROI on either side returns that side's
    reflectance from every direction, also seen obliquely across the boundary."""
    bm = carpet_model(z_left=ZL, z_right=ZR, components=("iso",))
    right = PolygonROI(np.array([[4.0, -6.0], [12.0, -6.0], [12.0, 6.0], [4.0, 6.0]]))
    left = PolygonROI(np.array([[-12.0, -6.0], [-4.0, -6.0], [-4.0, 6.0], [-12.0, 6.0]]))
    zen = np.array([0.0, 40.0, 60.0, 60.0])
    az = np.array([0.0, 90.0, 270.0, 90.0])
    r = B.roi_brf(bm, right, zen, az, size=24, backend="cpu")
    l_ = B.roi_brf(bm, left, zen, az, size=24, backend="cpu")
    assert (r.n_pixels > 50).all() and (l_.n_pixels > 50).all()
    # premultiplied renders over a zero background: the carpet's alpha is > 0.995
    np.testing.assert_allclose(r.values, np.tile(ZR, (4, 1)), rtol=5e-3)
    np.testing.assert_allclose(l_.values, np.tile(ZL, (4, 1)), rtol=5e-3)


def test_box_roi_of_a_view_returns_its_material():
    bm = carpet_model(z_left=ZL, z_right=ZR, components=("iso",))
    fr = bm.frame("v0")                                    # nadir; image x (columns) = east
    c2w = np.asarray(fr["c2w"])
    rv = render(bm, camera_from_intrinsics(c2w, bm.intrinsics), decode=False, backend="cpu")
    mask = np.zeros((bm.intrinsics.h, bm.intrinsics.w), bool)
    mask[10:22, 2:9] = True                                # west part of the image
    roi = roi_from_view_mask(mask, rv.depth, c2w, bm.intrinsics)
    assert (roi.points_m[:, 0] < -2.0).all()
    r = B.roi_brf(bm, roi, [0.0, 50.0], [0.0, 200.0], size=24, backend="cpu")
    np.testing.assert_allclose(r.values, np.tile(ZL, (2, 1)), rtol=5e-3)


def test_principal_plane_hotspot_and_specular_peaks():
    """A Li-Sparse (geometric-optical) surface peaks at the hotspot (+θ_s), a glossy one at the
    specular direction (−θ_s): the whole chain (sun, kernels, cameras, signs) must agree."""
    sun = (35.0, 150.0)
    roi = PolygonROI(np.array([[-6.0, -6.0], [6.0, -6.0], [6.0, 6.0], [-6.0, 6.0]]))
    geo = carpet_model(z_left=ZR, z_right=ZR, geo=0.25, components=("iso", "geo"), sun=sun)
    s, pp = B.principal_plane(geo, roi, [0, 3], max_zenith_deg=70.0, step_deg=5.0, size=24, backend="cpu")
    for j in range(2):
        assert abs(B.curve_peak(s, pp.values[:, j]) - sun[0]) <= 5.0
    gloss = carpet_model(z_left=ZR * 0.1, z_right=ZR * 0.1, spec=60.0, components=("iso", "spec"), sun=sun,
                         roughness=0.15)
    s, pp = B.principal_plane(gloss, roi, [0, 3], max_zenith_deg=70.0, step_deg=5.0, size=24, backend="cpu")
    for j in range(2):
        assert abs(B.curve_peak(s, pp.values[:, j]) + sun[0]) <= 5.0


def test_polar_map_shape_and_sun_side():
    bm = carpet_model(z_left=ZR, z_right=ZR, geo=0.25, components=("iso", "geo"), sun=(35.0, 150.0))
    roi = PolygonROI(np.array([[-6.0, -6.0], [6.0, -6.0], [6.0, 6.0], [-6.0, 6.0]]))
    zc, ac, vals, res = B.polar_map(bm, roi, [0], n_azimuth=8, n_zenith=3, max_zenith_deg=60.0, size=16,
                                    backend="cpu")
    assert vals.shape == (3, 8, 1) and np.isfinite(vals).all()
    i, k = np.unravel_index(np.argmax(vals[..., 0]), vals.shape[:2])
    assert zc[i] == pytest.approx(30.0) and ac[k] == pytest.approx(157.5)   # cell holding the sun (35°, 150°)


def _write_scene_from_model(root, bm, with_truth: bool):
    """A scene whose images are the model's own renders (observed == reconstructed)."""
    intr = bm.intrinsics
    frames = []
    for fr in bm.frames:
        c2w = np.asarray(fr["c2w"])
        rv = render(bm, camera_from_intrinsics(c2w, intr), backend="cpu")
        write_envi(root / "images" / f"{fr['name']}.hdr", rv.cube, bm.wavelengths_nm)
        if with_truth:
            write_envi(root / "truth" / "images" / f"{fr['name']}.hdr", rv.cube, bm.wavelengths_nm)
            (root / "truth" / "depth").mkdir(parents=True, exist_ok=True)
            np.save(root / "truth" / "depth" / f"{fr['name']}.npy", rv.depth.astype(np.float32))
        frames.append({"file_path": f"images/{fr['name']}.hdr", "transform_matrix": fr["c2w"],
                       "view_zenith_deg": fr["view_zenith_deg"], "view_azimuth_deg": fr["view_azimuth_deg"],
                       "split": fr["split"]})
    meta = {"camera_model": "PINHOLE", "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy,
            "w": intr.w, "h": intr.h, "wavelengths_nm": bm.wavelengths_nm.tolist(),
            "sun_zenith_deg": bm.sun_zenith_deg, "sun_azimuth_deg": bm.sun_azimuth_deg,
            "dark_sigma": [0.01] * len(bm.wavelengths_nm), "frames": frames}
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def test_frame_observations_against_own_renders(tmp_path):
    from brfgs.data import read_scene

    bm = carpet_model(z_left=ZL, z_right=ZR, geo=0.2, components=("iso", "geo"))
    _write_scene_from_model(tmp_path, bm, with_truth=True)
    sc = read_scene(tmp_path)
    roi = PolygonROI(np.array([[4.0, -6.0], [12.0, -6.0], [12.0, 6.0], [4.0, 6.0]]))
    # a few bright truth pixels inside the ROI (edge pixels mixed with a bright neighbour) are left out of
    # the truth mean, as the observed mean leaves them out
    import spectral.io.envi as envi

    from brfgs.data.cube_io import envi_image_path

    hdr = tmp_path / "truth" / "images" / "v0.hdr"
    cube = np.array(envi.open(str(hdr), str(envi_image_path(hdr))).load(), np.float32)
    pts = unproject_depth(np.load(tmp_path / "truth" / "depth" / "v0.npy").astype(float), sc.frames[0].c2w, sc.intrinsics)
    rows, cols = np.nonzero(roi.contains(pts.reshape(-1, 3)).reshape(pts.shape[:2]))
    cube[rows[:3], cols[:3]] *= 8.0
    write_envi(hdr, cube, bm.wavelengths_nm)
    obs = B.frame_observations(bm, roi, sc, backend="cpu")
    bright = B._truth_mean(tmp_path / "truth", "v0", sc.frames[0].c2w, sc.intrinsics, roi, outlier_k_mad=0)[0]
    assert (bright > obs[0].truth * 1.01).all()  # without the outlier removal they would bias it
    assert [o.name for o in obs] == ["v0", "v1", "v2", "v3"]
    for o in obs:
        assert o.n_pixels > 20
        np.testing.assert_allclose(o.observed, o.reconstructed, atol=1e-5)
        # v0: the mean over its other pixels (the three outliers are left out)
        np.testing.assert_allclose(o.truth, o.reconstructed, **(dict(rtol=5e-3) if o.name == "v0" else dict(atol=1e-5)))
        np.testing.assert_allclose(B.log_error(o.reconstructed, o.observed), 0.0, atol=1e-4)
    # view directions are measured from the ROI centre (8, 0, 0), not the camera's target (origin):
    # v1's camera is at (0, 30, 52) -> azimuth 345°, relative azimuth 195° (forward side, 15° off the plane)
    v1 = obs[1]
    assert v1.view_azimuth_deg == pytest.approx(np.degrees(np.arctan2(-8.0, 30.0)) % 360, abs=1e-6)
    assert v1.relative_azimuth_deg == pytest.approx((v1.view_azimuth_deg - 150.0) % 360, abs=1e-9)
    assert v1.plane_offset_deg == pytest.approx(15.07, abs=0.05) and v1.signed_zenith_deg < 0
    near = B.nearest_to_plane(obs, max_offset_deg=20.0)
    # v0 (nadir over the origin) is seen from the ROI at 7.6° zenith, azimuth 270° (60° off the plane)
    assert obs[0].plane_offset_deg == pytest.approx(60.0, abs=1e-6)
    assert [o.name for o in near] == ["v1"]
    assert B.nearest_to_plane(obs, max_offset_deg=10.0) == []


def test_log_error_and_curve_peak():
    np.testing.assert_allclose(B.log_error([0.2, 0.1], [0.1, 0.1]), [np.log(2.0), 0.0])
    s = np.arange(-10.0, 11.0, 5.0)
    assert B.curve_peak(s, -(s - 2.0) ** 2) == pytest.approx(2.0)


def test_robust_keep_drops_outlier_pixels():
    rng = np.random.default_rng(0)
    x = 0.3 + 0.01 * rng.standard_normal((50, 4))
    x[3] = 5.0
    x[7, 1] = np.nan
    keep = B.robust_keep(x)
    assert not keep[3] and not keep[7] and keep.sum() == 48
    assert B.robust_keep(x[:9]).sum() == 8           # too few pixels: only the non-finite one is dropped
