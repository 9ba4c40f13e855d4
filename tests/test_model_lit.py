"""A model trained with shadows (option ``shadows``): its spectra are the lit surface's times the sun
and sky illumination (1 − f_b) V + f_b. Checked against a float64 reference of the same product,
against the roof's closed-form shadow (a ground point in it renders f_b × its lit spectrum, and the
shadow moves with the sun), in both decode orders; the per-Gaussian least-squares initialisation
against its limit cases; the scene's diffuse_fraction field and the training options."""

import json
import math

import numpy as np
import pytest
import torch

from brfgs.data import read_scene
from brfgs.data.cameras import Intrinsics, look_at_c2w, project_points
from brfgs.data.sky import clear_sky_diffuse_fraction
from brfgs.errors import UserError
from brfgs.model import camera_from_intrinsics
from brfgs.model.shadows import sun_sky_light
from brfgs.model.view import render, sun_visibility_map
from brfgs.train.presets import preset
from tests.scenes import make_scene
from tests.test_model_shadows import ROOF_HALF_M, ROOF_Z_M, _roof_model

NADIR = Intrinsics(fl_x=80.0, fl_y=80.0, cx=32.0, cy=32.0, w=64, h=64)


def _lit_roof(f_value: float = 0.2, **kw):
    tm, n_ground, ground = _roof_model(**kw)
    tm.config = {**tm.config, "shadows": True}
    tm.scene = {**tm.scene, "diffuse_fraction": [f_value] * len(tm.scene["wavelengths_nm"])}
    return tm, n_ground, ground


def _nadir():
    c2w = look_at_c2w(np.array([0.0, 0.0, 60.0]), np.zeros(3))
    return c2w, camera_from_intrinsics(c2w, NADIR)


def test_the_rendered_cube_is_the_decoded_latent_times_the_light():
    tm, _, _ = _lit_roof(0.2)
    _, cam = _nadir()
    sun = (45.0, 90.0)
    rv = render(tm, cam, sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1], backend="torch")
    assert rv.sun_lit is not None and rv.latent.shape[-1] == tm.gaussians.latent_dim
    unlit = tm.decode(rv.latent).astype(np.float64)                                # [H, W, B]
    alpha = rv.alpha.astype(np.float64)
    vis = sun_visibility_map(tm, cam, tm.sun_visibility(*sun, backend="torch"), backend="torch", min_alpha=0.0)
    v_pix = np.nan_to_num(vis.astype(np.float64)) * alpha + (1.0 - alpha)          # blended V, background lit
    f = 0.2
    ref = unlit * ((1.0 - f) * v_pix[..., None] + f)
    np.testing.assert_allclose(rv.cube, ref, rtol=2e-4, atol=2e-5)
    np.testing.assert_allclose(rv.sun_lit, v_pix, atol=2e-5)


@pytest.mark.parametrize("order", ["pixel", "gaussian"])
def test_a_shadowed_ground_point_renders_the_sky_share_and_the_shadow_moves(order):
    f = 0.2
    tm, _, _ = _lit_roof(f)
    plain, _, _ = _roof_model()
    c2w, cam = _nadir()
    west, east = np.array([-ROOF_Z_M - 1.0, 0.0, 0.0]), np.array([ROOF_HALF_M + 3.0, 0.0, 0.0])
    uv, _ = project_points(np.stack([west, east]), c2w, NADIR)
    (cw, rw), (ce, re) = [(int(c), int(r)) for c, r in uv]
    for sun, dark, light in (((45.0, 90.0), (rw, cw), (re, ce)), ((45.0, 270.0), (re, ce), (rw, cw))):
        lit = render(tm, cam, sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1], backend="torch", decode_order=order).cube
        ref = render(plain, cam, sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1], backend="torch", decode_order=order).cube
        big = np.abs(ref[dark]) > 0.02
        ratio = np.median(lit[dark][big] / ref[dark][big])
        assert f - 0.01 <= ratio <= f + 0.04, ratio                                 # only the sky lights it
        np.testing.assert_allclose(lit[light], ref[light], rtol=0.02, atol=1e-4)     # the sun reaches it


