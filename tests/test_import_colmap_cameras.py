"""Every camera model pycolmap knows is imported by `brfgs import colmap` with the same projection as
pycolmap's own, or refused in one line naming the model."""

from __future__ import annotations

import zlib  # noqa: F401  (before pycolmap)
import json

import numpy as np
import pycolmap
import pytest

from brfgs.cli import main
from brfgs.init.colmap_io import SUPPORTED_CAMERA_MODELS, read_colmap_model
from test_import_colmap import _colmap_project

MODELS = [m.name for m in pycolmap.CameraModelId.__members__.values() if m.name != "INVALID"]


def _params(cam) -> np.ndarray:
    """Plausible parameters of a camera model: the focal lengths and principal point from
    pycolmap's defaults, small distortion coefficients (non-zero, so that a wrong mapping shows)."""
    p = np.array(cam.params, float)
    info = cam.params_info.split(", ")
    for k, name in enumerate(info):
        if name in ("k", "k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2", "sx1", "sy1", "omega"):
            p[k] = {"k": -0.05, "k1": -0.08, "k2": 0.02, "p1": 0.001, "p2": -0.0007, "omega": 0.3}.get(name, 0.01)
    return p


def _opencv_projection(keys: dict, xy: np.ndarray) -> np.ndarray:
    """[N, 2] pixels of normalised camera coordinates ``xy`` [N, 2] through transforms.json's keys
    (float64 OpenCV radial-tangential model, written out here as an independent reference)."""
    x, y = xy[:, 0], xy[:, 1]
    k1, k2, p1, p2 = (keys.get(k, 0.0) for k in ("k1", "k2", "p1", "p2"))
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([keys["fl_x"] * xd + keys["cx"], keys["fl_y"] * yd + keys["cy"]], -1)


@pytest.mark.parametrize("model", MODELS)
def test_every_pycolmap_camera_model_is_imported_or_refused(tmp_path, capsys, model):
    root, ref = _colmap_project(tmp_path)
    rec = read_colmap_model(root / "sparse" / "0")
    i = ref.intrinsics
    cam = pycolmap.Camera.create_from_model_name(1, model, i.fl_x, i.w, i.h)
    cam.params = _params(cam)
    rec.cameras[1] = cam
    rec.write(str(root / "sparse" / "0"))
    rc = main(["import", "colmap", str(root)])
    err = capsys.readouterr().err.strip()
    if model not in SUPPORTED_CAMERA_MODELS or (model == "FULL_OPENCV"):
        # FULL_OPENCV with k3..k6 != 0 (as here) cannot be represented exactly
        assert rc == 2 and len(err.splitlines()) == 1 and model in err and "camera 1" in err, err
        return
    assert rc == 0, err
    keys = json.loads((root / "transforms.json").read_text())
    xy = np.random.default_rng(0).uniform(-0.15, 0.15, (20, 2))                   # normalised, within the view
    theirs = np.asarray(cam.img_from_cam(np.c_[xy, np.ones(len(xy))]))
    np.testing.assert_allclose(_opencv_projection(keys, xy), theirs, rtol=1e-6, atol=1e-6)


def test_full_opencv_without_its_higher_terms_is_imported(tmp_path):
    root, ref = _colmap_project(tmp_path)
    rec = read_colmap_model(root / "sparse" / "0")
    i = ref.intrinsics
    cam = pycolmap.Camera.create_from_model_name(1, "FULL_OPENCV", i.fl_x, i.w, i.h)
    cam.params = np.array([i.fl_x, i.fl_y, i.cx, i.cy, -0.08, 0.02, 0.001, -0.0007, 0, 0, 0, 0], float)
    rec.cameras[1] = cam
    rec.write(str(root / "sparse" / "0"))
    assert main(["import", "colmap", str(root)]) == 0
    keys = json.loads((root / "transforms.json").read_text())
    xy = np.random.default_rng(1).uniform(-0.15, 0.15, (20, 2))
    np.testing.assert_allclose(_opencv_projection(keys, xy), np.asarray(cam.img_from_cam(np.c_[xy, np.ones(20)])),
                               rtol=1e-6, atol=1e-6)
