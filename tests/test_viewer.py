"""The viewer's pure pieces (brfgs.viewer.cameras, formula, frames, roi): no viser, no browser."""

import contextlib
import json
import math

import numpy as np
import pytest
import torch
from matplotlib import colormaps

from brfgs.analysis import brf as B
from brfgs.analysis.bench import synthetic_model
from brfgs.analysis.polygons import read_geojson_polygons
from brfgs.products.maps import nadir_camera
from brfgs.data.cameras import Intrinsics, look_at_c2w, project_points, viewmat_from_c2w
from brfgs.errors import UserError
from brfgs.model import render
from brfgs.model.camera import camera_from_intrinsics
from brfgs.viewer.cameras import c2w_from_viser, fov_from_intrinsics, intrinsics_from_fov, viser_from_c2w
from brfgs.viewer.formula import NDVI, parse_formula
from brfgs.viewer.frames import parse_mode, render_frame
from brfgs.viewer.roi import click_ray, disc_roi, polar_image, roi_directional, roi_spectrum, save_roi, surface_hit


@pytest.fixture(scope="module")
def tm():
    return synthetic_model(n_gaussians=2000)


@pytest.fixture(scope="module")
def nadir(tm):
    return nadir_camera(tm, size=64)


# ---------------------------------------------------------------- cameras


def test_viser_camera_round_trip_and_axes():
    rng = np.random.default_rng(0)
    for _ in range(20):
        eye = rng.normal(size=3) * 50 + np.array([0, 0, 100])
        c2w = look_at_c2w(eye, rng.normal(size=3))
        pos, wxyz = viser_from_c2w(c2w)
        assert np.allclose(c2w_from_viser(pos, wxyz), c2w, atol=1e-9)
        # viser's camera axes are OpenCV's: +z of the quaternion's frame looks at the target
        R = c2w_from_viser(pos, wxyz)[:3, :3] @ np.diag([1.0, -1.0, -1.0])
        assert np.allclose(R, np.linalg.inv(viewmat_from_c2w(c2w))[:3, :3], atol=1e-9)
    # a point straight ahead of the viser camera (its +z) projects to the image centre
    c2w = c2w_from_viser(np.array([1.0, 2.0, 50.0]), np.array([0.0, 1.0, 0.0, 0.0]))  # 180° about x: looks down
    intr = intrinsics_from_fov(math.radians(40), 1.5, 100)
    uv, z = project_points(np.array([[1.0, 2.0, 0.0]]), c2w, intr)
    assert np.allclose(uv[0], [intr.cx, intr.cy]) and z[0] == pytest.approx(50.0)


def test_intrinsics_from_fov_round_trip():
    intr = intrinsics_from_fov(math.radians(50), 16 / 9, 270)
    assert (intr.w, intr.h) == (480, 270)
    fov, aspect = fov_from_intrinsics(intr)
    assert fov == pytest.approx(math.radians(50)) and aspect == pytest.approx(480 / 270)


# ---------------------------------------------------------------- formulas


def test_formula_ndvi_and_decimal_bands():
    f = parse_formula(NDVI)
    assert f.wavelengths_nm == (860.0, 650.0)
    nir, red = np.array([[0.5, 0.0]]), np.array([[0.1, 0.0]])
    v = f.evaluate({860.0: nir, 650.0: red})
    assert v[0, 0] == pytest.approx(0.4 / 0.6) and np.isnan(v[0, 1])  # 0/0 → NaN
    g = parse_formula("-2.5*b550.5 / (b700 + 1)")
    assert g.wavelengths_nm == (550.5, 700.0)
    assert g.evaluate({550.5: np.ones(1), 700.0: np.ones(1)})[0] == pytest.approx(-1.25)


@pytest.mark.parametrize("bad", ["__import__('os')", "b860 ** 2", "x + b860", "b860.real", "open", "1 + 2", "",
                                 "b860 +", "(lambda: 1)()", "b860 if 1 else 0"])
