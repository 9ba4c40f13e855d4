"""`brfgs import colmap`: a COLMAP model (binary or text, in an arbitrary frame, PINHOLE or OPENCV) +
cubes + sidecar becomes a scene whose cameras are the original ENU cameras."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brfgs.cli import main
from brfgs.data.scene import read_scene
from brfgs.init.colmap_io import read_colmap_model, write_colmap_model
from scenes import make_scene


def _colmap_project(tmp_path, text: bool = False):
    """make_scene's ENU cameras written as a COLMAP model in a frame rotated, scaled and moved away from ENU."""
    root = make_scene(tmp_path / "p", n_frames=7, n_dark=0)
    ref = read_scene(root)
    meta = json.loads((root / "transforms.json").read_text())
    (root / "transforms.json").unlink()
    a = np.radians(40.0)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    scale, t = 0.05, np.array([3.0, -1.0, 7.0])                        # COLMAP = scale · rot · ENU + t
    c2w_colmap = []
    for f in ref.frames:
        m = np.eye(4)
        m[:3, :3] = rot @ f.c2w[:3, :3]
        m[:3, 3] = scale * rot @ f.c2w[:3, 3] + t
        c2w_colmap.append(m)
    names = [f"{f.name}.png" for f in ref.frames]
    write_colmap_model(root / "sparse" / "0", ref.intrinsics, names, np.stack(c2w_colmap), np.ones(7, bool),
                       np.zeros((0, 3)))
    if text:
        rec = read_colmap_model(root / "sparse" / "0")
        for f in (root / "sparse" / "0").iterdir():
            f.unlink()
        rec.write_text(str(root / "sparse" / "0"))
    side = {k: meta[k] for k in ("wavelengths_nm", "fwhm_nm", "sun_zenith_deg", "sun_azimuth_deg", "dark_sigma")}
    side["camera_positions_enu"] = {f.name: f.c2w[:3, 3].tolist() for f in ref.frames[:5]}
    (root / "spectral.json").write_text(json.dumps(side))
    return root, ref


