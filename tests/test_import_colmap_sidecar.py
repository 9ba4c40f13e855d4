"""`brfgs import colmap` refuses what it would otherwise pass on silently: NaN or Infinity anywhere in the
sidecar (written as null, then read as absent), sidecar entries for image stems that name no image, an
unaligned model in COLMAP's own gauge (an image at the identity pose), cameras that every later command
would refuse. Each is one line naming the file and the field; nothing is written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brfgs.cli import main
from brfgs.data.scene import read_scene
from colmap_bytes import TINY, make_project, run_import
from test_import_colmap import _colmap_project


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """make_scene's 7 views as a COLMAP model in an arbitrary frame, with spectral.json (5 ENU positions)."""
    root, _ = _colmap_project(tmp_path_factory.mktemp("sidecar"))
    return root


def _import(project, capsys, side: dict | str, *extra: str, names: str = "side.json") -> tuple[int, str]:
    path = project / "side.json"
    path.write_text(side if isinstance(side, str) else json.dumps(side))
    (project / "transforms.json").unlink(missing_ok=True)
    rc = main(["import", "colmap", str(project), "--sidecar", str(path), *extra])
    cap = capsys.readouterr()
    if rc == 2:
        err = cap.err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err and names in err, err
        assert not (project / "transforms.json").exists()
        return rc, err
    return rc, cap.out


def _side(project) -> dict:
    return json.loads((project / "spectral.json").read_text())


@pytest.mark.parametrize("path, raw", [
    (("sun_zenith_deg",), "NaN"), (("sun_azimuth_deg",), "Infinity"), (("dark_sigma", 2), "NaN"),
    (("wavelengths_nm", 0), "-Infinity"), (("diffuse_fraction",), "NaN"), (("fwhm_nm", 1), "1e400"),
    (("frames", "view_02", "irradiance_scale"), "NaN"), (("frames", "view_03", "diffuse_fraction"), "Infinity"),
    (("origin", "altitude_m"), "NaN"), (("camera_positions_enu", "view_01", 2), "NaN"),
])
def test_nan_or_infinity_anywhere_in_the_sidecar(project, capsys, path, raw):
    side = _side(project)
    side["origin"] = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}
    obj = side
    for key in path[:-1]:
        obj = obj.setdefault(key, {})
    obj[path[-1]] = "__V__"
    rc, err = _import(project, capsys, json.dumps(side).replace('"__V__"', raw))
    field = ".".join(str(p) for p in path if not isinstance(p, int)) + "".join(f"[{p}]" for p in path
                                                                                if isinstance(p, int))
    assert rc == 2 and f"field '{field}'" in err and "finite" in err, err


def test_an_integer_beyond_the_float_range_in_the_sidecar(project, capsys):
    side = _side(project)
    side["sun_zenith_deg"] = "__V__"
    rc, err = _import(project, capsys, json.dumps(side).replace('"__V__"', str(10 ** 400)))
    assert rc == 2 and "field 'sun_zenith_deg'" in err


@pytest.mark.parametrize("stem", ["view_7", "View_01", "view_01.png", "", "images/view_01"])
def test_a_frames_entry_that_matches_no_image_is_refused(project, capsys, stem):
    side = _side(project)
    side["frames"] = {"view_01": {"irradiance_scale": 1.1}, stem: {"irradiance_scale": 1.2}}
    rc, err = _import(project, capsys, side)
    assert rc == 2 and f"field 'frames.{stem}'" in err and "view_00" in err, err


def test_a_camera_position_that_matches_no_image_is_refused(project, capsys):
    side = _side(project)
    side["camera_positions_enu"]["view_77"] = side["camera_positions_enu"].pop("view_04")
    rc, err = _import(project, capsys, side)
    assert rc == 2 and "field 'camera_positions_enu.view_77'" in err, err