def test_formula_rejects_everything_else(bad):
    with pytest.raises(UserError) as e:
        parse_formula(bad)
    assert e.value.field == "formula"


# ---------------------------------------------------------------- a few bands of the decoder


@pytest.mark.parametrize("bands", [[0], [163, 0, 50, 123], [1, 2, 3], [5, 5], list(range(164))])
@pytest.mark.parametrize("rows", [20, 700])  # 700 x 25 pixels: more than one block of BLOCK_PX, the last one partial
def test_decode_bands_equals_the_full_decode(tm, bands, rows):
    from brfgs.spectral.band_decode import BLOCK_PX, decode_bands
    z = 2.0 * torch.randn(rows * 25, tm.gaussians.latent_dim, generator=torch.Generator().manual_seed(1))
    assert rows < 100 or (rows * 25 > 2 * BLOCK_PX and rows * 25 % BLOCK_PX)
    full = tm.decoder.decode(z)  # [N, B]
    assert torch.allclose(decode_bands(tm.decoder, z.reshape(rows, 25, -1), bands),
                          full[:, bands].reshape(rows, 25, -1), atol=2e-6)


# ---------------------------------------------------------------- display modes


def test_parse_mode():
    assert parse_mode("cir").kind == "cir" and parse_mode("band:860").wavelength_nm == 860.0
    assert parse_mode("index").formula.text == NDVI
    assert parse_mode("kernel:geo").term == "geo"
    for bad in ("band:abc", "kernel:foo", "rainbow", "depth:3"):
        with pytest.raises(UserError):
            parse_mode(bad)


def test_frames_match_the_library_render(tm, nadir):
    c2w, intr = nadir
    rv = render(tm, camera_from_intrinsics(c2w, intr), normals=True)
    cir = render_frame(tm, c2w, intr, parse_mode("cir"))
    assert cir.rgb.shape == (64, 64, 3) and cir.rgb.dtype == np.uint8
    assert np.abs(cir.rgb.astype(float) - np.clip(rv.cir, 0, 1) * 255).max() <= 0.51
    a = render_frame(tm, c2w, intr, parse_mode("alpha")).rgb
    assert np.abs(a[..., 0] - rv.alpha * 255).max() <= 0.51
    n = render_frame(tm, c2w, intr, parse_mode("normals")).rgb
    hit = rv.alpha > 0
    assert np.abs(n[hit].astype(float) - (rv.normal[hit] + 1) * 127.5).max() <= 0.51
    b = render_frame(tm, c2w, intr, parse_mode("band:860")).rgb
    band = rv.cube[..., tm.band_indices([860])[0]]
    expect = np.clip(band / np.percentile(band, 99.0), 0, 1) * 255  # the band over its 99th percentile
    assert np.abs(b[..., 0] - expect).max() <= 0.51 and b[..., 0].std() > 1
    # NDVI on the red-yellow-green map over [-1, 1]
    ndvi = parse_formula(NDVI).evaluate({860.0: band, 650.0: rv.cube[..., tm.band_indices([650])[0]]})
    g = render_frame(tm, c2w, intr, parse_mode("index")).rgb.astype(float)
    expect = colormaps["RdYlGn"](np.clip((np.nan_to_num(ndvi) + 1) / 2, 0, 1))[..., :3] * 255
    surface = (rv.alpha >= 0.1) & np.isfinite(ndvi)
    assert surface.mean() > 0.5 and np.abs(g - expect)[surface].max() <= 0.51
    assert (g[~surface] == 0).all()  # the background and values without a number: black


def test_every_mode_renders_and_they_differ(tm, nadir):
    c2w, intr = nadir
    imgs = {m: render_frame(tm, c2w, intr, parse_mode(m)).rgb
            for m in ("cir", "truecolor", "band:700", "index", "depth", "normals", "alpha",
                      "kernel:iso", "kernel:vol", "kernel:geo", "kernel:spec")}
    for m, im in imgs.items():
        assert im.shape == (64, 64, 3) and im.std() > 1.0, m
    names = list(imgs)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not np.array_equal(imgs[a], imgs[b]), (a, b)


