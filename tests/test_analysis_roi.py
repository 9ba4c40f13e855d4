"""Regions of interest: polygons, unprojection, view masks projected onto the surface, materials."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brfgs.analysis import roi as R
from brfgs.analysis import roi_spec
from brfgs.data.cameras import Intrinsics, pixel_rays, pose_from_view_angles, project_points
from brfgs.errors import UserError
from brfgs.model import camera_from_intrinsics, render
from test_analysis_helpers import carpet_model


def test_points_in_polygon_matches_matplotlib():
    from matplotlib.path import Path as MPath

    rng = np.random.default_rng(0)
    poly = np.array([[0, 0], [4, 0], [4, 3], [2, 1], [0, 3.0]])  # non-convex
    pts = rng.uniform(-1, 5, (2000, 2))
    ours = R.points_in_polygon(pts, poly)
    ref = MPath(poly).contains_points(pts)
    assert ours.sum() > 100
    assert (ours == ref).mean() > 0.999  # only points exactly on an edge may differ


def _plane_depth(c2w, intr, z0=0.0):
    """Analytic axial depth of the plane z = z0 seen by the camera (independent of the model)."""
    o, d = pixel_rays(c2w, intr)
    t = (z0 - o[..., 2]) / d[..., 2]
    forward = -c2w[:3, 2]
    return t * (d @ forward)


def test_unproject_depth_inverts_projection():
    intr = Intrinsics.from_fov(40.0, 20, 16)
    c2w = pose_from_view_angles(35.0, 200.0, 50.0)
    depth = _plane_depth(c2w, intr, z0=1.5)
    pts = R.unproject_depth(depth, c2w, intr)
    np.testing.assert_allclose(pts[..., 2], 1.5, atol=1e-9)
    uv, z = project_points(pts.reshape(-1, 3), c2w, intr)
    j, i = np.meshgrid(np.arange(intr.h) + 0.5, np.arange(intr.w) + 0.5, indexing="ij")
    np.testing.assert_allclose(uv[:, 0], i.ravel(), atol=1e-6)
    np.testing.assert_allclose(uv[:, 1], j.ravel(), atol=1e-6)
    np.testing.assert_allclose(z, depth.ravel(), atol=1e-9)


def test_box_in_oblique_view_projects_onto_the_right_ground_area():
    """A pixel box of an oblique training view, unprojected with the *rendered* depth of a flat
    Gaussian carpet, must land on the ground quadrilateral hit by the box's pixel rays."""
    bm = carpet_model(half_m=20.0, spacing_m=1.0, n_bands=4)
    fr = bm.frame("v1")                                  # 30° zenith, azimuth 0 (camera to the north)
    c2w = np.asarray(fr["c2w"])
    intr = Intrinsics.from_fov(40.0, 32, 32)
    bm.intrinsics = intr
    rv = render(bm, camera_from_intrinsics(c2w, intr), decode=False, backend="cpu")
    mask = np.zeros((32, 32), bool)
    mask[8:14, 18:27] = True                             # rows 8..13, cols 18..26
    roi = R.roi_from_view_mask(mask, rv.depth, c2w, intr, name="box")
    # reference: the ground points of the box pixels from the analytic plane z = 0
    ref = R.unproject_depth(_plane_depth(c2w, intr), c2w, intr)[mask]
    got = roi.points_m
    footprint = R.pixel_footprint_m(rv.depth, intr, mask)            # ~1.4 m per pixel here
    # The rendered (expected) depth of a carpet of 1 m Gaussians seen at 30° is biased toward
    # the camera by less than one Gaussian spacing; the ground points agree within half a pixel.
    assert np.abs(got[:, 2]).max() < 1.0
    np.testing.assert_allclose(got[:, :2], ref[:, :2], atol=0.5 * footprint)
    # the ROI contains the quadrilateral's interior and not the ground far outside it
    lo, hi = ref[:, :2].min(0), ref[:, :2].max(0)
    inner = np.stack(np.meshgrid(np.linspace(lo[0] + 0.5, hi[0] - 0.5, 5),
                                 np.linspace(lo[1] + 0.5, hi[1] - 0.5, 5)), -1).reshape(-1, 2)
    assert roi.contains(np.c_[inner, np.zeros(len(inner))]).all()
    far = np.array([[lo[0] - 4, lo[1]], [hi[0] + 4, hi[1]], [lo[0], lo[1] - 4], [hi[0], hi[1] + 4]])
    assert not roi.contains(np.c_[far, np.zeros(4)]).any()
    # a point above the area by more than the vertical tolerance is not in it
    mid = np.r_[0.5 * (lo + hi), got[:, 2].max() + roi.tol_z_m + 0.5]
    assert not roi.contains(mid[None])[0]


def test_material_points_from_truth_maps(tmp_path):
    intr = Intrinsics.from_fov(40.0, 24, 24)
    c2w = pose_from_view_angles(0.0, 0.0, 40.0)
    depth = _plane_depth(c2w, intr)
    pts = R.unproject_depth(depth, c2w, intr)
    mat = np.where(pts[..., 0] > 2.0, 3, 1).astype(np.int16)      # "water" east of x = 2 m
    (tmp_path / "materials").mkdir()
    (tmp_path / "depth").mkdir()
    np.save(tmp_path / "materials" / "v0.npy", mat)
    np.save(tmp_path / "depth" / "v0.npy", depth.astype(np.float32))
    (tmp_path / "materials.json").write_text(json.dumps({"1": {"name": "grass"}, "3": {"name": "water"}}))

    class F:
        name = "v0"

    F.c2w = c2w
    p, fp = R.material_points(tmp_path, "water", [F], intr)
    assert len(p) == int((mat == 3).sum()) and (p[:, 0] > 2.0).all()
    assert fp == pytest.approx(40.0 / intr.fl_x, rel=0.05)
    with pytest.raises(UserError, match="not in this scene"):
        R.material_points(tmp_path, "lava", [F], intr)


@pytest.mark.parametrize("bad", ["polygon:0,0;1,1", "box:v0:1,2,3", "box:v0:5,5,2,9", "circle:3",
                                 "polygon:0,0;1,nan;2,2", "material:"])
def test_bad_roi_specs_are_user_errors(bad):
    with pytest.raises(UserError):
        roi_spec.parse_roi_spec(bad)


def test_roi_spec_parsing():
    s = roi_spec.parse_roi_spec("polygon:0,0;10,0;10,5")
    assert s.kind == "polygon" and s.polygon_xy_m.shape == (3, 2)
    s = roi_spec.parse_roi_spec("box:view_03:1,2,10,12")
    assert (s.kind, s.view, s.box) == ("box", "view_03", (1, 2, 10, 12))
    assert roi_spec.parse_roi_spec("material:water").material == "water"
