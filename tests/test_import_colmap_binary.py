"""brfgs's own COLMAP reader: the same cameras and poses as pycolmap on the models it writes (three- and
five-file layouts, a multi-camera rig, binary and text); a binary file cut at any byte, with bytes after
its last record, with counts of 2^64 - 1 or with random bytes flipped is refused in one line naming the
file (exit 2, never a traceback), in bounded time and memory."""

from __future__ import annotations

import zlib  # noqa: F401  (before pycolmap)
import random
import resource
import shutil
import struct
import subprocess
import sys

import numpy as np
import pycolmap
import pytest

from brfgs.init.colmap_model import CAMERA_MODELS
from brfgs.init.colmap_read import read_model
from colmap_bytes import TINY, import_error, make_project, run_import, write_bin

BINARY_FILES = ("cameras.bin", "images.bin", "points3D.bin", "rigs.bin", "frames.bin")


def _project(tmp_path, layout: str):
    """The tiny project in the three-file layout ("legacy", as written byte by byte) or the five-file
    layout ("five", the same model written again by pycolmap)."""
    root = make_project(tmp_path / layout)
    if layout == "five":
        sparse = root / "sparse" / "0"
        pycolmap.Reconstruction(str(sparse)).write(str(sparse))
    return root


def _one_line(err: str, *words: str) -> bool:
    lines = err.splitlines()
    return len(lines) == 1 and lines[0].startswith("brfgs: error: ") and all(w in lines[0] for w in words)


def test_the_camera_model_table_is_colmaps():
    for mid, (name, params, focal) in CAMERA_MODELS.items():
        cam = pycolmap.Camera.create_from_model_name(1, name, 1.0, 10, 10)
        assert int(cam.model.value) == mid and cam.params_info.replace(",", " ").split() == list(params), name
        assert [params[k] for k in focal] in (["f"], ["fx", "fy"]) or name == "EQUIRECTANGULAR", name
    assert {m.name for m in pycolmap.CameraModelId.__members__.values()} - {"INVALID"} == \
        {name for name, _, _ in CAMERA_MODELS.values()}


def _pycolmap_rig_model(folder):
    """Two cameras on one rig (the second at a random pose on it), three frames at random poses."""
    rng = np.random.default_rng(0)

    def rigid():
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        return pycolmap.Rigid3d(pycolmap.Rotation3d(np.r_[q[1:], q[0]]), rng.normal(size=3))

    rec = pycolmap.Reconstruction()
    for c in (1, 2):
        rec.add_camera(pycolmap.Camera.create_from_model_name(c, "OPENCV" if c == 2 else "PINHOLE", 30.0, 24, 16))
    rig = pycolmap.Rig(rig_id=1)
    cam = [pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=c) for c in (1, 2)]
    rig.add_ref_sensor(cam[0])
    rig.add_sensor(cam[1], rigid())
    rec.add_rig(rig)
    for f in (1, 2, 3):
        fr = pycolmap.Frame(frame_id=f, rig_id=1)
        fr.rig_from_world = rigid()
        for c in (1, 2):
            fr.add_data_id(pycolmap.data_t(sensor_id=cam[c - 1], id=2 * f + c - 2))
        rec.add_frame(fr)
        for c in (1, 2):
            rec.add_image(pycolmap.Image(name=f"cam{c}/f{f}_c{c}.png", camera_id=c, image_id=2 * f + c - 2, frame_id=f))
        rec.register_frame(f)
    folder.mkdir(parents=True)
    rec.write(str(folder))
    return folder


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("layout", ["legacy", "five", "rig"])
def test_the_reader_agrees_with_pycolmap(tmp_path, layout, text):
    sparse = _pycolmap_rig_model(tmp_path / "rig") if layout == "rig" else _project(tmp_path, layout) / "sparse" / "0"
    if text and layout == "legacy":                                       # three text files, written byte by byte
        sparse = make_project(tmp_path / "txt", fmt="txt") / "sparse" / "0"
    elif text:
        rec = pycolmap.Reconstruction(str(sparse))
        for f in sparse.iterdir():
            f.unlink()
        rec.write_text(str(sparse))
    ours, theirs = read_model(sparse), pycolmap.Reconstruction(str(sparse))
    assert ours.layout == ("text" if text else "binary") and ours.n_points == len(theirs.points3D)
    assert ("rigs" in ours.files) == (layout != "legacy")
    assert [im.name for im in ours.images] == sorted(im.name for im in theirs.images.values())
    for im in ours.images:
        ref = theirs.images[im.image_id]
        assert (im.name, im.camera_id) == (ref.name, ref.camera_id)
        np.testing.assert_allclose(im.cam_from_world, ref.cam_from_world().matrix(), atol=1e-12)
    for cid, cam in ours.cameras.items():
        ref = theirs.cameras[cid]
        assert (cam.model, cam.width, cam.height) == (ref.model.name, ref.width, ref.height)
        np.testing.assert_array_equal(cam.params, ref.params)


