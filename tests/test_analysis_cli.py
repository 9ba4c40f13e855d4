"""`brfgs render | brf | products | export` on a small model file (identity decoder)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from brfgs.cli import main
from brfgs.data.cube_io import envi_image_path, read_envi_header
from test_analysis_brf import _write_scene_from_model
from test_analysis_helpers import carpet_model, write_model_file

ZR = np.linspace(0.5, 0.1, 8)
ZL = np.linspace(0.1, 0.4, 8)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("analysis_cli")
    bm = carpet_model(half_m=10.0, n_bands=8, z_left=ZL, z_right=ZR, geo=0.2, components=("iso", "geo", "spec"))
    scene = _write_scene_from_model(root / "scene", bm, with_truth=True)
    write_model_file(root / "run" / "model.safetensors", bm, scene_root=scene)
    return root / "run"


@pytest.mark.parametrize("zen", ["90", "95", "-1", "nan", "inf"])
def test_render_refuses_impossible_view_zenith(run_dir, zen, capsys):
    rc = main(["render", str(run_dir), "--view-zenith", zen, "--view-azimuth", "10", "-o", str(run_dir / "x")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--view-zenith" in err and "zenith" in err and "Traceback" not in err
    assert not (run_dir / "x").exists()


def test_render_refuses_impossible_sun(run_dir, capsys):
    rc = main(["render", str(run_dir), "--view-zenith", "10", "--view-azimuth", "nan"])
    assert rc == 2 and "--view-azimuth" in capsys.readouterr().err
    rc = main(["render", str(run_dir), "--view-zenith", "10", "--view-azimuth", "0", "--sun-zenith", "91"])
    assert rc == 2 and "--sun-zenith" in capsys.readouterr().err


def test_render_writes_cube_cir_depth_normals(run_dir, tmp_path):
    out = tmp_path / "r"
    args = ["render", str(run_dir), "--view-zenith", "35", "--view-azimuth", "120", "--size", "24,16", "--fov", "15",
            "-o", str(out)]
    assert main(args) == 0
    hdr = read_envi_header(out / "cube.hdr")
    assert [float(w) for w in hdr["wavelength"]] == pytest.approx(np.linspace(480.0, 860.0, 8), abs=1e-3)
    assert (int(hdr["samples"]), int(hdr["lines"]), int(hdr["bands"])) == (24, 16, 8)
    # viewers' header fields: CIR as default bands (1-based), band names, NaN as no-data — read by GDAL too
    assert [int(b) for b in hdr["default bands"]] == [7 + 1, 4 + 1, 0 + 1]
    assert hdr["band names"][0] == "480.0 nm" and hdr["data ignore value"] == "nan"
    rasterio = pytest.importorskip("rasterio")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                        # "not georeferenced": a camera view has no map
        with rasterio.open(out / "cube.img") as ds:
            assert ds.count == 8 and np.isnan(ds.nodata) and ds.descriptions[0].startswith("480.0 nm")
    depth = np.load(out / "depth.npy")
    normal = np.load(out / "normal.npy")
    assert depth.shape == (16, 24) and normal.shape == (16, 24, 3)
    # the carpet is flat: normals point up, the depth is the camera's distance along its axis
    ok = np.load(out / "alpha.npy") > 0.5
    assert ok.mean() > 0.9
    np.testing.assert_allclose(normal[ok][:, 2], 1.0, atol=1e-3)
    info = json.loads((out / "render.json").read_text())
    assert info["view_zenith_deg"] == 35.0 and info["timings_s"]["median"]["total_s"] > 0
    vis = np.load(out / "sun_visibility.npy")               # nothing casts a shadow on the flat carpet
    assert vis.shape == (16, 24) and (vis[ok] > 0.99).all()
    for f in ("cir.png", "depth.png", "normal.png", "sun_visibility.png"):
        assert (out / f).stat().st_size > 0
    assert main(args) == 2                                # a finished result is not overwritten
    assert main(args + ["--overwrite"]) == 0


def test_render_orbit_path(run_dir, tmp_path):
    out = tmp_path / "orbit"
    assert main(["render", str(run_dir), "--view-zenith", "30", "--view-azimuth", "0", "--path", "orbit",
                 "--frames", "3", "--size", "16", "-o", str(out), "-q"]) == 0
    assert sorted(p.name for p in (out / "frames").iterdir()) == [f"frame_{k:03d}.png" for k in range(3)]
    from PIL import Image

    assert Image.open(out / "orbit.gif").n_frames == 3


def test_brf_command_with_observations_and_truth(run_dir, tmp_path):
    out = tmp_path / "brf"
    rc = main(["brf", str(run_dir), "--roi", "polygon:3,-5;9,-5;9,5;3,5", "--roi-name", "east",
               "--bands", "480,860", "--step", "15", "--max-zenith", "60", "--polar-azimuths", "6",
               "--polar-zeniths", "2", "--size", "16", "-o", str(out), "-q"])
    assert rc == 0
    for f in ("principal_plane.csv", "principal_plane.png", "polar.csv", "polar.png", "spectra.csv", "spectra.png",
              "observations.csv", "roi.json", "brf.json"):
        assert (out / f).stat().st_size > 0, f
    rows = list(csv.DictReader(open(out / "principal_plane.csv")))
    assert [float(r["signed_view_zenith_deg"]) for r in rows] == [-60, -45, -30, -15, 0, 15, 30, 45, 60]
    assert len(list(csv.DictReader(open(out / "polar.csv")))) == 12
    spec = list(csv.DictReader(open(out / "spectra.csv")))
    assert len(spec) == 8
    # the scene's images are the model's own renders: no error against observations or truth
    assert max(abs(float(r["log_error"])) for r in spec) < 1e-3
    s = json.loads((out / "brf.json").read_text())
    assert s["brf_error"]["vs_truth"]["n_frames"] == 4
    assert max(s["brf_error"]["vs_truth"]["rmse"].values()) < 1e-4
    assert max(s["brf_error"]["vs_observed"]["rmse"].values()) < 1e-4
    assert s["principal_plane"]["peak_signed_zenith_deg"]["480"] == pytest.approx(35.0, abs=8.0)  # hotspot (Li term)


def test_brf_box_roi_and_bad_view(run_dir, tmp_path, capsys):
    assert main(["brf", str(run_dir), "--roi", "box:nope:0,0,4,4", "-o", str(tmp_path / "b"), "-q"]) == 2
    assert "no training view named 'nope'" in capsys.readouterr().err
    out = tmp_path / "box"
    assert main(["brf", str(run_dir), "--roi", "box:v0:2,10,9,22", "--bands", "480", "--step", "30",
                 "--no-polar", "--size", "16", "-o", str(out), "-q"]) == 0
    rows = list(csv.DictReader(open(out / "principal_plane.csv")))
    vals = np.array([float(r["brf_480nm"]) for r in rows])
    assert np.isfinite(vals).all()


def test_products_and_export(run_dir, tmp_path):
    out = tmp_path / "p"
    assert main(["products", str(run_dir), "--size", "16", "-o", str(out), "-q", "--no-check-decoder"]) == 0
    for name in ("iso", "geo", "spec", "total", "nbar", "bsa", "wsa", "anix"):
        hdr = read_envi_header(out / f"{name}.hdr")
        assert int(hdr["bands"]) == 8 and (out / f"{name}.png").stat().st_size > 0
    assert not (out / "vol.hdr").exists()                  # the model has no volumetric term
    info = json.loads((out / "products.json").read_text())
    assert info["settings"]["components"] == ["iso", "geo", "spec"]
    # MODIS-style weights of the carpet (z_geo = 0.2 z_iso, no volumetric term): f_geo / f_iso = 0.2, f_vol = 0
    import spectral.io.envi as envi

    f = {k: np.asarray(envi.open(str(out / f"{k}.hdr"), str(envi_image_path(out / f"{k}.hdr"))).load())
         for k in ("f_iso", "f_vol", "f_geo", "fit_rmse")}
    ok = np.isfinite(f["f_iso"]) & (f["f_iso"] > 0.05)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(np.median(f["f_geo"][ok] / f["f_iso"][ok]), 0.2, rtol=0.01)
    assert np.nanmax(np.abs(f["f_vol"])) < 0.01 * np.nanmax(f["f_iso"])
    assert len(info["mcd43_fit_rmse_per_band"]["p95"]) == 8
    ex = tmp_path / "e"
    assert main(["export", str(run_dir), str(ex)]) == 0
    from plyfile import PlyData

    ply = PlyData.read(str(ex / "gaussians.ply"))
    assert ply["vertex"].count == 400 and "f_dc_0" in ply["vertex"].data.dtype.names
    info = json.loads((ex / "export.json").read_text())
    assert info["n_gaussians"] == 400
    assert main(["render", str(ex / "model.safetensors"), "--view-zenith", "0", "--view-azimuth", "0",
                 "--size", "8", "-o", str(tmp_path / "from_export")]) == 0


def test_bench_analysis_runs_on_a_small_synthetic_model(tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "analysis", "--gaussians", "2000", "--size", "16", "--repeats", "1", "--threads", "1",
                 "--polar-azimuths", "4", "--polar-zeniths", "2", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["n_gaussians"] == 2000 and res["bands"] == 164
    assert res["polar_map"]["directions"] == 8 and res["render"]["median_s"] > 0


def test_export_refuses_unknown_view_dependence(run_dir, tmp_path, capsys):
    assert main(["export", str(run_dir), str(tmp_path / "e"), "--view-dependence", "sometimes"]) == 2
    assert "--view-dependence" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()