def test_kernel_contributions_sum_to_the_render(tm, nadir):
    """iso + vol + geo + spec contributions add up to the decoded reflectance of the full render."""
    from brfgs.viewer.frames import _kernel_view, kernel_contribution
    c2w, intr = nadir
    cam = camera_from_intrinsics(c2w, intr)
    sun = (tm.sun_zenith_deg, tm.sun_azimuth_deg)
    view = _kernel_view(tm, cam, sun, "iso", "auto")
    band = tm.cir_indices[0]
    total = sum(kernel_contribution(tm, view.image, view.alpha, t, band) for t in ("iso", "vol", "geo", "spec"))
    rv = render(tm, cam)
    assert np.allclose(total, rv.cube[..., band], atol=2e-4)


def test_sun_changes_the_frame_but_not_the_geometry(tm, nadir):
    c2w, intr = nadir
    a = render_frame(tm, c2w, intr, parse_mode("cir"), sun_zenith_deg=10.0, sun_azimuth_deg=0.0)
    b = render_frame(tm, c2w, intr, parse_mode("cir"), sun_zenith_deg=60.0, sun_azimuth_deg=200.0)
    assert not np.array_equal(a.rgb, b.rgb)
    assert np.array_equal(a.view.depth, b.view.depth)


# ---------------------------------------------------------------- click → ROI


def test_click_ray_goes_through_the_clicked_pixel(tm, nadir):
    c2w, intr = nadir
    o, d = click_ray(c2w, intr, 0.25, 0.75)
    uv, z = project_points((o + 10.0 * d)[None], c2w, intr)
    assert np.allclose(uv[0], [0.25 * intr.w, 0.75 * intr.h], atol=1e-9) and z[0] > 0
    assert np.linalg.norm(d) == pytest.approx(1.0)


def test_roi_spectrum_and_brf_are_the_brf_library_results(tm, nadir, tmp_path):
    c2w, intr = nadir
    p = surface_hit(tm, c2w, intr, 0.5, 0.5)
    roi = disc_roi(p, 3.0)
    assert roi.area_m2 == pytest.approx(math.pi * 9, rel=0.01)
    sun = (40.0, 120.0)
    res = roi_spectrum(tm, roi, c2w, intr, sun)
    ref, n, _ = B.roi_mean_from_view(tm, roi, c2w, intr, tm.sun_direction(*sun), min_alpha=0.1)
    assert res.n_pixels == n > 0 and np.array_equal(res.spectrum, ref)
    seen = []
    roi_directional(tm, res, bands_nm=(480.0, 860.0), step_deg=25.0, polar_azimuths=4, polar_zeniths=2,
                    each=lambda k, total: seen.append((k, total)) or contextlib.nullcontext())
    assert seen == [(k, 7 + 8) for k in range(15)]  # 7 principal-plane and 2 x 4 polar directions
    bi = tm.band_indices([480, 860])
    s, pp = B.principal_plane(tm, roi, bi, step_deg=25.0, sun_deg=sun, min_alpha=0.1)
    assert np.array_equal(res.pp_signed_zenith_deg, s) and np.array_equal(res.pp_values, pp.values, equal_nan=True)
    assert res.extra["principal_plane_pixels"] == pp.n_pixels.tolist()
    zc, ac, vals, _ = B.polar_map(tm, roi, bi, n_azimuth=4, n_zenith=2, sun_deg=sun, min_alpha=0.1)
    assert np.array_equal(res.polar_zenith_deg, zc) and np.array_equal(res.polar_azimuth_deg, ac)
    assert np.array_equal(res.polar_values, vals) and res.polar_values.shape == (2, 4, 2)
    assert np.isfinite(res.polar_values).all()
    img = polar_image(res.polar_zenith_deg, res.polar_azimuth_deg, res.polar_values[..., 1], size_px=50)
    assert img.shape == (50, 50, 3) and img[25, 25].tolist() != [255, 255, 255] and img[0, 0].tolist() == [255] * 3
    paths = save_roi(res, tmp_path / "roi")
    assert sorted(p.name for p in paths) == ["polar.csv", "principal_plane.csv", "roi.geojson", "spectrum.csv"]
    polys, _ = read_geojson_polygons(tmp_path / "roi" / "roi.geojson")
    assert np.allclose(polys[0][0][:32], roi.vertices_xy_m)
    lines = (tmp_path / "roi" / "spectrum.csv").read_text().splitlines()
    assert lines[0] == "wavelength_nm,reflectance" and len(lines) == 1 + len(tm.wavelengths_nm)
    assert json.loads((tmp_path / "roi" / "roi.geojson").read_text())["features"][0]["geometry"]["type"] == "Polygon"


