"""The report writers of `brfgs render | products | brf | export`, called as library functions
(no command line): the files they write hold what the library functions return."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import spectral.io.envi as envi

from brfgs.analysis import brf as B
from brfgs.products import maps as P
from brfgs.analysis.brf_report import BRFOptions, brf_report
from brfgs.products.export import ExportOptions, export_model, read_ply
from brfgs.products.mcd43_maps import render_mcd43
from brfgs.products.report import ProductsOptions, products_report
from brfgs.analysis.render_report import RenderOptions, render_report
from brfgs.analysis.roi_spec import parse_roi_spec, resolve_roi
from brfgs.data.cameras import Intrinsics
from brfgs.data.cube_io import envi_image_path
from brfgs.errors import UserError
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from test_analysis_brf import _write_scene_from_model
from test_analysis_helpers import carpet_model, write_model_file

ZR = np.linspace(0.5, 0.1, 8)
ZL = np.linspace(0.1, 0.4, 8)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("analysis_reports")
    bm = carpet_model(half_m=10.0, n_bands=8, z_left=ZL, z_right=ZR, geo=0.2, components=("iso", "geo", "spec"))
    scene = _write_scene_from_model(root / "scene", bm, with_truth=True)
    write_model_file(root / "run" / "model.safetensors", bm, scene_root=scene)
    return root / "run"


def _cube(hdr) -> np.ndarray:
    return np.asarray(envi.open(str(hdr), str(envi_image_path(hdr))).load(), np.float32)


def _csv(path) -> tuple[list[str], list[dict]]:
    with open(path) as f:
        rows = list(csv.DictReader(f))
    with open(path) as f:
        header = next(csv.reader(f))
    return header, rows


def _floats(rows: list[dict], key: str) -> np.ndarray:
    return np.array([float(r[key]) if r[key] != "" else np.nan for r in rows])


def _camera(info: dict):
    intr = Intrinsics(**info["intrinsics"])
    return camera_from_intrinsics(np.array(info["c2w"]), intr)


def test_render_report_writes_the_rendered_view(run_dir, tmp_path):
    opts = RenderOptions(view_zenith_deg=35.0, view_azimuth_deg=120.0, size=(24, 16), fov_deg=15.0, sun_zenith_deg=50.0,
                         backend="cpu", progress=False)
    rep = render_report(run_dir, opts, tmp_path / "r")
    info = json.loads((rep.out / "render.json").read_text())
    assert info == json.loads(json.dumps(rep.info)) and rep.out == tmp_path / "r"
    assert (info["width"], info["height"], info["sun_zenith_deg"]) == (24, 16, 50.0)
    tm = TrainedModel.load(run_dir)
    rv = render(tm, _camera(info), sun_zenith_deg=50.0, normals=True, backend="cpu")
    np.testing.assert_array_equal(_cube(rep.out / "cube.hdr"), rv.cube)
    np.testing.assert_array_equal(np.load(rep.out / "depth.npy"), rv.depth)
    np.testing.assert_array_equal(np.load(rep.out / "alpha.npy"), rv.alpha)
    np.testing.assert_array_equal(np.load(rep.out / "normal.npy"), rv.normal)
    assert set(info["files"]) == {"cube", "cir_png", "depth_png", "normal_png", "sun_visibility_png"}
    from brfgs.model.shadows import gaussian_sun_visibility
    from brfgs.model.view import sun_visibility_map

    vis = sun_visibility_map(tm, _camera(info), gaussian_sun_visibility(tm, 50.0, tm.sun_azimuth_deg, backend="cpu"),
                             backend="cpu")
    np.testing.assert_array_equal(np.load(rep.out / "sun_visibility.npy"), vis)   # under the render's sun
    assert "24x16" in rep.message
    with pytest.raises(UserError, match="render.json"):  # a finished result is kept
        render_report(run_dir, opts, tmp_path / "r")


def test_render_report_refuses_a_bad_path_before_writing(run_dir, tmp_path):
    with pytest.raises(UserError, match="--path"):
        render_report(run_dir, RenderOptions(10.0, 0.0, path="spiral"), tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_products_report_writes_the_rendered_products(run_dir, tmp_path):
    rep = products_report(run_dir, ProductsOptions(size=(16,), check_decoder=False, backend="cpu", progress=False),
                          tmp_path / "p")
    info = json.loads((rep.out / "products.json").read_text())
    assert info == json.loads(json.dumps(rep.info))
    tm = TrainedModel.load(run_dir)
    res = P.render_products(tm, _camera(info["camera"]), backend="cpu")
    mcd43 = ["f_iso", "f_vol", "f_geo", "fit_rmse", "nbar_mcd43", "bsa_mcd43", "wsa_mcd43"]
    assert sorted(info["files"]) == sorted(["iso", "geo", "spec", "total", "nbar", "bsa", "wsa", "anix", "dsm"] + mcd43)
    dsm = info["files"].pop("dsm")                                      # the flat carpet lies at z = 0
    assert abs(dsm["median_m"]) < 0.05 and dsm["finite_fraction"] > 0.9
    fit = render_mcd43(tm, _camera(info["camera"]), nbar_sun_zenith_deg=tm.sun_zenith_deg,
                       albedo_sun_zenith_deg=tm.sun_zenith_deg, backend="cpu")
    res.update({k: fit[k] for k in mcd43})
    np.testing.assert_array_equal(np.load(rep.out / "alpha.npy"), res["alpha"])
    i_map = int(np.argmin(np.abs(tm.wavelengths_nm - 860.0)))
    for name, f in info["files"].items():
        cube = _cube(rep.out / f["cube"])
        np.testing.assert_array_equal(cube, res[name])
        assert f["mean_at_nm"] == pytest.approx(float(np.nanmean(res[name][..., i_map])), rel=1e-6)
        assert (rep.out / f["png"]).stat().st_size > 0
    assert info["settings"].pop("mcd43")["grid"] == fit["settings"]["grid"]
    assert info["settings"] == json.loads(json.dumps(res["settings"]))
    assert len(info["mcd43_fit_rmse_per_band"]["median"]) == len(tm.wavelengths_nm)


def test_brf_report_tables_hold_the_sampled_brf(run_dir, tmp_path):
    opts = BRFOptions(roi="polygon:3,-5;9,-5;9,5;3,5", roi_name="east", bands_nm=(480.0, 860.0), step_deg=15.0,
                      max_zenith_deg=60.0, polar_azimuths=6, polar_zeniths=2, size=16, backend="cpu", progress=False)
    warnings = []
    rep = brf_report(run_dir, opts, tmp_path / "b", warn=warnings.append)
    summary = json.loads((rep.out / "brf.json").read_text())
    assert summary == json.loads(json.dumps(rep.info)) and warnings == []
    tm = TrainedModel.load(run_dir)
    roi = resolve_roi(parse_roi_spec(opts.roi, opts.roi_name), tm, backend="cpu")
    assert summary["roi"] == json.loads(json.dumps(roi.describe()))
    bi = tm.band_indices(opts.bands_nm)
    # principal plane: columns and values (written with 6 significant digits)
    s, pp = B.principal_plane(tm, roi, bi, max_zenith_deg=60.0, step_deg=15.0, size=16, backend="cpu")
    header, rows = _csv(rep.out / "principal_plane.csv")
    assert header == ["signed_view_zenith_deg", "brf_480nm", "brf_860nm", "n_pixels"]
    np.testing.assert_allclose(_floats(rows, "signed_view_zenith_deg"), s)
    np.testing.assert_allclose(np.c_[_floats(rows, "brf_480nm"), _floats(rows, "brf_860nm")], pp.values, rtol=1e-5)
    np.testing.assert_array_equal(_floats(rows, "n_pixels"), pp.n_pixels)
    peaks = summary["principal_plane"]["peak_signed_zenith_deg"]
    assert peaks == {"480": B.curve_peak(s, pp.values[:, 0]), "860": B.curve_peak(s, pp.values[:, 1])}
    # polar map
    zc, ac, vals, _ = B.polar_map(tm, roi, bi, n_azimuth=6, n_zenith=2, max_zenith_deg=60.0, size=16, backend="cpu")
    header, rows = _csv(rep.out / "polar.csv")
    assert header == ["view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg", "brf_480nm", "brf_860nm",
                      "n_pixels"]
    np.testing.assert_allclose(_floats(rows, "view_zenith_deg"), np.repeat(zc, len(ac)))
    np.testing.assert_allclose(_floats(rows, "view_azimuth_deg"), np.tile(ac, len(zc)))
    np.testing.assert_allclose(_floats(rows, "brf_860nm"), vals[..., 1].ravel(), rtol=1e-5)
    # observations of every frame: the scene's images are the model's own renders
    sc_obs = B.frame_observations(tm, roi, None, backend="cpu")
    header, rows = _csv(rep.out / "observations.csv")
    assert header[:7] == ["frame", "split", "view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg",
                          "signed_view_zenith_deg", "n_pixels"]
    assert header[7:] == [f"{k}_{w}nm" for k in ("reconstructed", "observed", "truth") for w in (480, 860)]
    assert [r["frame"] for r in rows] == [o.name for o in sc_obs]
    np.testing.assert_allclose(_floats(rows, "view_zenith_deg"), [o.view_zenith_deg for o in sc_obs], rtol=1e-5)
    np.testing.assert_allclose(_floats(rows, "reconstructed_480nm"), _floats(rows, "observed_480nm"), atol=2e-5)
    assert summary["brf_error"]["vs_observed"]["n_frames"] == len(rows)
    header, rows = _csv(rep.out / "spectra.csv")
    assert header == ["wavelength_nm", "reconstructed", "observed", "log_error", "truth"] and len(rows) == 8
    assert set(summary["files"].values()) <= {p.name for p in rep.out.iterdir()}
    assert rep.message.startswith("east: principal-plane peaks 480 nm:")


def test_brf_report_warns_when_the_roi_is_not_seen(run_dir, tmp_path):
    opts = BRFOptions(roi="polygon:3,-5;9,-5;9,5;3,5", bands_nm=(480.0,), step_deg=30.0, max_zenith_deg=60.0,
                      polar=False, min_alpha=1.0, size=16, scene=None, backend="cpu", progress=False)
    warnings = []
    rep = brf_report(run_dir, opts, tmp_path / "w", warn=warnings.append)
    assert len(warnings) == 1 and "not seen" in warnings[0]
    assert rep.info["principal_plane"]["directions_without_roi_pixels"] == 5
    assert not (rep.out / "polar.csv").exists()


def test_export_model_writes_ply_and_a_loadable_copy(run_dir, tmp_path):
    info = export_model(run_dir, tmp_path / "e", ExportOptions(view_dependence="none"))
    assert info == json.loads((tmp_path / "e" / "export.json").read_text())
    tm = TrainedModel.load(tmp_path / "e" / info["model"])
    v = read_ply(tmp_path / "e" / info["ply"])
    assert len(v["x"]) == info["n_gaussians"] == tm.n_gaussians
    assert all((v[f"f_rest_{i}"] == 0).all() for i in range(45))
    assert info["ply_colours"]["method"] == "colour at nadir view (no view dependence)"
