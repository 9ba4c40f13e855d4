"""OPENCV distortion and per-frame intrinsics: resampling maps against cv2.projectPoints, an image
resampled onto the pinhole camera, and scenes that use them (and refuse bad camera fields)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from brfgs.data.cameras import Intrinsics
from brfgs.data.cube_io import write_envi
from brfgs.data.scene import read_scene
from brfgs.data.undistort import FrameCamera, resample_cube, resample_maps
from brfgs.errors import UserError
from scenes import make_scene

DST = Intrinsics(60.0, 60.0, 24.0, 16.0, 48, 32)
SRC = FrameCamera(Intrinsics(63.0, 62.0, 25.2, 15.4, 52, 34), (-0.18, 0.04, 0.002, -0.0015))


def _bilinear(m: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    return ((1 - fx) * (1 - fy) * m[y0, x0] + fx * (1 - fy) * m[y0, x0 + 1]
            + (1 - fx) * fy * m[y0 + 1, x0] + fx * fy * m[y0 + 1, x0 + 1])


def test_maps_send_each_ray_where_opencv_projects_it():
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.3, 0.3, (200, 2)), np.ones(200)] * rng.uniform(2, 50, (200, 1))   # camera frame
    k_dst = FrameCamera(DST).opencv_K()
    p_dst = (pts[:, :2] / pts[:, 2:]) * [k_dst[0, 0], k_dst[1, 1]] + k_dst[:2, 2]              # OpenCV pixels
    ok = (p_dst[:, 0] > 0) & (p_dst[:, 0] < DST.w - 1) & (p_dst[:, 1] > 0) & (p_dst[:, 1] < DST.h - 1)
    want, _ = cv2.projectPoints(pts[ok], np.zeros(3), np.zeros(3), SRC.opencv_K(), np.asarray(SRC.dist))
    mx, my = resample_maps(SRC, DST)
    got = np.c_[_bilinear(mx, *p_dst[ok].T), _bilinear(my, *p_dst[ok].T)]
    assert ok.sum() > 100
    np.testing.assert_allclose(got, want[:, 0], atol=0.02)


def _pattern(xn: np.ndarray, yn: np.ndarray) -> np.ndarray:       # smooth, in normalised image coordinates
    return np.stack([0.3 + 0.2 * np.sin(6 * xn) * np.cos(5 * yn), 0.2 + 0.1 * xn + 0.05 * yn], -1)


def _distorted_image(cam: FrameCamera) -> np.ndarray:
    """What the distorted camera sees of the pattern: each source pixel's ray, undistorted by OpenCV."""
    i = cam.intrinsics
    u, v = np.meshgrid(np.arange(i.w, dtype=float), np.arange(i.h, dtype=float))
    und = cv2.undistortPoints(np.c_[u.ravel(), v.ravel()][:, None], cam.opencv_K(), np.asarray(cam.dist))[:, 0]
    return _pattern(und[:, 0], und[:, 1]).reshape(i.h, i.w, 2).astype(np.float32)


def _pinhole_image(intr: Intrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(intr.w) + 0.5, np.arange(intr.h) + 0.5)
    return _pattern((u - intr.cx) / intr.fl_x, (v - intr.cy) / intr.fl_y)


def test_resampled_image_is_the_pinhole_image():
    out = resample_cube(_distorted_image(SRC), SRC, DST)
    want = _pinhole_image(DST)
    ok = np.isfinite(out).all(-1)
    assert ok.mean() > 0.9
    assert np.abs(out[ok] - want[ok]).max() < 0.01                    # bilinear on a smooth pattern
    ignored = resample_cube(_distorted_image(SRC), FrameCamera(SRC.intrinsics), DST)     # distortion ignored
    assert np.nanmax(np.abs(ignored[ok] - want[ok])) > 0.02


def test_scene_with_opencv_and_per_frame_cameras(tmp_path):
    root = make_scene(tmp_path / "s", n_frames=7, w=DST.w, h=DST.h, n_bands=2, n_dark=0)
    meta = json.loads((root / "transforms.json").read_text())
    meta.update({"fl_x": DST.fl_x, "fl_y": DST.fl_y, "cx": DST.cx, "cy": DST.cy})
    wl = meta["wavelengths_nm"]
    fr = meta["frames"][2]                                             # its own, distorted camera
    i = SRC.intrinsics
    fr.update({"camera_model": "OPENCV", "fl_x": i.fl_x, "fl_y": i.fl_y, "cx": i.cx, "cy": i.cy, "w": i.w, "h": i.h,
               "k1": SRC.dist[0], "k2": SRC.dist[1], "p1": SRC.dist[2], "p2": SRC.dist[3]})
    write_envi(root / fr["file_path"], _distorted_image(SRC), wl)
    (root / "transforms.json").write_text(json.dumps(meta))
    sc = read_scene(root)
    assert sc.frames[2].camera == SRC and sc.frames[1].camera is None and sc.intrinsics == DST
    img = sc.load_image(2)
    want = _pinhole_image(DST)
    ok = np.isfinite(img).all(-1)
    assert img.shape == (DST.h, DST.w, 2) and ok.mean() > 0.9
    assert np.abs(img[ok] - want[ok]).max() < 0.01
    half = read_scene(root, downscale=2).load_image(2)                  # downscale after resampling
    np.testing.assert_allclose(half, img.reshape(16, 2, 24, 2, 2).mean(axis=(1, 3)), atol=1e-6)


@pytest.mark.parametrize("change, field", [
    ({"camera_model": "FISHEYE"}, "camera_model"),
    ({"k1": 0.1}, "camera_model"),                                        # distortion on a PINHOLE camera
    ({"camera_model": "OPENCV", "k1": "a lot"}, "k1"),
    ({"frame": {"w": 30}}, "samples/lines"),                              # the frame's own size ≠ its cube
    ({"frame": {"camera_model": "OPENCV", "p2": float("inf")}}, "frames[1] ('view_01').p2"),
])
def test_bad_camera_fields_name_the_field(tmp_path, change, field):
    root = make_scene(tmp_path / "s", n_frames=7, n_dark=0)
    meta = json.loads((root / "transforms.json").read_text())
    frame_change = change.pop("frame", None)
    meta.update(change)
    if frame_change:
        meta["frames"][1].update(frame_change)
    (root / "transforms.json").write_text(json.dumps(meta).replace("Infinity", "1e999"))
    with pytest.raises(UserError) as exc:
        read_scene(root)
    assert exc.value.field == field
