"""`brfgs import colmap` refuses impossible values in one line naming the file and the camera or image,
the same for binary and text models: focal lengths that are not finite and positive, image sizes
outside 1..65,535, non-finite parameters and poses, zero quaternions, repeated image names, stems and
ids, names that are not UTF-8 or too long; rigs and frames whose structure does not hold together."""

from __future__ import annotations

import zlib  # noqa: F401  (before pycolmap)
import json
import struct

import numpy as np
import pycolmap
import pytest

from brfgs.init.colmap_read import read_model
from colmap_bytes import TINY, Cam, Img, make_project, run_import
from test_import_colmap_binary import _pycolmap_rig_model

INF, NAN = float("inf"), float("nan")
Q0 = TINY.images[0].pose
BAD = {  # name: (records, file kind, words the message must hold)
    "focal 0": (TINY.with_camera(params=(0.0, 31.0, 12.0, 8.0)), "cameras", ("camera 1", "focal length fx = 0.0")),
    "focal negative": (TINY.with_camera(params=(30.0, -31.0, 12.0, 8.0)), "cameras", ("camera 1", "focal length")),
    "focal NaN": (TINY.with_camera(params=(NAN, 31.0, 12.0, 8.0)), "cameras", ("camera 1", "fx is nan", "finite")),
    "focal +inf": (TINY.with_camera(params=(INF, 31.0, 12.0, 8.0)), "cameras", ("camera 1", "fx is inf", "finite")),
    "focal -inf": (TINY.with_camera(params=(30.0, -INF, 12.0, 8.0)), "cameras", ("camera 1", "fy is -inf")),
    "simple focal 0": (TINY.with_camera(model_id=0, model_name="SIMPLE_PINHOLE", params=(0.0, 12.0, 8.0)), "cameras",
                       ("camera 1", "focal length")),
    "size 0 x 0": (TINY.with_camera(width=0, height=0), "cameras", ("camera 1", "width 0")),
    "height 0": (TINY.with_camera(height=0), "cameras", ("camera 1", "height 0")),
    "size 2^40 x 64": (TINY.with_camera(width=2**40, height=64), "cameras", ("camera 1", f"width {2**40}")),
    "width 65536": (TINY.with_camera(width=65536), "cameras", ("camera 1", "width 65536")),
    "cx NaN": (TINY.with_camera(params=(30.0, 31.0, NAN, 8.0)), "cameras", ("camera 1", "parameter cx is nan")),
    "cy inf": (TINY.with_camera(params=(30.0, 31.0, 12.0, INF)), "cameras", ("camera 1", "parameter cy is inf")),
    "k1 inf": (TINY.with_camera(model_id=4, model_name="OPENCV", params=(30.0, 31.0, 12.0, 8.0, INF, 0, 0, 0)),
               "cameras", ("camera 1", "OPENCV parameter k1 is inf")),
    "zero quaternion": (TINY.with_image(0, pose=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)), "images",
                        ("image v0.png", "quaternion", "zero")),
    "NaN quaternion": (TINY.with_image(1, pose=(NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)), "images",
                       ("image v1.png", "not finite")),
    "NaN translation": (TINY.with_image(0, pose=(*Q0[:4], 0.0, NAN, 1.0)), "images", ("image v0.png", "not finite")),
    "inf translation": (TINY.with_image(0, pose=(*Q0[:4], 0.0, 0.0, -INF)), "images", ("image v0.png", "not finite")),
    "one name twice": (TINY.with_image(1, name=b"v0.png"), "images", ("image v0.png", "appears twice")),
    "one stem twice": (TINY.with_image(1, name=b"v0.jpg"), "images", ("image v0.jpg", "stem 'v0'")),
    "one stem in two folders": (TINY.with_image(0, name=b"a/v1.png"), "images", ("stem 'v1'",)),
    "one id twice": (TINY.with_image(1, image_id=1), "images", ("image id 1", "appears twice")),
    "unknown camera": (TINY.with_image(1, camera_id=7), "images", ("image v1.png", "camera 7")),
    "not UTF-8": (TINY.with_image(1, name=b"v\xff\xfe.png"), "images", ("image id 2", "not UTF-8")),
    "5,000-character name": (TINY.with_image(1, name=b"v" * 4996 + b".png"), "images", ("image id 2", "4096")),
    "300-byte component": (TINY.with_image(1, name=b"d/" + "é".encode() * 150 + b".png"), "images",
                           ("image id 2", "component of 304 bytes")),
    "control character": (TINY.with_image(1, name=b"v\x01.png"), "images", ("image id 2", "control characters")),
    "no file name": (TINY.with_image(1, name=b"d/"), "images", ("image d/", "does not end in a file name")),
    "dot dot": (TINY.with_image(1, name=b"d/.."), "images", ("image d/..", "does not end in a file name")),
}