def test_disc_roi_rejects_bad_radius():
    with pytest.raises(UserError):
        disc_roi(np.zeros(3), -1.0)


# ---------------------------------------------------------------- the command's errors


def test_view_command_bad_run_and_busy_port_are_one_line_errors(tm, tmp_path, capsys):
    import socket

    from brfgs.cli import main
    from brfgs.viewer.ports import check_port_free

    assert main(["view", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing" in err[0] and "not found" in err[0]
    (tmp_path / "empty").mkdir()
    assert main(["view", str(tmp_path / "empty")]) == 2
    assert "model.safetensors" in capsys.readouterr().err
    model = tm.save(tmp_path / "run" / "model.safetensors")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        assert main(["view", str(model.parent), "--port", str(port)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--port" in err[0] and str(port) in err[0]
        with pytest.raises(UserError) as e:
            check_port_free("127.0.0.1", port)
        assert e.value.field == "--port"
    with pytest.raises(UserError):
        check_port_free("127.0.0.1", 70000)


def test_frame_comparison_render_observation_error(tm):
    from brfgs.viewer.frames import frame_comparison
    rgb, obs, err = frame_comparison(tm, 1, None)
    assert rgb.shape == (128, 128, 3) and obs is None and err is None
    fr = tm.frames[1]
    cube = render(tm, camera_from_intrinsics(np.asarray(fr["c2w"]), tm.intrinsics)).cube  # a perfect observation
    rgb2, obs2, err2 = frame_comparison(tm, 1, cube)
    assert np.array_equal(rgb2, rgb) and np.abs(obs2.astype(int) - rgb.astype(int)).max() <= 1
    assert err2.shape == rgb.shape and err2.max() < 40  # magma's dark end: no error
    noisy = cube + 0.2
    assert frame_comparison(tm, 1, noisy)[2].mean() > err2.mean() + 20
    with pytest.raises(UserError):
        frame_comparison(tm, 1, cube[:10])


def test_bench_viewer_rejects_a_bad_mode_before_rendering(capsys):
    from brfgs.cli import main
    assert main(["bench", "viewer", "--modes", "cir,rainbow"]) == 2
    assert "rainbow" in capsys.readouterr().err


def test_bench_viewer_times_frames_and_band_decoding(tmp_path):
    """brfgs bench viewer on a small synthetic model: a median per mode, and for the spectral modes the
    band decoding timed against the full decode on the same latents, equal within float rounding."""
    from brfgs.cli import main
    out = tmp_path / "bench.json"
    assert main(["bench", "viewer", "--gaussians", "500", "--size", "32", "--modes", "cir,depth,band:860",
                 "--repeats", "2", "--threads", "1", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert set(res["modes"]) == {"cir", "depth", "band:860"}
    assert all(r["median_s"] > 0 for r in res["modes"].values())
    assert "decode" not in res["modes"]["depth"]
    for name in ("cir", "band:860"):
        dec = res["modes"][name]["decode"]
        assert dec["median_s"] > 0 and dec["reference_median_s"] > 0 and dec["max_abs_difference"] < 1e-5
    assert len(res["modes"]["cir"]["decode"]["bands"]) == 3
