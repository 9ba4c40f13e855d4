"""Truth BRF rendered again by the simulator (Mitsuba), on the Lambertian 'flat' scene."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brfgs.analysis.truth import has_simulator_truth, truth_brf
from brfgs.analysis.roi import PolygonROI


def test_truth_brf_of_a_lambertian_field_is_isotropic_and_the_soil_spectrum(tmp_path):
    pytest.importorskip("mitsuba")
    from brfgs.sim import spectra as sp
    from brfgs.sim.acquisition import SimConfig
    from brfgs.sim.materials import material

    cfg = SimConfig.tiny("flat", bands=6, spp=16, size=16)
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth" / "scene.json").write_text(json.dumps({"config": cfg.to_json()}))
    assert has_simulator_truth(tmp_path)
    roi = PolygonROI(np.array([[-15.0, -15.0], [15.0, -15.0], [15.0, 15.0], [-15.0, 15.0]]))  # 4 m pixels
    res = truth_brf(tmp_path, roi, [0.0, 40.0, 40.0], [0.0, 150.0, 330.0], [1, 4], distance_m=100.0, size=16)
    assert (res.n_pixels > 20).all()
    wl = cfg.wavelengths_nm()
    soil = sp.band_average(material("soil_plain").end1, wl, cfg.fwhm_array_nm())
    np.testing.assert_allclose(res.values, np.tile(soil[[1, 4]], (3, 1)), rtol=0.05)


def test_check_truth_spp_follows_the_scenes_sampler(tmp_path):
    from brfgs.analysis.truth import check_truth_spp
    from brfgs.errors import UserError

    (tmp_path / "truth").mkdir()
    for sampler, good, bad in (("ldsampler", (1, 4, 16, 64, 256), (2, 8, 32, 12)), (None, (1, 2, 8, 32), (3, 12))):
        cfg = {"scene": "flat", "spp": 16} | ({"sampler": sampler} if sampler else {})   # no key: old scene
        (tmp_path / "truth" / "scene.json").write_text(json.dumps({"config": cfg}))
        for spp in good:
            assert check_truth_spp(tmp_path, spp) == spp
        for spp in bad:
            with pytest.raises(UserError, match="power of"):
                check_truth_spp(tmp_path, spp, field="--truth-spp")
    assert check_truth_spp(tmp_path, None) is None


def test_brf_command_compares_polar_maps_with_the_simulator_truth(tmp_path):
    """A Lambertian model of the simulator's flat soil field: the model's polar map and the truth
    rendered again by Mitsuba agree in every band; truth polar CSV/PNG and per-band errors are written."""
    pytest.importorskip("mitsuba")
    import csv

    from brfgs.cli import main
    from brfgs.sim import spectra as sp
    from brfgs.sim.acquisition import SimConfig
    from brfgs.sim.materials import material
    from test_analysis_brf import _write_scene_from_model
    from test_analysis_helpers import carpet_model, write_model_file

    cfg = SimConfig.tiny("flat", bands=4, spp=16, size=16, wavelength_min_nm=480.0, wavelength_max_nm=860.0,
                         sun_zenith_deg=35.0, sun_azimuth_deg=150.0)
    soil = sp.band_average(material("soil_plain").end1, cfg.wavelengths_nm(), cfg.fwhm_array_nm())
    bm = carpet_model(half_m=24.0, n_bands=4, z_left=soil, z_right=soil, components=("iso",))
    np.testing.assert_allclose(bm.wavelengths_nm, cfg.wavelengths_nm())
    scene = _write_scene_from_model(tmp_path / "scene", bm, with_truth=True)
    (scene / "truth" / "scene.json").write_text(json.dumps({"config": cfg.to_json()}))
    write_model_file(tmp_path / "run" / "model.safetensors", bm, scene_root=scene)
    out = tmp_path / "brf"
    args = ["brf", str(tmp_path / "run"), "--roi", "polygon:-12,-12;12,-12;12,12;-12,12", "--bands", "480,860",
            "--step", "30", "--max-zenith", "60", "--polar-azimuths", "6", "--polar-zeniths", "2", "--size", "16",
            "--truth-step", "60", "--truth-size", "16", "--truth-polar-azimuths", "3", "--truth-polar-zeniths", "2",
            "--truth-polar-size", "16", "-o", str(out), "-q"]
    assert main(args + ["--truth-spp", "8"]) == 2             # ldsampler scene: spp must be a power of 4
    assert not (out / "brf.json").exists()
    assert main(args + ["--truth-spp", "4"]) == 0
    for f in ("polar_truth.png", "polar_truth.csv", "truth_error.csv", "principal_plane_truth.csv"):
        assert (out / f).stat().st_size > 0, f
    rows = list(csv.DictReader(open(out / "polar_truth.csv")))
    assert len(rows) == 6
    assert {float(r["view_zenith_deg"]) for r in rows} == {15.0, 45.0}
    truth = np.array([[float(r["truth_480nm"]), float(r["truth_860nm"])] for r in rows])
    model = np.array([[float(r["model_480nm"]), float(r["model_860nm"])] for r in rows])
    np.testing.assert_allclose(truth, np.tile(soil[[0, 3]], (6, 1)), rtol=0.06)
    np.testing.assert_allclose(model, np.tile(soil[[0, 3]], (6, 1)), rtol=1e-3)
    s = json.loads((out / "brf.json").read_text())
    pv = s["polar"]["vs_truth_render"]
    assert pv["n_directions"] == 6 and (pv["n_azimuth"], pv["n_zenith"], pv["size_px"], pv["spp"]) == (3, 2, 16, 4)
    for w, j in (("480", 0), ("860", 3)):
        assert pv["rmse"][w] < 0.06 * soil[j]
        assert abs(pv["mean_bias"][w]) <= pv["rmse"][w] + 1e-12
        assert pv["mean_bias"][w] == pytest.approx(np.mean(model[:, 0 if w == "480" else 1] - truth[:, 0 if w == "480" else 1]),
                                                   abs=1e-5)
    assert s["principal_plane"]["vs_truth_render"]["n_directions"] == 3
    err = list(csv.DictReader(open(out / "truth_error.csv")))
    assert [(r["comparison"], r["wavelength_nm"]) for r in err] == [
        ("principal_plane", "480"), ("principal_plane", "860"), ("polar", "480"), ("polar", "860")]