@pytest.mark.parametrize("fmt", ["bin", "txt"])
@pytest.mark.parametrize("case", list(BAD))
def test_an_impossible_value_is_refused_naming_the_file_and_the_record(tmp_path, capsys, case, fmt):
    rec, kind, words = BAD[case]
    root = make_project(tmp_path / "p", rec, fmt)
    rc, err = run_import(root, capsys)
    lines = err.splitlines()
    assert rc == 2 and len(lines) == 1 and f"{kind}.{fmt}" in err and all(w in err for w in words), err
    assert not (root / "transforms.json").exists()


@pytest.mark.parametrize("fmt", ["bin", "txt"])
def test_the_tiny_model_with_other_values_imports(tmp_path, capsys, fmt):
    """A non-unit quaternion is normalised (the same pose as the unit one, even at 1e307); a principal point outside the
    image, a 65,535-pixel side and a name in a sub-folder with UTF-8 letters are possible."""
    rec = TINY.with_image(0, pose=(*(1e307 * np.asarray(Q0[:4])), *Q0[4:]), name="sub/vü0.png".encode())
    rec = rec.with_camera(params=(30.0, 31.0, -5.0, 80.0), width=65535)
    root = make_project(tmp_path / "p", rec, fmt)
    assert run_import(root, capsys) == (0, "")
    meta = json.loads((root / "transforms.json").read_text())
    assert (meta["w"], meta["cx"], meta["fl_y"]) == (65535, -5.0, 31.0)
    assert [f["file_path"] for f in meta["frames"]] == ["images/vü0.npy", "images/v1.npy"]     # sorted by name
    np.testing.assert_allclose(read_model(root / "sparse" / "0").images[0].cam_from_world,
                               read_model(make_project(tmp_path / "q", TINY, fmt) / "sparse" / "0").images[0]
                               .cam_from_world, atol=1e-15)


def test_a_position_beyond_float_range_is_refused(tmp_path, capsys):
    """Finite poses whose camera position (-R^T t) or its alignment to ENU overflows."""
    n = np.ones(3) / np.sqrt(3)                                          # R maps z to n: R^T t = |t| z
    axis, half = np.cross([0.0, 0.0, 1.0], n), np.arccos(n[2]) / 2
    q = (np.cos(half), *(np.sin(half) * axis / np.linalg.norm(axis)))
    root = make_project(tmp_path / "o", TINY.with_image(1, pose=(*q, 1.7e308, 1.7e308, 1.7e308)))
    rc, err = run_import(root, capsys)
    assert rc == 2 and "images.bin" in err and "image v1.png" in err and "out of range" in err, err
    root = make_project(tmp_path / "p", TINY.with_image(0, pose=(*Q0[:4], 1e308, 0.0, -1e308)))
    # scale 10 and a half turn about x: TINY's cameras (below z = 0 in its frame) land above the ground
    (root / "side.json").write_text(json.dumps({"enu_from_colmap": np.diag([10.0, -10.0, -10.0, 1.0]).tolist()}))
    rc, err = run_import(root, capsys, "--sidecar", str(root / "side.json"))
    assert rc == 2 and "images.bin" in err and "image v0.png" in err and "out of range" in err, err
    assert run_import(make_project(tmp_path / "q", TINY), capsys, "--sidecar", str(root / "side.json")) == (0, "")


def test_text_lines_that_do_not_parse(tmp_path, capsys):
    root = make_project(tmp_path / "p", TINY, "txt")
    sparse = root / "sparse" / "0"
    good = {f: (sparse / f).read_text() for f in ("cameras.txt", "images.txt", "points3D.txt")}
    for f, old, new, words in [("cameras.txt", "PINHOLE 24", "PINHOLE 24.5", ("line 2", "width")),
                               ("cameras.txt", "PINHOLE", "FISHEYE_X", ("unknown camera model",)),
                               ("cameras.txt", " 8.0", " 8.0 1.0", ("PINHOLE has 4 parameters",)),
                               ("cameras.txt", " 8.0", "", ("PINHOLE has 4 parameters",)),
                               ("images.txt", "3.0 4.0 1", "3.0 4.0", ("image v0.png", "triples")),
                               ("images.txt", " 1 v0.png", " v0.png", ("image id 1",)),
                               ("points3D.txt", " 10 20 30", " 10 20 300", ("3D point 1", "0..255")),
                               ("points3D.txt", "2 0\n", "2\n", ("3D point 1", "pairs"))]:
        (sparse / f).write_text(good[f].replace(old, new, 1))
        rc, err = run_import(root, capsys)
        assert rc == 2 and len(err.splitlines()) == 1 and f in err and all(w in err for w in words), (old, err)
        (sparse / f).write_text(good[f])
    (sparse / "images.txt").write_bytes(b"1 " * (9 * 2**20))               # one line longer than 16 MiB
    rc, err = run_import(root, capsys)
    assert rc == 2 and "line 1 is longer than" in err


