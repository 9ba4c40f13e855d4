"""Simulated flights as real ones are: a sun that moves over the views (per-view UTC times, NREL SPA)
and a drifting downwelling irradiance (per-frame irradiance_scale), read back by the scene reader."""

from __future__ import annotations

import json

import numpy as np

from brfgs.data.cameras import pose_from_view_angles
from brfgs.data.scene import read_scene
from brfgs.sim import SimConfig, simulate
from brfgs.sim.acquisition import _make_renderer


def test_moving_the_sun_renders_what_a_renderer_built_for_that_sun_renders():
    kw = dict(scene="testsite", size=16, bands=3)
    c2w = pose_from_view_angles(30.0, 40.0, 100.0)
    _, moved = _make_renderer(SimConfig.tiny(**kw))
    intr = SimConfig.tiny(**kw).intrinsics()
    before = moved.render_cube(c2w, intr, 1)
    _, fixed = _make_renderer(SimConfig.tiny(**kw, sun_zenith_deg=55.0, sun_azimuth_deg=210.0))
    moved.set_sun(55.0, 210.0)
    after = moved.render_cube(c2w, intr, 1)
    np.testing.assert_array_equal(after, fixed.render_cube(c2w, intr, 1))
    assert np.abs(after - before).mean() > 0.005                        # shadows and hotspot moved


def test_timed_flight_with_irradiance_drift(tmp_path):
    cfg = SimConfig.tiny(size=16, bands=4, views=13, spp=4, n_dark=2, origin=(48.1, 11.5, 520.0),
                         start_time="2024-06-21T07:00:00Z", duration_min=40.0, irradiance_drift=0.1)
    root = simulate(tmp_path / "flight", cfg, progress=False)
    meta = json.loads((root / "transforms.json").read_text())
    times = [f["time"] for f in meta["frames"]]
    assert times[0].startswith("2024-06-21T07:00:00") and times[-1].startswith("2024-06-21T07:40:00")
    scales = np.array([f["irradiance_scale"] for f in meta["frames"]])
    assert scales.min() >= 0.9 - 1e-9 and scales.max() <= 1.1 + 1e-9 and scales.max() - scales.min() > 0.1
    sc = read_scene(root)
    zen = np.array([f.sun_zenith_deg for f in sc.frames])
    assert zen[0] - zen[-1] > 5.0                                      # the sun climbs ~6° in 40 morning minutes
    np.testing.assert_allclose(zen, SimConfig.from_json(cfg.to_json()).view_suns()[0])
    # brfgs inspect's summary shows the flight
    from brfgs.data.summary import format_summary, summarize

    summ = summarize(sc, progress=False)
    assert summ.flight["sun_zenith_range_deg"] == [zen.min(), zen.max()] and summ.flight["origin"]["latitude_deg"] == 48.1
    text = format_summary(summ)
    assert "frame suns" in text and "irradiance scale" in text and "origin" in text
    assert set(summ.ring_spacing_deg) == set(summ.rings) and "view spacing" in text
    # the simulator's sky share is the scene's field (a downwelling sensor's), shown by inspect
    assert summ.diffuse_fraction_source == "transforms.json" and "diffuse fraction" in text
    np.testing.assert_allclose(summ.diffuse_fraction, 0.1 * (550.0 / sc.wavelengths_nm) ** 2.5, rtol=0, atol=1e-6)
    # the reader divides each frame by its irradiance scale: observed / scale ≈ the clean truth
    for i in (2, 9):
        obs, truth = sc.load_image(i), sc.load_truth(i)
        ratio = np.median(obs[truth > 0.05] / truth[truth > 0.05])
        assert abs(ratio - 1.0) < 0.02, (i, ratio, scales[i])
        raw = np.median(obs[truth > 0.05] * scales[i] / truth[truth > 0.05])
        assert abs(raw - scales[i]) < 0.02


def test_distorted_camera_is_undistorted_back_to_the_pinhole_view(tmp_path):
    """--distortion renders through an OPENCV lens; brfgs's reader resamples the frame back onto the
    pinhole camera: the resampled ray-cast depth equals the pinhole simulation's depth."""
    from brfgs.data.undistort import resample_cube

    kw = dict(scene="testsite", size=32, bands=3, views=13, spp=1, n_dark=0)
    dist = (-0.15, 0.03, 0.002, -0.001)
    bent = simulate(tmp_path / "bent", SimConfig.tiny(**kw, distortion=dist), progress=False)
    flat = simulate(tmp_path / "flat", SimConfig.tiny(**kw), progress=False)
    meta = json.loads((bent / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV" and [meta[k] for k in ("k1", "k2", "p1", "p2")] == list(dist)
    sc = read_scene(bent)
    cam = sc.frames[-1].camera                                          # an oblique view: depth varies across it
    assert cam is not None and cam.dist == dist
    name = sc.frames[-1].name
    d_bent = np.load(bent / "truth" / "depth" / f"{name}.npy")
    d_flat = np.load(flat / "truth" / "depth" / f"{name}.npy")
    back = resample_cube(d_bent[..., None], cam, sc.intrinsics)[..., 0]
    ok = np.isfinite(back) & np.isfinite(d_flat)
    assert ok.mean() > 0.9
    assert np.median(np.abs(back[ok] - d_flat[ok])) < 0.02 * np.median(d_flat[ok])
    assert np.median(np.abs(d_bent[ok] - d_flat[ok])) > 3 * np.median(np.abs(back[ok] - d_flat[ok]))   # it was bent
    assert sc.load_image(0).shape == (32, 32, 3)