def test_the_tiny_model_imports(tmp_path, capsys):
    for layout in ("legacy", "five"):
        assert run_import(_project(tmp_path, layout), capsys) == (0, "")


@pytest.mark.parametrize("layout", ["legacy", "five"])
def test_a_file_cut_at_any_byte_is_refused_in_one_line(tmp_path, capsys, layout):
    root = _project(tmp_path, layout)
    sparse = root / "sparse" / "0"
    files = [f for f in BINARY_FILES if (sparse / f).is_file()]
    assert len(files) == (5 if layout == "five" else 3)
    for name in files:
        data = (sparse / name).read_bytes()
        for cut in range(len(data)):
            (sparse / name).write_bytes(data[:cut])
            err = import_error(root)
            assert err is not None and _one_line(f"brfgs: error: {err}", name, "byte"), (name, cut, err)
            if cut % 16 == 0 or cut == len(data) - 1:                         # the command line on a sample
                rc, out = run_import(root, capsys)
                assert rc == 2 and out == f"brfgs: error: {err}"
        (sparse / name).write_bytes(data)
    assert run_import(root, capsys) == (0, "")


@pytest.mark.parametrize("layout", ["legacy", "five"])
def test_bytes_after_the_last_record_are_refused(tmp_path, capsys, layout):
    root = _project(tmp_path, layout)
    sparse = root / "sparse" / "0"
    for name in (f for f in BINARY_FILES if (sparse / f).is_file()):
        data = (sparse / name).read_bytes()
        for tail in (b"\0", b"garbage!" * 3):
            (sparse / name).write_bytes(data + tail)
            rc, err = run_import(root, capsys)
            assert rc == 2 and _one_line(err, name, f"{len(tail)} bytes after the last record", f"byte {len(data)}")
        (sparse / name).write_bytes(data)


def _offsets(sparse) -> dict[str, list[tuple[str, int, str]]]:
    """(what, offset, struct format) of every count in the tiny five-file model's files."""
    name_end = (sparse / "images.bin").read_bytes().index(b"\0", 8 + 64)
    return {"cameras.bin": [("cameras", 0, "<Q")],
            "images.bin": [("images", 0, "<Q"), ("2D points", name_end + 1, "<Q")],
            "points3D.bin": [("3D points", 0, "<Q"), ("track", 8 + 43, "<Q")],
            "rigs.bin": [("rigs", 0, "<Q"), ("sensors", 12, "<I")],
            "frames.bin": [("frames", 0, "<Q"), ("data ids", 8 + 64, "<I")]}


def test_counts_up_to_2_64_minus_1_are_refused_without_allocating(tmp_path, capsys):
    root = _project(tmp_path, "five")
    sparse = root / "sparse" / "0"
    for name, counts in _offsets(sparse).items():
        data = (sparse / name).read_bytes()
        for what, at, fmt in counts:
            assert struct.unpack_from(fmt, data, at)[0] in (1, 2), (name, what)          # the count is there
            for n in (2 ** (8 * struct.calcsize(fmt)) - 1, 2 ** (8 * struct.calcsize(fmt) - 1), 3):
                (sparse / name).write_bytes(data[:at] + struct.pack(fmt, n) + data[at + struct.calcsize(fmt):])
                rc, err = run_import(root, capsys)
                assert rc == 2 and _one_line(err, name), (name, what, n, err)
                assert n == 3 or (str(n) in err and "byte" in err), err             # the count and where
        (sparse / name).write_bytes(data)


