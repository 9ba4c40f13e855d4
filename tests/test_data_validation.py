"""One test per validation rule: exit status 2, the file and field named, nothing written to the scene."""

import json
import shutil

import numpy as np
import pytest
from scenes import make_scene, snapshot

from brfgs.cli import main
from brfgs.data.cube_io import write_envi


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    return make_scene(tmp_path_factory.mktemp("pristine") / "scene")


@pytest.fixture
def scene(pristine, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(pristine, root)
    return root


def edit_meta(root, fn):
    meta = json.loads((root / "transforms.json").read_text())
    fn(meta)
    (root / "transforms.json").write_text(json.dumps(meta))


def run_inspect(root, tmp_path, capsys, *extra):
    before = snapshot(root)
    rc = main(["inspect", str(root), "--out", str(tmp_path / "out"), "-q", *extra])
    err = capsys.readouterr().err
    assert snapshot(root) == before, "the scene folder was modified"
    return rc, err


def expect_error(root, tmp_path, capsys, *needles, extra=()):
    rc, err = run_inspect(root, tmp_path, capsys, *extra)
    assert rc == 2, err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, f"{n!r} not in {err!r}"
    return err


def test_valid_scene_passes(scene, tmp_path, capsys):
    rc, err = run_inspect(scene, tmp_path, capsys)
    assert rc == 0, err
    out = capsys.readouterr().out
    assert (tmp_path / "out" / "views_polar.png").stat().st_size > 1000


def test_missing_cube(scene, tmp_path, capsys):
    (scene / "images" / "view_03.img").unlink()
    expect_error(scene, tmp_path, capsys, "view_03.hdr", "view_03", "data file")


def test_missing_header(scene, tmp_path, capsys):
    (scene / "images" / "view_02.hdr").unlink()
    expect_error(scene, tmp_path, capsys, "view_02.hdr", "not found")


def test_unreadable_cube_header(scene, tmp_path, capsys):
    (scene / "images" / "view_04.hdr").write_text("this is not an ENVI header\n")
    expect_error(scene, tmp_path, capsys, "view_04.hdr", "unreadable")


def test_truncated_cube_data(scene, tmp_path, capsys):
    img = scene / "images" / "view_05.img"
    img.write_bytes(img.read_bytes()[:100])
    expect_error(scene, tmp_path, capsys, "view_05.img", "bytes")


def test_header_band_count_differs(scene, tmp_path, capsys):
    cube = np.zeros((16, 24, 5), np.float32) + 0.2
    write_envi(scene / "images" / "view_01.hdr", cube, np.linspace(420, 880, 5))
    expect_error(scene, tmp_path, capsys, "view_01.hdr", "field 'bands'", "5 bands")


def test_header_wavelengths_differ_from_transforms(scene, tmp_path, capsys):
    cube = np.zeros((16, 24, 6), np.float32) + 0.2
    wl = np.linspace(420, 880, 6)
    wl[2] += 7.0
    write_envi(scene / "images" / "view_06.hdr", cube, wl)
    expect_error(scene, tmp_path, capsys, "view_06.hdr", "field 'wavelength'", "band 2")


def test_wavelengths_not_increasing(scene, tmp_path, capsys):
    edit_meta(scene, lambda m: m["wavelengths_nm"].__setitem__(3, 400.0))
    expect_error(scene, tmp_path, capsys, "transforms.json", "field 'wavelengths_nm'", "increasing")


def test_nan_pixels_reported_not_fatal(scene, tmp_path, capsys):
    cube = np.full((16, 24, 6), 0.2, np.float32)
    cube[0:2, 0:3] = np.nan
    write_envi(scene / "images" / "view_02.hdr", cube, np.linspace(420, 880, 6), np.full(6, 4.0))
    before = snapshot(scene)
    rc = main(["inspect", str(scene), "--out", str(tmp_path / "o"), "-q"])
    out = capsys.readouterr().out
    assert rc == 0 and snapshot(scene) == before
    assert "NaN/Inf pixels   6 in 1 frame(s): view_02=6" in out
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["invalid_pixels"]["view_02"] == 6
    assert np.isfinite(summary["mean_reflectance"]).all()  # NaNs were masked, not averaged


def test_reflectance_out_of_range(scene, tmp_path, capsys):
    cube = np.full((16, 24, 6), 0.2, np.float32)
    cube[4:8, :, 0] = 42.0          # 96 of 384 pixels: more than a glint (tests/test_data_values.py)
    write_envi(scene / "images" / "view_03.hdr", cube, np.linspace(420, 880, 6))
    expect_error(scene, tmp_path, capsys, "view_03.hdr", "frame 'view_03'", "96 of 384 pixels (25.0 %)",
                 "--value-range")
    # glint above 1 and small negatives are accepted by default; the range is configurable
    rc, err = run_inspect(scene, tmp_path, capsys, "--value-range", "-1,50")
    assert rc == 0, err


def test_rotation_not_orthonormal(scene, tmp_path, capsys):
    def f(m):
        m["frames"][4]["transform_matrix"][0][0] *= 1.5
    edit_meta(scene, f)
    expect_error(scene, tmp_path, capsys, "transforms.json", "frames[4] ('view_04').transform_matrix",
                 "orthonormal")


def test_intrinsics_do_not_fit_image(scene, tmp_path, capsys):
    edit_meta(scene, lambda m: m.update(cx=30.0))
    expect_error(scene, tmp_path, capsys, "transforms.json", "field 'cx'", "outside the image width")


def test_image_size_differs_from_transforms(scene, tmp_path, capsys):
    edit_meta(scene, lambda m: m.update(w=32, cx=16.0))
    expect_error(scene, tmp_path, capsys, "view_00.hdr", "24x16", "w=32")


def test_fewer_than_three_frames(scene, tmp_path, capsys):
    edit_meta(scene, lambda m: m.update(frames=m["frames"][:2]))
    expect_error(scene, tmp_path, capsys, "transforms.json", "field 'frames'", "at least 3")


@pytest.mark.parametrize("key,where,value", [
    ("sun_zenith_deg", None, 95.0),
    ("sun_azimuth_deg", None, 720.0),
    ("view_zenith_deg", 5, -3.0),
])
def test_angles_out_of_range(scene, tmp_path, capsys, key, where, value):
    def f(m):
        (m if where is None else m["frames"][where])[key] = value
    edit_meta(scene, f)
    field = key if where is None else f"frames[{where}] ('view_0{where}').{key}"
    expect_error(scene, tmp_path, capsys, "transforms.json", field, "out of range")


def test_file_path_outside_scene_folder(scene, tmp_path, capsys):
    shutil.copy(scene / "images" / "view_01.hdr", tmp_path / "evil.hdr")
    edit_meta(scene, lambda m: m["frames"][1].update(file_path="../evil.hdr"))
    expect_error(scene, tmp_path, capsys, "frames[1].file_path", "outside the scene folder")


def test_missing_transforms_and_bad_json(scene, tmp_path, capsys):
    (scene / "transforms.json").write_text("{ not json")
    expect_error(scene, tmp_path, capsys, "transforms.json", "not valid JSON")
    (scene / "transforms.json").unlink()
    expect_error(scene, tmp_path, capsys, "no transforms.json")


def test_missing_required_field(scene, tmp_path, capsys):
    edit_meta(scene, lambda m: m.pop("sun_zenith_deg"))
    expect_error(scene, tmp_path, capsys, "field 'sun_zenith_deg'", "required field missing")


def test_output_inside_scene_refused(scene, tmp_path, capsys):
    before = snapshot(scene)
    rc = main(["inspect", str(scene), "--out", str(scene / "out"), "-q"])
    assert rc == 2 and "inside the scene folder" in capsys.readouterr().err
    assert snapshot(scene) == before