def _five(tmp_path):
    sparse = _pycolmap_rig_model(tmp_path / "rig")
    root = sparse.parent
    (root / "images").mkdir()
    for k in range(1, 4):
        for c in (1, 2):
            (root / "images" / f"f{k}_c{c}.npy").write_bytes(b"")
    return root, sparse


def _patch(path, at: int, fmt: str, *values) -> bytes:
    data = path.read_bytes()
    path.write_bytes(data[:at] + struct.pack(fmt, *values) + data[at + struct.calcsize(fmt):])
    return data


def test_a_rig_imports_with_each_camera_at_its_pose_on_the_rig(tmp_path, capsys):
    root, sparse = _five(tmp_path)
    assert run_import(root, capsys, "--sparse", str(sparse)) == (0, "")
    meta = json.loads((root / "transforms.json").read_text())
    rec = pycolmap.Reconstruction(str(sparse))
    by_name = {im.name.split("/")[1][:-4]: im for im in rec.images.values()}
    for fr in meta["frames"]:
        w2c = np.eye(4)
        w2c[:3] = by_name[fr["file_path"][7:-4]].cam_from_world().matrix()
        gl_to_cv = np.diag([1.0, -1.0, -1.0, 1.0])
        np.testing.assert_allclose(fr["transform_matrix"], np.linalg.inv(w2c) @ gl_to_cv, atol=1e-12)
    assert meta["camera_model"] == "PINHOLE" and sum(f.get("camera_model") == "OPENCV" for f in meta["frames"]) == 3


def test_rigs_and_frames_that_do_not_hold_together_are_refused(tmp_path, capsys):
    root, sparse = _five(tmp_path)
    rigs, frames = sparse / "rigs.bin", sparse / "frames.bin"
    cases = [(frames, 16, "<4d", (0.0,) * 4, ("frames.bin", "frame 1", "zero")),       # rig_from_world
             (frames, 48, "<d", (NAN,), ("frames.bin", "frame 1", "not finite")),
             (frames, 8 + 68 + 8, "<Q", (99,), ("images.bin", "image id 1 is in no frame")),
             (frames, 8 + 4, "<I", (5,), ("frames.bin", "rig 5 is not in rigs.bin")),
             (frames, 8 + 68 + 4, "<I", (2,), ("images.bin", "frame 1 has it from camera 2")),
             (rigs, 33, "<d", (NAN,), ("rigs.bin", "rig 1", "not finite")),                # sensor_from_rig
             (rigs, 32, "<B", (2,), ("rigs.bin", "has_pose is 2")),
             (rigs, 28, "<I", (3,), ("rigs.bin", "camera 2 is not a sensor of rig 1")),
             (rigs, 16, "<i", (7,), ("rigs.bin", "unknown sensor type 7"))]
    for path, at, fmt, values, words in cases:
        data = _patch(path, at, fmt, *values)
        rc, err = run_import(root, capsys, "--sparse", str(sparse))
        assert rc == 2 and len(err.splitlines()) == 1 and all(w in err for w in words), (words, err)
        path.write_bytes(data)
    data = rigs.read_bytes()
    rigs.write_bytes(data[:32] + b"\0")                                  # camera 2 on the rig without a pose
    rc, err = run_import(root, capsys, "--sparse", str(sparse))
    assert rc == 2 and "rigs.bin" in err and "camera 2 has no pose in rig 1" in err
    rigs.write_bytes(data)
    for lone in (rigs, frames):
        data = lone.read_bytes()
        lone.unlink()
        rc, err = run_import(root, capsys, "--sparse", str(sparse))
        assert rc == 2 and "without" in err
        lone.write_bytes(data)
    (sparse / "points3D.bin").unlink()
    rc, err = run_import(root, capsys, "--sparse", str(sparse))
    assert rc == 2 and "lacks points3D.bin" in err


@pytest.mark.parametrize("side, field", [
    ({"enu_from_colmap": "abc"}, "enu_from_colmap"),
    ({"enu_from_colmap": [[1, 2], [3]]}, "enu_from_colmap"),
    ({"enu_from_colmap": [[1e400] * 4] * 4}, "enu_from_colmap[0][0]"),
    ({"camera_positions_enu": [1, 2, 3]}, "camera_positions_enu"),
    ({"camera_positions_enu": {"v0": "a", "v1": [0, 0, 1], "v2": [1, 0, 0]}}, "camera_positions_enu.v0"),
    ({"camera_positions_enu": {"v0": [0, 0, 1], "v1": [[0], 0, 1]}}, "camera_positions_enu.v1"),
])
def test_a_sidecar_of_the_wrong_shape_is_one_line(tmp_path, capsys, side, field):
    root = make_project(tmp_path / "p", TINY)
    (root / "side.json").write_text(json.dumps(side).replace("Infinity", "1e400"))
    rc, err = run_import(root, capsys, "--sidecar", str(root / "side.json"))
    assert rc == 2 and "side.json" in err and f"field '{field}'" in err, err