def test_a_frames_entry_of_an_unregistered_cube_is_left_out_and_said(project, capsys):
    """A cube that COLMAP did not register (it has a cube, not an image of the model) is not an error:
    the import says that its sidecar entry is left out."""
    (project / "images" / "view_09.npy").write_bytes(b"")
    side = _side(project)
    side["frames"] = {"view_09": {"irradiance_scale": 1.1}}
    try:
        rc, out = _import(project, capsys, side)
    finally:
        (project / "images" / "view_09.npy").unlink()
    assert rc == 0 and "left out 1 sidecar frame" in out and "view_09" in out, out


def test_an_unaligned_model_at_colmaps_gauge_is_refused_with_the_way_out(tmp_path, capsys):
    root = make_project(tmp_path / "p", TINY.with_image(0, pose=(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
    rc, err = run_import(root, capsys)
    assert rc == 2 and len(err.splitlines()) == 1 and "images.bin" in err and "image v0.png" in err, err
    assert "identity pose" in err and "camera_positions_enu" in err and "enu_from_colmap" in err, err
    assert not (root / "transforms.json").exists()


def test_colmaps_gauge_with_an_alignment_imports_and_reads(project, capsys):
    """The same gauge (the model moved so that its first image has the identity pose), aligned by the
    sidecar's camera positions, is a scene `brfgs inspect` reads; without them it is refused."""
    from brfgs.data.cameras import Intrinsics
    from brfgs.init.colmap_io import read_colmap_model, write_colmap_model

    rec = read_colmap_model(project / "sparse" / "0")
    images = sorted(rec.images.values(), key=lambda im: im.name)
    w2c = [np.vstack([im.cam_from_world().matrix(), [0.0, 0.0, 0.0, 1.0]]) for im in images]
    gl = np.diag([1.0, -1.0, -1.0, 1.0])                                 # OpenCV <-> OpenGL camera axes
    c2w_gauge = np.stack([w2c[0] @ np.linalg.inv(m) @ gl for m in w2c])   # world = the first camera's frame
    fx, fy, cx, cy = (float(v) for v in next(iter(rec.cameras.values())).params[:4])
    cam = next(iter(rec.cameras.values()))
    gauge = project.parent / "gauge"
    write_colmap_model(gauge, Intrinsics(fx, fy, cx, cy, cam.width, cam.height), [im.name for im in images],
                       c2w_gauge, np.ones(len(images), bool), np.zeros((0, 3)))
    side = _side(project)
    rc, out = _import(project, capsys, side, "--sparse", str(gauge))
    assert rc == 0, out
    assert main(["inspect", str(project), "--out", str(project.parent / "inspect"), "-q"]) == 0, capsys.readouterr()
    del side["camera_positions_enu"]
    rc, err = _import(project, capsys, side, "--sparse", str(gauge), names="images.bin")
    assert rc == 2 and "identity pose" in err and "image view_00.png" in err, err


def test_cameras_below_the_ground_after_the_alignment_are_refused(project, capsys):
    side = _side(project)
    side["camera_positions_enu"] = {k: [v[0], v[1], v[2] - 500.0] for k, v in side["camera_positions_enu"].items()}
    rc, err = _import(project, capsys, side, names="images.bin")
    assert rc == 2 and "below the ground" in err and "camera_positions_enu" in err, err


def test_cameras_beyond_100_km_after_the_alignment_are_refused(project, capsys):
    side = _side(project)
    side["camera_positions_enu"] = {k: [c * 1e4 for c in v] for k, v in side["camera_positions_enu"].items()}
    rc, err = _import(project, capsys, side, names="images.bin")
    assert rc == 2 and "100 km" in err, err


def test_camera_positions_written_as_strings_are_refused(project, capsys):
    side = _side(project)
    side["camera_positions_enu"]["view_02"] = [str(c) for c in side["camera_positions_enu"]["view_02"]]
    rc, err = _import(project, capsys, side)
    assert rc == 2 and "camera_positions_enu.view_02" in err, err
