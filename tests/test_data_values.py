"""What a cube's values mean: glints above the plausible range, unit errors, no-data values and
integer-scaled reflectance (ENVI ``data ignore value`` / ``reflectance scale factor``, GeoTIFF
``GDAL_NODATA``)."""

import json

import numpy as np
import pytest
import spectral.io.envi as envi
import tifffile
from scenes import make_scene, snapshot
from test_data_validation import pristine, scene  # noqa: F401  (fixtures: a copy of one small scene per test)

import brfgs.data.cube_io as cube_io
from brfgs.cli import main
from brfgs.data.cube_io import write_envi
from brfgs.data.scene import read_scene
from brfgs.data.validation import BAD_PIXEL_SHARE, GLINT_PIXEL_SHARE, RangeTally
from brfgs.errors import UserError

H, W, B = 16, 24, 6          # make_scene's cubes: 384 pixels (5 % of them: 19.2, 1 %: 3.84)
WL = np.linspace(420.0, 880.0, B)


def inspect(root, tmp_path, capsys):
    before = snapshot(root)
    rc = main(["inspect", str(root), "--out", str(tmp_path / "out"), "-q"])
    out, err = capsys.readouterr()
    assert snapshot(root) == before, "the scene folder was modified"
    assert "Traceback" not in err
    return rc, out, err


def test_a_few_glint_pixels_are_kept_and_reported(scene, tmp_path, capsys):
    """A car's or a pond's specular glint (BRF > 10 at 3 of 384 pixels) is data, not a unit error."""
    cube = np.full((H, W, B), 0.2, np.float32)
    cube[5, 7, 2:] = [11.6, 12.0, 23.0, 9.0]          # one pixel, several bands above 10
    cube[9, 3, :], cube[0, 0, 0] = 42.0, 10.5
    write_envi(scene / "images" / "view_03.hdr", cube, WL, np.full(B, 4.0))
    rc, out, err = inspect(scene, tmp_path, capsys)
    assert rc == 0, err
    assert "above the range  3 pixel(s) in 1 frame(s): view_03=3" in out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["bright_pixels"]["view_03"] == 3 and summary["bright_pixels"]["view_02"] == 0
    sc = read_scene(scene)
    np.testing.assert_array_equal(sc.load_image(3), cube)     # kept as they are


def test_a_unit_error_is_refused(scene, tmp_path, capsys):
    """Percent reflectance (every value x 100): the bulk of the frame is outside the range."""
    sc = read_scene(scene)
    write_envi(scene / "images" / "view_01.hdr", 100.0 * sc.load_image(1), WL, np.full(B, 4.0))
    rc, out, err = inspect(scene, tmp_path, capsys)
    assert rc == 2
    for needle in ("view_01.hdr", "frame 'view_01'", "of 384 pixels", "reflectance units", "--value-range"):
        assert needle in err, (needle, err)


@pytest.mark.parametrize("value,share", [(50.0, GLINT_PIXEL_SHARE), (-2.0, BAD_PIXEL_SHARE)])
def test_just_over_the_tolerated_share_is_refused(scene, tmp_path, capsys, value, share):
    """Up to 5 % of a frame's pixels may lie above the range (glints), 1 % below it (bad pixels)."""
    n_ok = int(share * H * W)                           # 19 / 3 of 384 pass, one more does not
    for n, want in ((n_ok, 0), (n_ok + 1, 2)):
        cube = np.full((H, W, B), 0.2, np.float32)
        cube.reshape(-1, B)[:n, 0] = value
        write_envi(scene / "images" / "view_04.hdr", cube, WL, np.full(B, 4.0))
        rc, out, err = inspect(scene, tmp_path, capsys)
        assert rc == want, err
        if want:
            assert f"{n} of 384 pixels" in err


def test_values_below_the_range_are_masked(scene, tmp_path, capsys):
    """A dead pixel at -3 is not a reflectance: masked like NaN (counted, out of every loss)."""
    cube = np.full((H, W, B), 0.2, np.float32)
    cube[2, 2, 1] = -3.0
    cube[3, 4, 0] = -0.4                                # small negatives (dark-band noise) stay
    write_envi(scene / "images" / "view_05.hdr", cube, WL, np.full(B, 4.0))
    rc, out, err = inspect(scene, tmp_path, capsys)
    assert rc == 0, err
    assert "NaN/Inf pixels   1 in 1 frame(s): view_05=1" in out
    sc = read_scene(scene)
    img = sc.load_image(5)
    assert np.isnan(img[2, 2, 1]) and not sc.valid_mask(5, img)[2, 2] and sc.valid_mask(5, img).sum() == H * W - 1
    assert img[3, 4, 0] == np.float32(-0.4)


def test_non_finite_pixels_are_masked_whatever_their_share(scene, tmp_path, capsys):
    """NaN and ±Inf are masked and counted as before, not judged as outliers (20 % of the frame here)."""
    cube = np.full((H, W, B), 0.2, np.float32)
    cube[:2, :, 0], cube[2, :, 1], cube[3, :, 2] = np.nan, np.inf, -np.inf     # 4 rows of 16
    write_envi(scene / "images" / "view_05.hdr", cube, WL, np.full(B, 4.0))
    rc, out, err = inspect(scene, tmp_path, capsys)
    assert rc == 0, err
    assert f"NaN/Inf pixels   {4 * W} in 1 frame(s): view_05={4 * W}" in out and "above the range" not in out


