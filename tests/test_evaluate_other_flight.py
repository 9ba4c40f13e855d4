"""`brfgs evaluate RUN --scene OTHER` on another flight of the same site: each of OTHER's frames is
rendered from its own camera under its own sun (or, with --sun model, under the sun the model was
trained under) and scored into RUN/evaluate/, leaving the run's own metrics alone; flights that do
not share the model's frame are refused in one line."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import spectral
import torch

from brfgs.cli import main
from brfgs.data import read_scene
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from test_train_cli import TINY

SIM = ["--scene", "testsite", "--size", "32", "--bands", "8", "--views", "13", "--spp", "16", "--seed", "3", "-q"]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Two flights of one site (same seed: same geometry and cameras) at two suns, and a run on the first."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("flights")
    a, b, run = root / "sun35", root / "sun55", root / "run"
    assert main(["simulate", str(a), *SIM, "--sun-zenith", "35", "--sun-azimuth", "150"]) == 0
    assert main(["simulate", str(b), *SIM, "--sun-zenith", "55", "--sun-azimuth", "220"]) == 0
    assert main(["train", str(a), str(run), *TINY, "--backend", "torch"]) == 0
    return a, b, run


def test_another_flight_is_rendered_under_its_own_sun_and_cameras(flights, capsys):
    a, b, run = flights
    own = (run / "metrics.json").read_bytes()
    assert main(["evaluate", str(run), "--scene", str(b), "--quiet", "--backend", "torch"]) == 0
    dest = run / "evaluate" / "sun55-sun-scene"
    assert f"metrics: {dest.resolve() / 'metrics.json'}" in capsys.readouterr().out
    m = json.loads((dest / "metrics.json").read_text())
    assert m["evaluation"] == {"another_scene": True, "sun": "scene", "folder": str(dest.resolve())}
    assert (run / "metrics.json").read_bytes() == own                # the run's own evaluation stays
    assert m["against"]["truth"]["mean"]["psnr"] > 0
    # each written render is the model seen from B's camera under B's sun (not the model's)
    lm, sc = TrainedModel.load(run / "model.safetensors"), read_scene(b)
    assert (lm.sun_zenith_deg, sc.sun_zenith_deg) == (35.0, 55.0)
    i = sc.indices_of("test")[0]
    f = sc.frames[i]
    ref = render(lm, camera_from_intrinsics(f.c2w, sc.intrinsics, f.name), sun_zenith_deg=55.0,
                 sun_azimuth_deg=220.0, backend="torch").cube
    written = np.fromfile(dest / "eval" / "renders" / f"{f.name}.img", "<f4").reshape(ref.shape)
    np.testing.assert_allclose(written, ref, rtol=1e-5, atol=1e-6)
    # --sun model: the same views under the model's own sun, into their own folder
    assert main(["evaluate", str(run), "--scene", str(b), "--sun", "model", "--quiet", "--no-images",
                 "--backend", "torch"]) == 0
    m2 = json.loads((run / "evaluate" / "sun55-sun-model" / "metrics.json").read_text())
    assert m2["evaluation"]["sun"] == "model" and (run / "metrics.json").read_bytes() == own
    assert m2["against"]["truth"]["mean"]["psnr"] != m["against"]["truth"]["mean"]["psnr"]
    # cast shadows of the model's geometry under each sun, against B's truth
    sh, sh2 = m["against"]["truth"]["shadows"], m2["against"]["truth"]["shadows"]
    for x in (sh, sh2):
        assert 0 <= x["accuracy"] <= 1 and x["n_pixels"] > 0 and 0 < x["shadow_share_truth"] < 0.5
        assert 0 < x["cast"]["n_pixels"] < x["n_pixels"]              # crowns' pixels left out
    assert sh["shadow_share_truth"] == sh2["shadow_share_truth"] and sh["n_pixels"] != 0
    assert [v["name"] for v in m2["against"]["truth"]["views"]] == [v["name"] for v in m["against"]["truth"]["views"]]


def test_true_visibility_is_block_averaged_on_downscaled_scenes(flights, tmp_path):
    from brfgs.evaluation.shadows import truth_visibility

    a, _, _ = flights
    full, half = read_scene(a), read_scene(a, downscale=2)
    raw = np.load(a / "truth" / "sun_visibility" / f"{full.frames[0].name}.npy")
    v1 = truth_visibility(full, 0, (full.height, full.width))
    v2 = truth_visibility(half, 0, (half.height, half.width))
    assert np.array_equal(np.isnan(v1), raw == 255) and np.array_equal(v1[raw != 255], raw[raw != 255])
    blk = np.where(raw == 255, np.nan, raw.astype(float)).reshape(16, 2, 16, 2).mean(axis=(1, 3))
    np.testing.assert_array_equal(v2, blk)
    assert truth_visibility(full, 0, (8, 8)) is None                   # not the images' grid
    from brfgs.evaluation.shadows import canopy_pixels

    mats = np.load(a / "truth" / "materials" / f"{full.frames[0].name}.npy")
    table = json.loads((a / "truth" / "materials.json").read_text())["materials"]
    leaf = np.isin(mats, [int(k) for k, v in table.items() if v["bsdf"] == "leaf"])
    assert leaf.any() and np.array_equal(canopy_pixels(full, 0, (32, 32)), leaf)
    assert np.array_equal(canopy_pixels(half, 0, (16, 16)), leaf.reshape(16, 2, 16, 2).any(axis=(1, 3)))


def test_the_model_sun_on_its_own_flight_keeps_the_run_metrics(flights):
    a, b, run = flights
    own = (run / "metrics.json").read_bytes()
    assert main(["evaluate", str(run), "--sun", "model", "--quiet", "--no-images", "--backend", "torch"]) == 0
    m = json.loads((run / "evaluate" / "sun35-sun-model" / "metrics.json").read_text())
    assert m["evaluation"]["another_scene"] is False and (run / "metrics.json").read_bytes() == own


def test_flights_outside_the_model_frame_are_refused(flights, tmp_path, capsys):
    a, b, run = flights
    geo = tmp_path / "geo"
    assert main(["simulate", str(geo), *SIM, "--origin", "47.0,8.0,400"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(run), "--scene", str(geo), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "origin" in err[0] and "transforms.json" in err[0], err
    other = tmp_path / "bands"
    assert main(["simulate", str(other), *[x if x != "8" else "6" for x in SIM]]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(run), "--scene", str(other), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "wavelengths" in err[0], err
    assert main(["evaluate", str(run), "--sun", "noon", "--quiet"]) == 2
    assert "--sun" in capsys.readouterr().err


def test_a_model_with_shadows_trains_from_a_stage1_and_relights_another_flight(flights, tmp_path):
    """--shadows: stage 2 from the run's stage-1 geometry with the flight's own diffuse fraction; the
    model renders each frame of B with the light of B's sun (its cube the decoded latent times
    (1 − f_b) V + f_b, V varying over the view)."""
    a, b, run = flights
    lit = tmp_path / "lit"
    assert main(["train", str(a), str(lit), *TINY, "--backend", "torch", "--shadows",
                 "--from-stage1", str(run / "checkpoints" / "stage1.safetensors")]) == 0
    lm = TrainedModel.load(lit / "model.safetensors")
    field = json.loads((a / "transforms.json").read_text())["diffuse_fraction"]
    assert lm.shadowed and np.allclose(lm.diffuse_fraction(55.0).numpy(), field, atol=1e-6)
    assert main(["evaluate", str(lit), "--scene", str(b), "--quiet", "--no-images", "--backend", "torch"]) == 0
    m = json.loads((lit / "evaluate" / "sun55-sun-scene" / "metrics.json").read_text())
    assert m["against"]["truth"]["mean"]["psnr"] > 0
    sc = read_scene(b)
    f = sc.frames[sc.indices_of("test")[0]]
    rv = render(lm, camera_from_intrinsics(f.c2w, sc.intrinsics, f.name), sun_zenith_deg=55.0, sun_azimuth_deg=220.0,
                backend="torch")
    f_b = lm.diffuse_fraction(55.0).numpy()
    light = (1 - f_b) * rv.sun_lit[..., None] + f_b
    np.testing.assert_allclose(rv.cube, lm.decode(rv.latent) * light, rtol=1e-4, atol=1e-5)
    assert rv.sun_lit.max() - rv.sun_lit.min() > 0.05 and rv.sun_lit.max() <= 1.0 + 1e-6  # the geometry shades
    # a flight under a hazier sky (its own diffuse fraction): its frames are lit by that sky
    hazy = tmp_path / "hazy"
    shutil.copytree(b, hazy)
    meta = json.loads((hazy / "transforms.json").read_text())
    meta["diffuse_fraction"] = 0.4
    (hazy / "transforms.json").write_text(json.dumps(meta))
    assert main(["evaluate", str(lit), "--scene", str(hazy), "--quiet", "--backend", "torch"]) == 0
    written = spectral.open_image(str(lit / "evaluate" / "hazy-sun-scene" / "eval" / "renders" / f"{f.name}.hdr"))
    lit_hazy = render(lm, camera_from_intrinsics(f.c2w, sc.intrinsics, f.name), sun_zenith_deg=55.0,
                      sun_azimuth_deg=220.0, backend="torch", diffuse_fraction=0.4)
    np.testing.assert_allclose(lit_hazy.cube, lm.decode(rv.latent) * (0.6 * rv.sun_lit[..., None] + 0.4), rtol=1e-4,
                               atol=1e-5)
    np.testing.assert_allclose(np.asarray(written.load()), lit_hazy.cube, rtol=1e-5, atol=1e-6)
    assert np.abs(lit_hazy.cube - rv.cube).max() > 1e-3


def test_brf_of_another_flight_is_under_its_sun(flights, capsys):
    """`brfgs brf RUN --scene B`: the BRF (principal plane, observations) under B's sun, the model rendered
    for it; --sun-* under any sun, where the simulator's truth (rendered under the scene's own sun) is left out."""
    a, b, run = flights
    common = ["--roi", "material:grass", "--no-polar", "--step", "15", "--quiet", "--backend", "torch"]
    assert main(["brf", str(run), *common, "--scene", str(b), "--no-truth-render", "-o", str(run / "brf_b")]) == 0
    s = json.loads((run / "brf_b" / "brf.json").read_text())
    assert (s["sun_zenith_deg"], s["sun_azimuth_deg"]) == (55.0, 220.0)
    assert s["principal_plane"]["hotspot_signed_zenith_deg"] == 55.0
    capsys.readouterr()
    assert main(["brf", str(run), *common, "--scene", str(b), "--sun-zenith", "40", "-o", str(run / "brf_40")]) == 0
    assert "no truth comparison" in capsys.readouterr().err
    s40 = json.loads((run / "brf_40" / "brf.json").read_text())
    assert (s40["sun_zenith_deg"], s40["sun_azimuth_deg"]) == (40.0, 220.0) and "truth_error_csv" not in s40["files"]
    pp_b = np.loadtxt(run / "brf_b" / "principal_plane.csv", delimiter=",", skiprows=1)
    pp_40 = np.loadtxt(run / "brf_40" / "principal_plane.csv", delimiter=",", skiprows=1)
    assert not np.allclose(pp_b[:, 1:-1], pp_40[:, 1:-1])                  # another sun, another BRF
    assert main(["brf", str(run), *common, "--sun-zenith", "95"]) == 2
