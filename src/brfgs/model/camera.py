"""Cameras as the rasterizer sees them, and the scene description stored in model files.

Files use nerfstudio/OpenGL camera-to-world matrices (docs/data-format.md); the rasterizer takes
gsplat's world-to-camera with OpenCV axes. The one conversion is
:func:`brfgs.data.cameras.viewmat_from_c2w`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from brfgs.data.cameras import Intrinsics, viewmat_from_c2w


@dataclass
class Camera:
    """One pinhole camera: world-to-camera ``viewmat`` [4, 4] (OpenCV axes), ``K`` [3, 3] (px),
    image size (px) and ``centre`` [3] (m, ENU), all float32."""

    name: str
    viewmat: Tensor  # [4, 4]
    K: Tensor  # [3, 3]
    width: int
    height: int
    centre: Tensor  # [3] m

    def crop(self, x0: int, y0: int, w: int, h: int) -> "Camera":
        """The camera seeing only the pixel window [x0, x0+w) x [y0, y0+h) (principal point shifted)."""
        K = self.K.clone()
        K[0, 2] -= x0
        K[1, 2] -= y0
        return Camera(self.name, self.viewmat, K, int(w), int(h), self.centre)


def camera_from_c2w(
    name: str,
    c2w_gl: np.ndarray,  # [4, 4] OpenGL camera-to-world
    K: np.ndarray,  # [3, 3] px
    width: int,
    height: int,
) -> Camera:
    """Camera from an OpenGL camera-to-world matrix (docs/data-format.md) and intrinsics."""
    c2w = np.asarray(c2w_gl, np.float64)
    vm = viewmat_from_c2w(c2w)
    return Camera(
        name,
        torch.as_tensor(np.asarray(vm), dtype=torch.float32),
        torch.as_tensor(np.asarray(K), dtype=torch.float32),
        int(width),
        int(height),
        torch.as_tensor(c2w[:3, 3], dtype=torch.float32),
    )


def camera_from_intrinsics(c2w_gl: np.ndarray, intr: Intrinsics, name: str = "view") -> Camera:
    """Camera from an OpenGL camera-to-world [4, 4] and :class:`brfgs.data.cameras.Intrinsics`."""
    return camera_from_c2w(name, c2w_gl, intr.K(), intr.w, intr.h)


def intrinsics_from_description(desc: dict) -> Intrinsics:
    """:class:`Intrinsics` of a scene description (see :func:`scene_description`)."""
    return Intrinsics(**{k: (int(v) if k in ("w", "h") else float(v)) for k, v in desc["intrinsics"].items()})


def cameras_from_description(desc: dict) -> list[Camera]:
    """One :class:`Camera` per frame of a scene description, in frame order."""
    intr = intrinsics_from_description(desc)
    return [camera_from_c2w(fr["name"], np.array(fr["c2w"]), intr.K(), intr.w, intr.h) for fr in desc["frames"]]


def _frame_sun(f) -> dict:
    """A frame's own sun (brfgs.data.sun) and sky share (diffuse fraction) for the model file, when the
    frame has them."""
    own = getattr(f, "diffuse_fraction", None)
    out = {} if own is None else {"diffuse_fraction": [float(v) for v in own]}
    z = getattr(f, "sun_zenith_deg", float("nan"))
    if not np.isfinite(z):
        return out
    out.update(sun_zenith_deg=float(z), sun_azimuth_deg=float(f.sun_azimuth_deg))
    return {**out, "time_utc": f.time_utc} if getattr(f, "time_utc", None) else out


def scene_description(scene, c2w: np.ndarray) -> dict:
    """JSON-ready description of a :class:`brfgs.data.Scene` as trained, with the poses ``c2w``
    [F, 4, 4] (OpenGL) the training used (known or SfM): what model files carry so that a model
    renders without its scene."""
    intr = scene.intrinsics
    return {
        "name": scene.name,
        "root": str(Path(scene.root).resolve()),
        "wavelengths_nm": [float(w) for w in scene.wavelengths_nm],
        "fwhm_nm": None if scene.fwhm_nm is None else [float(w) for w in scene.fwhm_nm],
        "sun_zenith_deg": float(scene.sun_zenith_deg),
        "sun_azimuth_deg": float(scene.sun_azimuth_deg),
        **({"diffuse_fraction": [float(v) for v in scene.diffuse_fraction]}     # given; else the default at each sun
           if getattr(scene, "diffuse_fraction_source", "clear-sky default") != "clear-sky default" else {}),
        **({"origin": scene.origin.to_json(), "crs": scene.crs} if getattr(scene, "origin", None) else {}),
        "intrinsics": {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h},
        "downscale": int(getattr(scene, "downscale", 1)),
        "roi": getattr(scene, "roi", None),
        "split": scene.split_record(),
        "frames": [
            {
                "name": f.name,
                "split": f.split,
                "c2w": np.asarray(c2w[i], float).tolist(),
                "view_zenith_deg": float(f.view_zenith_deg),
                "view_azimuth_deg": float(f.view_azimuth_deg),
                **_frame_sun(f),
            }
            for i, f in enumerate(scene.frames)
        ],
    }