@pytest.mark.parametrize("text", [False, True])
def test_import_colmap_recovers_the_enu_cameras(tmp_path, text, capsys):
    root, ref = _colmap_project(tmp_path, text)
    assert main(["import", "colmap", str(root)]) == 0
    assert "estimate_sim3d on 5 camera positions" in capsys.readouterr().out
    sc = read_scene(root)
    assert [f.name for f in sc.frames] == [f.name for f in ref.frames] and sc.intrinsics == ref.intrinsics
    for a, b in zip(sc.frames, ref.frames):
        np.testing.assert_allclose(a.c2w, b.c2w, atol=1e-6)
    np.testing.assert_array_equal(sc.load_image(3), ref.load_image(3))
    # a finished transforms.json is never overwritten silently
    assert main(["import", "colmap", str(root)]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_import_colmap_opencv_cameras_and_bad_input(tmp_path, capsys):
    import zlib  # noqa: F401
    import pycolmap

    root, ref = _colmap_project(tmp_path)
    rec = read_colmap_model(root / "sparse" / "0")
    cam = rec.cameras[1]
    i = ref.intrinsics
    opencv = pycolmap.Camera.create_from_model_name(1, "OPENCV", i.fl_x, i.w, i.h)
    opencv.params = np.array([i.fl_x, i.fl_y, i.cx, i.cy, -0.1, 0.02, 0.001, -0.001])
    rec.cameras[1] = opencv
    rec.write(str(root / "sparse" / "0"))
    assert main(["import", "colmap", str(root)]) == 0
    meta = json.loads((root / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV" and meta["k1"] == pytest.approx(-0.1)
    assert read_scene(root).frames[0].camera is not None               # resampled onto the pinhole camera
    del cam
    # no cube for an image, a sidecar that is not JSON, too few positions
    (root / "images" / "view_06.hdr").rename(root / "images" / "x.hdr")
    assert main(["import", "colmap", str(root), "--overwrite"]) == 2
    assert "view_06" in capsys.readouterr().err
    (root / "images" / "x.hdr").rename(root / "images" / "view_06.hdr")
    (root / "bad.json").write_text("{nope")
    assert main(["import", "colmap", str(root), "--overwrite", "--sidecar", str(root / "bad.json")]) == 2
    assert "bad.json" in capsys.readouterr().err
    (root / "few.json").write_text(json.dumps({"camera_positions_enu": {"view_00": [0, 0, 100]}}))
    assert main(["import", "colmap", str(root), "--overwrite", "--sidecar", str(root / "few.json")]) == 2
    assert "camera_positions_enu" in capsys.readouterr().err
    assert main(["import", "colmap", str(tmp_path / "nowhere")]) == 2
    side = json.loads((root / "spectral.json").read_text())             # a frame under its own sky
    (root / "sky.json").write_text(json.dumps({**side, "frames": {"view_01": {"diffuse_fraction": 0.3}}}))
    assert main(["import", "colmap", str(root), "--overwrite", "--sidecar", str(root / "sky.json")]) == 0
    sc = read_scene(root)
    k = [f.name for f in sc.frames].index("view_01")
    assert np.allclose(sc.frame_diffuse_fraction(k), 0.3) and sc.frames[k - 1 if k else k + 1].diffuse_fraction is None


_FLIGHT = ["--size", "32", "--bands", "16", "--views", "13", "--spp", "4", "--dark-frames", "2", "--origin",
           "48.1,11.5,520", "--start-time", "2024-06-21T07:00:00Z", "--duration-min", "30", "--irradiance-drift", "0.1",
           "--distortion=-0.12,0.03,0.001,-0.0005", "--quiet"]


def test_a_simulated_flight_round_trips_through_colmap(tmp_path):
    """`brfgs simulate --layout colmap` (a timed, drifting flight through an OPENCV lens: LZW TIFFs, the model in
    a random frame, a sidecar) → brfgs import colmap: the same scene as the native layout of the same flight
    (poses, lens, images, truth, suns, irradiance, split)."""
    import tifffile

    assert main(["simulate", str(tmp_path / "scene"), *_FLIGHT]) == 0
    assert main(["simulate", str(tmp_path / "proj"), "--layout", "colmap", *_FLIGHT]) == 0
    assert sorted(p.name for p in (tmp_path / "proj").iterdir()) == ["calibration", "images", "sparse",
                                                                      "spectral.json", "truth"]
    with tifffile.TiffFile(tmp_path / "proj" / "images" / "v00_z00_a000.tif") as t:
        assert t.pages[0].compression == tifffile.COMPRESSION.LZW
    assert main(["import", "colmap", str(tmp_path / "proj")]) == 0
    a, b = read_scene(tmp_path / "scene"), read_scene(tmp_path / "proj")
    assert [f.name for f in a.frames] == [f.name for f in b.frames] and a.split_record() == b.split_record()
    for x, y in zip(a.frames, b.frames):
        np.testing.assert_allclose(y.c2w, x.c2w, atol=1e-6)
        assert y.camera == x.camera and y.camera.dist == pytest.approx((-0.12, 0.03, 0.001, -0.0005))
        assert (y.sun_zenith_deg, y.sun_azimuth_deg, y.irradiance_scale) == pytest.approx(
            (x.sun_zenith_deg, x.sun_azimuth_deg, x.irradiance_scale))
    np.testing.assert_array_equal(b.load_image(5), a.load_image(5))
    np.testing.assert_array_equal(b.load_truth(5), a.load_truth(5))
    assert (b.sun_zenith_deg, b.origin) == (a.sun_zenith_deg, a.origin)


def test_the_simulated_colmap_points_lie_on_the_truth_surface(tmp_path):
    """sparse/0's points (back-projected from the nadir truth depth through the OPENCV lens) project, with
    pycolmap's own OPENCV camera model, back onto their pixel centres in the nadir image, and onto the truth
    surface in oblique views (COLMAP depth × the model's scale = truth depth)."""
    assert main(["simulate", str(tmp_path / "proj"), "--layout", "colmap", *_FLIGHT]) == 0
    rec = read_colmap_model(tmp_path / "proj" / "sparse" / "0")
    ims = {im.name: im for im in rec.images.values()}
    pts = np.array([p.xyz for p in rec.points3D.values()])                     # [P, 3] COLMAP frame
    assert len(pts) == 64

    def project(name):
        im = ims[name]
        pc = np.array([im.cam_from_world() * p for p in pts])                   # [P, 3]
        return np.array([rec.cameras[im.camera_id].img_from_cam(p) for p in pc]), pc[:, 2]

    uv, z0 = project("v00_z00_a000.tif")
    np.testing.assert_allclose(uv - 0.5, np.round(uv - 0.5), atol=1e-3)            # pixel centres (+0.5)
    assert set(np.round(uv - 0.5).astype(int).ravel()) <= set(range(2, 32, 4))
    d0 = np.load(tmp_path / "proj" / "truth" / "depth" / "v00_z00_a000.npy")
    scale = d0[np.round(uv[:, 1] - 0.5).astype(int), np.round(uv[:, 0] - 0.5).astype(int)] / z0
    np.testing.assert_allclose(scale, np.median(scale), rtol=1e-5)               # one similarity for all
    for name in ("v01_z38_a000.tif", "v05_z38_a120.tif"):
        uv, z = project(name)
        ok = (uv >= 0).all(1) & (uv < 32).all(1)
        d = np.load(tmp_path / "proj" / "truth" / "depth" / f"{name[:-4]}.npy")
        ratio = d[uv[ok, 1].astype(int), uv[ok, 0].astype(int)] / (z[ok] * np.median(scale))
        assert ok.sum() > 40 and abs(np.median(ratio) - 1) < 0.01


def test_simulate_colmap_refuses_a_folder_it_did_not_write(tmp_path, capsys):
    (tmp_path / "proj").mkdir()
    (tmp_path / "proj" / "notes.txt").write_text("mine")
    assert main(["simulate", str(tmp_path / "proj"), "--layout", "colmap", "--overwrite", *_FLIGHT]) == 2
    assert "does not write" in capsys.readouterr().err and (tmp_path / "proj" / "notes.txt").read_text() == "mine"
    assert main(["simulate", str(tmp_path / "x"), "--layout", "ply", *_FLIGHT]) == 2
    assert "--layout" in capsys.readouterr().err


def test_simulate_colmap_resumes_a_conversion_cut_short(tmp_path):
    """A run stopped after the rendering (complete staging, a partial images/) is finished by --resume."""
    from brfgs.init.colmap_project import PROJECT_ENTRIES

    assert ".native" in PROJECT_ENTRIES
    assert main(["simulate", str(tmp_path / "proj" / ".native"), *_FLIGHT]) == 0
    (tmp_path / "proj" / "images").mkdir()
    (tmp_path / "proj" / "images" / "v00_z00_a000.tif").write_bytes(b"partial")
    assert main(["simulate", str(tmp_path / "proj"), "--layout", "colmap", *_FLIGHT]) == 2      # not without --resume
    assert main(["simulate", str(tmp_path / "proj"), "--layout", "colmap", "--resume", *_FLIGHT]) == 0
    assert not (tmp_path / "proj" / ".native").exists()
    assert main(["import", "colmap", str(tmp_path / "proj")]) == 0
    assert len(read_scene(tmp_path / "proj").frames) == 13
