"""Hostile values in a scene, each refused by `brfgs inspect` in one line naming the file and the field
(exit status 2, no traceback, the scene folder unchanged): cameras at the origin, below the ground or
beyond 100 km; matrix elements that are huge integers or strings; a file_path that names a folder; frame
times with control characters; ENVI header numbers written with other scripts' digits."""

import json
import shutil

import pytest
from scenes import make_scene, snapshot

from brfgs.cli import main


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    return make_scene(tmp_path_factory.mktemp("pristine") / "scene", n_frames=4, n_bands=3, w=12, h=8, n_dark=0)


@pytest.fixture
def scene(pristine, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(pristine, root)
    return root


def edit(root, fn, raw=None):
    meta = json.loads((root / "transforms.json").read_text())
    fn(meta)
    text = json.dumps(meta)
    (root / "transforms.json").write_text(text.replace('"__V__"', raw) if raw is not None else text)


def refused(root, tmp_path, capsys, *needles):
    before = snapshot(root)
    rc = main(["inspect", str(root), "--out", str(tmp_path / "out"), "-q"])
    err = capsys.readouterr().err
    assert snapshot(root) == before
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)
    return err


def _no_angles(meta, k):
    del meta["frames"][k]["view_zenith_deg"], meta["frames"][k]["view_azimuth_deg"]


def test_a_camera_at_the_origin_without_view_angles(scene, tmp_path, capsys):
    def fn(meta):
        _no_angles(meta, 2)
        for r in range(3):
            meta["frames"][2]["transform_matrix"][r][3] = 0.0
    edit(scene, fn)
    refused(scene, tmp_path, capsys, "transforms.json", "frames[2]", "transform_matrix", "origin")


def test_a_camera_at_the_origin_with_view_angles(scene, tmp_path, capsys):
    def fn(meta):
        for r in range(3):
            meta["frames"][1]["transform_matrix"][r][3] = 0.0
    edit(scene, fn)
    refused(scene, tmp_path, capsys, "transforms.json", "frames[1]", "transform_matrix", "origin")


def test_a_camera_below_the_ground_without_view_angles(scene, tmp_path, capsys):
    def fn(meta):
        _no_angles(meta, 3)
        meta["frames"][3]["transform_matrix"][2][3] = -20.0
    edit(scene, fn)
    refused(scene, tmp_path, capsys, "transforms.json", "frames[3]", "transform_matrix", "below the ground")


@pytest.mark.parametrize("up_m", [1e300, 2e5])
def test_a_camera_farther_than_100_km(scene, tmp_path, capsys, up_m):
    edit(scene, lambda meta: meta["frames"][1]["transform_matrix"][2].__setitem__(3, up_m))
    refused(scene, tmp_path, capsys, "transforms.json", "frames[1]", "transform_matrix", "100 km")


def test_a_camera_within_100_km_is_read(scene, tmp_path, capsys):
    edit(scene, lambda meta: meta["frames"][1]["transform_matrix"][2].__setitem__(3, 9e4))
    assert main(["inspect", str(scene), "--out", str(tmp_path / "out"), "-q"]) == 0, capsys.readouterr().err


def test_a_distance_beyond_100_km(tmp_path, capsys):
    root = make_scene(tmp_path / "s", n_frames=4, n_bands=3, w=12, h=8, n_dark=0, angles_only=True)
    edit(root, lambda meta: meta["frames"][0].__setitem__("distance_m", 1e300))
    refused(root, tmp_path, capsys, "transforms.json", "frames[0]", "distance_m")


def test_a_matrix_element_beyond_the_float_range(scene, tmp_path, capsys):
    edit(scene, lambda meta: meta["frames"][2]["transform_matrix"][0].__setitem__(3, "__V__"), raw=str(10 ** 400))
    refused(scene, tmp_path, capsys, "transforms.json", "frames[2]", "transform_matrix", "beyond the range")


@pytest.mark.parametrize("raw", ['"1"', '"\u0661"', "true"])
def test_a_matrix_element_that_is_a_string_or_a_boolean(scene, tmp_path, capsys, raw):
    edit(scene, lambda meta: meta["frames"][0]["transform_matrix"][1].__setitem__(1, "__V__"), raw=raw)
    refused(scene, tmp_path, capsys, "transforms.json", "frames[0]", "transform_matrix")


@pytest.mark.parametrize("suffix", ["/", "//", "\\"])
def test_a_file_path_with_a_trailing_slash(scene, tmp_path, capsys, suffix):
    edit(scene, lambda meta: meta["frames"][1].__setitem__("file_path", "images/view_01.hdr" + suffix))
    refused(scene, tmp_path, capsys, "transforms.json", "frames[1].file_path", "folder")


@pytest.mark.parametrize("tail", ["\u0000", "\n", "\t", "\x7f", " "])
def test_a_frame_time_ending_in_a_control_character(scene, tmp_path, capsys, tail):
    def fn(meta):
        meta["origin"] = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}
        meta["frames"][2]["time"] = "2024-06-21T10:32:05Z" + tail
    edit(scene, fn)
    refused(scene, tmp_path, capsys, "transforms.json", "frames[2].time")


def test_a_frame_time_in_other_digits(scene, tmp_path, capsys):
    def fn(meta):
        meta["origin"] = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}
        meta["frames"][0]["time"] = "\u0662\u0660\u0662\u0664-06-21T10:32:05Z"
    edit(scene, fn)
    refused(scene, tmp_path, capsys, "transforms.json", "frames[0].time")


def _set_header(path, key, value):
    lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.split("=")[0].strip().lower() != key]
    lines.insert(1, f"{key} = {value}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


@pytest.mark.parametrize("key, value", [("lines", "\u0668"), ("samples", "\u0661\u0662"), ("bands", "\u0663"),
                                        ("lines", "\uff18"), ("samples", "1\u0662"), ("header offset", "\u0660"),
                                        ("lines", "\u00b2")])
def test_envi_numbers_in_other_digits(scene, tmp_path, capsys, key, value):
    _set_header(scene / "images" / "view_02.hdr", key, value)
    refused(scene, tmp_path, capsys, "view_02.hdr", f"'{key}'", "0-9")


def test_envi_wavelengths_in_other_digits(scene, tmp_path, capsys):
    hdr = scene / "images" / "view_01.hdr"
    text = hdr.read_text(encoding="utf-8")
    start = text.index("wavelength = {") + len("wavelength = {")
    first = text[start:].split(",")[0].strip()
    hdr.write_text(text.replace(first, first.translate(str.maketrans("0123456789", "\u0660\u0661\u0662\u0663\u0664"
                                                                     "\u0665\u0666\u0667\u0668\u0669")), 1),
                   encoding="utf-8")
    refused(scene, tmp_path, capsys, "view_01.hdr", "'wavelength'", "0-9")


def test_envi_reflectance_scale_in_other_digits(scene, tmp_path, capsys):
    _set_header(scene / "images" / "view_00.hdr", "reflectance scale factor", "\u0661\u0660")
    refused(scene, tmp_path, capsys, "view_00.hdr", "reflectance scale factor")