def test_sun_sky_light_limits():
    f = torch.tensor([0.0, 0.1, 0.5])
    v = torch.tensor([[1.0, 0.0], [0.5, 1.0]])
    out = sun_sky_light(f, v)                                                       # [2, 2, 3]
    assert out.shape == (2, 2, 3)
    np.testing.assert_allclose(out[0, 0].numpy(), [1.0, 1.0, 1.0])                  # lit: the whole irradiance
    np.testing.assert_allclose(out[0, 1].numpy(), [0.0, 0.1, 0.5])                  # shadow: the sky's share
    np.testing.assert_allclose(out[1, 0].numpy(), [0.5, 0.55, 0.75])


def test_clear_sky_default_follows_the_sun_the_wavelength_and_the_altitude():
    """SPECTRL2's clear sky: a bluer sky share (Rayleigh scattering) that grows as the sun sinks and
    shrinks with altitude (less air above); 0.1-0.2 at 550 nm for a sun at 20-55°; all in [0, 0.9]."""
    wl = np.array([400.0, 450.0, 550.0, 681.0, 860.0, 1000.0])
    by_zenith = np.stack([clear_sky_diffuse_fraction(wl, z) for z in (0.0, 20.0, 35.0, 55.0, 70.0, 85.0)])
    assert np.all(np.diff(by_zenith[:-1], axis=1) < 0) and np.all(np.diff(by_zenith, axis=0) > 0)
    assert 0.1 < by_zenith[1, 2] < by_zenith[3, 2] < 0.2 and 0.03 < by_zenith[2, 4] < 0.1
    assert by_zenith.min() > 0 and by_zenith.max() <= 0.9
    np.testing.assert_array_equal(clear_sky_diffuse_fraction(wl, 89.0), by_zenith[-1])   # clipped at 85°
    assert np.all(clear_sky_diffuse_fraction(wl, 35.0, altitude_m=2500.0) < by_zenith[2])


def test_without_a_field_each_sun_has_its_own_sky():
    """A model whose scene gives no diffuse fraction lights its shadows with the clear-sky default of the
    sun it is rendered under; a scene without the field gives each frame the default of its own sun."""
    tm, _, _ = _lit_roof(0.2)
    tm.scene = {k: v for k, v in tm.scene.items() if k != "diffuse_fraction"}
    _, cam = _nadir()
    wl = np.asarray(tm.scene["wavelengths_nm"], float)
    for z in (30.0, 65.0):
        rv = render(tm, cam, sun_zenith_deg=z, sun_azimuth_deg=90.0, backend="torch")
        f = clear_sky_diffuse_fraction(wl, z)
        ref = tm.decode(rv.latent).astype(np.float64) * ((1.0 - f) * rv.sun_lit[..., None] + f)
        np.testing.assert_allclose(rv.cube, ref, rtol=2e-4, atol=2e-5)
    assert np.all(tm.diffuse_fraction(65.0).numpy() > tm.diffuse_fraction(30.0).numpy())


def test_a_scene_without_the_field_gives_each_frame_its_suns_sky(tmp_path):
    root = make_scene(tmp_path / "s")
    tf = root / "transforms.json"
    meta = json.loads(tf.read_text())
    meta["frames"][2].update(sun_zenith_deg=60.0, sun_azimuth_deg=150.0)
    tf.write_text(json.dumps(meta))
    sc = read_scene(root)
    np.testing.assert_allclose(sc.diffuse_fraction, clear_sky_diffuse_fraction(sc.wavelengths_nm, sc.sun_zenith_deg))
    np.testing.assert_allclose(sc.frame_diffuse_fraction(2), clear_sky_diffuse_fraction(sc.wavelengths_nm, 60.0))
    assert np.all(sc.frame_diffuse_fraction(2) > sc.frame_diffuse_fraction(0))


def test_the_field_is_read_and_checked(tmp_path):
    root = make_scene(tmp_path / "s")
    assert read_scene(root).diffuse_fraction_source == "clear-sky default"
    tf = root / "transforms.json"
    meta = json.loads(tf.read_text())
    for value, ok in ((0.15, True), ([0.3, 0.2, 0.15, 0.1, 0.08, 0.05], True), ([0.1] * 5, False),
                      (-0.1, False), (0.95, False), ("sky", False), ([0.1, 0.1, 0.1, 0.1, 0.1, math.inf], False)):
        tf.write_text(json.dumps({**meta, "diffuse_fraction": value}).replace("Infinity", "1e999"))
        if ok:
            sc = read_scene(root)
            np.testing.assert_allclose(sc.diffuse_fraction, np.broadcast_to(value, (6,)))
            assert sc.diffuse_fraction_source == "transforms.json"
        else:
            with pytest.raises(UserError) as e:
                read_scene(root)
            assert "diffuse_fraction" in str(e.value.field) and e.value.file is not None