def test_the_share_is_per_frame_not_per_row_block(monkeypatch):
    """Blocks of one row: a frame whose outliers sit in one row is judged on all its pixels."""
    cube = np.full((H, W, B), 0.2, np.float32)
    cube[0, :3, 0] = 20.0                              # 3 pixels: 12 % of row 0, 0.8 % of the frame
    tally = RangeTally((-0.5, 10.0))
    for r in range(H):
        tally.add(cube[r:r + 1].copy())
    tally.check(None, "f")                             # accepted
    assert (tally.n_pixels, tally.n_high, tally.high_max) == (H * W, 3, 20.0)


def test_reading_in_blocks_counts_the_whole_frame(scene, monkeypatch):
    cube = np.full((H, W, B), 0.2, np.float32)
    cube[0, :3, 0] = 20.0
    write_envi(scene / "images" / "view_02.hdr", cube, WL, np.full(B, 4.0))
    monkeypatch.setattr(cube_io, "CHUNK_BYTES", W * B * 4)      # one row per block
    sc = read_scene(scene)
    np.testing.assert_array_equal(sc.load_image(2), cube)
    assert sc.bright_counts["view_02"] == 3


def write_int16_envi(path_hdr, stored, extra):
    meta = {"wavelength units": "Nanometers", "wavelength": [f"{w:.4f}" for w in WL], **extra}
    envi.save_image(str(path_hdr), stored, metadata=meta, interleave="bip", force=True, ext=".img",
                    dtype=np.int16)


def test_envi_reflectance_scale_factor_and_data_ignore_value(scene, tmp_path, capsys):
    """int16 reflectance x 10000 with -9999 outside the orthorectified footprint, as processors write it."""
    rng = np.random.default_rng(3)
    refl = (0.05 + 0.4 * rng.random((H, W, B))).astype(np.float32)
    stored = np.round(refl * 10000).astype(np.int16)
    stored[:, :2] = -9999                               # no data along the left edge
    write_int16_envi(scene / "images" / "view_06.hdr", stored,
                     {"reflectance scale factor": "10000", "data ignore value": "-9999"})
    img = read_scene(scene).load_image(6)
    assert np.isnan(img[:, :2]).all()
    np.testing.assert_allclose(img[:, 2:], stored[:, 2:] / 10000.0, rtol=0, atol=1e-7)
    rc, out, err = inspect(scene, tmp_path, capsys)
    assert rc == 0, err
    assert f"NaN/Inf pixels   {2 * H} in 1 frame(s): view_06={2 * H}" in out


@pytest.mark.parametrize("field,value,needle", [("reflectance scale factor", "0", "a positive number"),
                                                ("reflectance scale factor", "abc", "a positive number"),
                                                ("data ignore value", "none", "a number or nan")])
def test_bad_value_fields_are_refused(scene, tmp_path, capsys, field, value, needle):
    stored = np.full((H, W, B), 2000, np.int16)
    write_int16_envi(scene / "images" / "view_02.hdr", stored, {field: value})
    rc, out, err = inspect(scene, tmp_path, capsys)
    assert rc == 2
    for n in ("view_02.hdr", field, needle):
        assert n in err, (n, err)


def test_without_a_scale_factor_integer_counts_are_a_unit_error(scene, tmp_path, capsys):
    stored = np.full((H, W, B), 2000, np.int16)
    write_int16_envi(scene / "images" / "view_02.hdr", stored, {})
    rc, out, err = inspect(scene, tmp_path, capsys)
    assert rc == 2 and "384 of 384 pixels (100.0 %)" in err


def _geotiff_scene(tmp_path, nodata_text: str, fill: float):
    """make_scene's scene with view_02 a float GeoTIFF carrying GDAL_NODATA ``nodata_text`` (as GDAL
    writes it) and a 2 x 4 patch of ``fill``; returns (root, patch slice)."""
    root = make_scene(tmp_path / "s", fmt="npy")
    meta = json.loads((root / "transforms.json").read_text())
    fr = meta["frames"][2]
    cube = np.load(root / fr["file_path"])
    patch = (slice(4, 6), slice(5, 9))
    cube[patch] = fill
    tif = fr["file_path"].replace(".npy", ".tif")
    tifffile.imwrite(root / tif, np.moveaxis(cube, -1, 0), photometric="minisblack", planarconfig="separate",
                     extratags=[(cube_io.GDAL_NODATA_TAG, "s", 0, nodata_text, True)])
    fr["file_path"] = tif
    (root / "transforms.json").write_text(json.dumps(meta))
    return root, patch


def test_geotiff_gdal_nodata(tmp_path):
    """A float GeoTIFF whose GDAL_NODATA is float32's lowest value, written as text (as GDAL does)."""
    low = np.finfo(np.float32).min
    root, patch = _geotiff_scene(tmp_path, repr(float(low)), low)
    img = read_scene(root).load_image(2)
    assert np.isnan(img[patch]).all() and np.isfinite(img).sum() == (H * W - 8) * B


def test_geotiff_bad_gdal_nodata_is_refused(tmp_path, capsys):
    root, _ = _geotiff_scene(tmp_path, "none", 0.2)
    rc, out, err = inspect(root, tmp_path, capsys)
    assert rc == 2
    for n in ("view_02.tif", "GDAL_NODATA", "a number or nan", "'none'"):
        assert n in err, (n, err)


def test_range_tally_refusal_names_file_and_field(tmp_path):
    tally = RangeTally((-0.5, 10.0))
    tally.add(np.full((2, 2, 3), 500.0, np.float32))
    with pytest.raises(UserError) as e:
        tally.check(tmp_path / "c.hdr", "v")
    assert e.value.field == "reflectance" and "4 of 4 pixels (100.0 %)" in str(e.value)