_MEASURE = """
import resource, subprocess, sys, time
for root in sys.argv[1:]:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "brfgs", "import", "colmap", root], capture_output=True, text=True,
                       timeout=120)
    print(r.returncode, f"{time.perf_counter() - t0:.2f}", len(r.stderr.strip().splitlines()), flush=True)
print("maxrss_kib", resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
"""


def test_the_worst_cuts_end_in_bounded_time_and_memory(tmp_path):
    """The cuts that made COLMAP's own reader allocate gigabytes or loop (images.bin after 9 and 12 bytes,
    frames.bin and images.bin inside their last records) and the largest counts, each in its own process:
    exit 2 in under 30 s and under 1 GB peak memory."""
    cases = []
    for k, (name, cut, patch) in enumerate([("images.bin", 9, None), ("images.bin", 12, None), ("frames.bin", -9, None),
                                            ("images.bin", -30, None), ("images.bin", None, ("<Q", 0)),
                                            ("points3D.bin", None, ("<Q", 51))]):
        root = _project(tmp_path / f"c{k}", "five")
        f = root / "sparse" / "0" / name
        data = f.read_bytes()
        if patch:
            fmt, at = patch
            data = data[:at] + struct.pack(fmt, 2**64 - 1) + data[at + 8:]
        f.write_bytes(data if cut is None else data[:cut])
        cases.append(str(root))
    out = subprocess.run([sys.executable, "-c", _MEASURE, *cases], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    *rows, peak = out.stdout.split("\n")[:-1]
    for row, case in zip(rows, cases):
        rc, seconds, lines = row.split()
        assert (int(rc), int(lines)) == (2, 1) and float(seconds) < 30, (case, row)
    assert len(rows) == len(cases) and int(peak.split()[1]) < 2**20, peak          # KiB: < 1 GiB
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss < 2**21


def test_random_byte_flips_never_give_a_traceback(tmp_path, capsys):
    """Seeded random flips of 1-4 bytes in each binary file of both layouts (and of the text files):
    exit 0 (a flip can leave a possible model) or 2 with one line naming the file."""
    rng = random.Random(0)
    roots = [_project(tmp_path, "legacy"), _project(tmp_path, "five")]
    text = make_project(tmp_path / "text", fmt="txt")
    counts = {0: 0, 2: 0}
    for root in (*roots, text):
        sparse = root / "sparse" / "0"
        for f in sorted(sparse.iterdir()):
            data = f.read_bytes()
            for _ in range(100):
                buf = bytearray(data)
                for _ in range(rng.randint(1, 4)):
                    buf[rng.randrange(len(buf))] ^= rng.randint(1, 255)
                f.write_bytes(bytes(buf))
                err = import_error(root)
                assert err is None or _one_line(f"brfgs: error: {err}", str(sparse)), (f.name, bytes(buf), err)
                counts[0 if err is None else 2] += 1
                if (counts[0] + counts[2]) % 250 == 1:                                         # the command line
                    assert run_import(root, capsys) == (0 if err is None else 2, "" if err is None else
                                                        f"brfgs: error: {err}")
            f.write_bytes(data)
    assert counts[2] > counts[0] > 0, counts


def test_write_bin_is_colmaps_layout(tmp_path):
    """The test models written byte by byte read the same in pycolmap (so the tests above cut COLMAP's format)."""
    sparse = write_bin(tmp_path / "m", TINY)
    rec = pycolmap.Reconstruction(str(sparse))
    assert sorted(im.name for im in rec.images.values()) == ["v0.png", "v1.png"]
    assert rec.images[2].num_points2D() == 2 and rec.points3D[1].track.length() == 2
    np.testing.assert_array_equal(rec.cameras[1].params, TINY.cameras[0].params)
    shutil.rmtree(sparse)