def test_a_frame_may_carry_its_own_sky(tmp_path):
    """frames[k].diffuse_fraction overrides the scene's for that frame (a flight under another sky);
    a bad one is refused naming that frame's field."""
    root = make_scene(tmp_path / "s")
    tf = root / "transforms.json"
    meta = json.loads(tf.read_text())
    meta["diffuse_fraction"] = 0.1
    meta["frames"][1]["diffuse_fraction"] = [0.3, 0.25, 0.2, 0.15, 0.1, 0.05]
    tf.write_text(json.dumps(meta))
    sc = read_scene(root, bands=[1, 2, 4])
    np.testing.assert_allclose(sc.frame_diffuse_fraction(0), [0.1, 0.1, 0.1])
    np.testing.assert_allclose(sc.frame_diffuse_fraction(1), [0.25, 0.2, 0.1])      # the selected bands
    for bad in (0.95, [0.2] * 5, "haze"):
        meta["frames"][1]["diffuse_fraction"] = bad
        tf.write_text(json.dumps(meta))
        with pytest.raises(UserError) as e:
            read_scene(root)
        assert str(e.value.field).startswith("frames[1].diffuse_fraction") and str(e.value.file) == str(tf)


def test_the_options_refuse_what_cannot_have_shadows():
    assert preset("tiny", shadows=True).shadows
    for bad in (dict(joint=True), dict(variant="cir")):
        with pytest.raises(UserError) as e:
            preset("tiny", shadows=True, **bad)
        assert e.value.field == "shadows"


def test_backprojected_reflectance_limits(tmp_path):
    """Light 1 everywhere: the blending-weighted mean of the images (the plain targets); light c_b in
    every pixel: that mean divided by c_b."""
    from brfgs.model import init_from_points
    from brfgs.model.camera import cameras_from_description
    from brfgs.train.targets import backprojected_reflectance, backprojected_targets

    root = make_scene(tmp_path / "s", w=20, h=14, n_bands=5)
    sc = read_scene(root)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-8, 8, (300, 3)).astype(np.float32)
    pts[:, 2] = 0.0
    gm = init_from_points(pts, np.full((300, 3), 0.3, np.float32), latent_dim=4)

    from brfgs.train.images import ImageStore

    def Store():
        return ImageStore(sc, sc.train_indices)

    from brfgs.model.camera import scene_description
    cams = cameras_from_description(scene_description(sc, np.stack([f.c2w for f in sc.frames])))
    idx = sc.train_indices
    plain = backprojected_targets(gm, Store(), cams, idx, backend="torch")
    ones = backprojected_reflectance(gm, Store(), cams, idx, lambda i, cam: torch.ones(cam.height, cam.width, 5), backend="torch")
    np.testing.assert_allclose(ones.numpy(), plain.numpy(), rtol=1e-5, atol=1e-6)
    c = torch.tensor([0.5, 1.0, 2.0, 0.25, 1.5])
    scaled = backprojected_reflectance(gm, Store(), cams, idx, lambda i, cam: c.expand(cam.height, cam.width, 5), backend="torch")
    np.testing.assert_allclose(scaled.numpy(), plain.numpy() / c.numpy(), rtol=1e-4, atol=1e-6)


def test_the_viewer_bands_are_the_lit_cube_bands():
    from brfgs.viewer.frames import _spectral_view

    tm, _, _ = _lit_roof(0.3)
    _, cam = _nadir()
    bands = [3, 80, 150]
    view, planes = _spectral_view(tm, cam, (45.0, 90.0), bands, "torch")
    full = render(tm, cam, sun_zenith_deg=45.0, sun_azimuth_deg=90.0, backend="torch").cube
    np.testing.assert_allclose(planes, full[..., bands], rtol=1e-4, atol=1e-5)
