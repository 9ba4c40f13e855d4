"""A native scene written as a user's COLMAP project (``brfgs simulate --layout colmap``).

The project is what a UAV campaign processed with COLMAP hands over, so that ``brfgs import colmap``
is tested end to end on data with known truth:

- ``images/<name>.tif``: each cube as stored (no irradiance division, no resampling), band-first,
  LZW-compressed TIFF;
- ``sparse/0``: a binary COLMAP model — one camera per distinct lens (PINHOLE, or OPENCV with
  k1, k2, p1, p2), every image with its pose, and sparse points back-projected from the first
  view's truth depth (every ``point_step``-th pixel, coloured CIR) — moved into an arbitrary frame
  by a seeded random similarity, as SfM leaves a model;
- ``spectral.json``: the sidecar ``brfgs import colmap`` reads (wavelengths, fwhm, origin/crs, dark
  frames, the scene sun when frames have none, per-image time / sun / irradiance_scale / split) and
  ``camera_positions_enu`` of every image (GNSS-like camera centres, exact here) from which the
  import recovers the similarity (pycolmap ``estimate_sim3d``);
- ``calibration/`` and ``truth/`` as in the native layout.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
from brfgs.init.pycolmap_safe import pycolmap
import tifffile

from brfgs.data import atomic
from brfgs.data.lock import LOCK_NAME
from brfgs.data.cameras import GL_TO_CV
from brfgs.data.cube_io import read_block_averaged
from brfgs.data.validation import RangeTally
from brfgs.data.scene import read_scene
from brfgs.data.undistort import FrameCamera, read_frame_camera
from brfgs.errors import UserError
from brfgs.init import colmap_io

__all__ = ["write_colmap_project", "pycolmap_camera", "prepare_project_dir", "PROJECT_ENTRIES"]

PROJECT_ENTRIES = ("images", "sparse", "spectral.json", "calibration", "truth", "transforms.json", ".native")

# the sidecar keys `brfgs import colmap` reads; the scene sun is added only when frames carry none
_SIDECAR_KEYS = tuple(k for k in colmap_io._SIDECAR_KEYS if not k.startswith("sun_"))


def pycolmap_camera(cam: FrameCamera, camera_id: int):
    """The pycolmap camera of a brfgs camera: PINHOLE, or OPENCV when it has distortion (both put
    pixel centres at +0.5, as brfgs does)."""
    i = cam.intrinsics
    model = "OPENCV" if any(cam.dist) else "PINHOLE"
    out = pycolmap.Camera.create_from_model_name(camera_id, model, float(i.fl_x), int(i.w), int(i.h))
    params = [i.fl_x, i.fl_y, i.cx, i.cy] + (list(cam.dist) if model == "OPENCV" else [])
    out.params = np.asarray(params, float)
    return out


def _truth_points(scene_dir: Path, name: str, cam: FrameCamera, c2w_gl: np.ndarray, step: int,
                  cir_bands: np.ndarray, cube: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ENU points [P, 3] and CIR colours [P, 3] in [0, 1] of every ``step``-th pixel of a view's truth
    depth (m along the optical axis, in the view's own — possibly distorted — image)."""
    path = scene_dir / "truth" / "depth" / f"{name}.npy"
    if not path.is_file():
        return np.zeros((0, 3)), np.zeros((0, 3))
    depth = np.load(path)                                                       # [H, W]
    v, u = np.mgrid[step // 2:depth.shape[0]:step, step // 2:depth.shape[1]:step]
    z = depth[v, u]
    keep = np.isfinite(z) & (z > 0)
    u, v, z = u[keep], v[keep], z[keep]
    xn = cv2.undistortPoints(np.c_[u, v].astype(np.float64)[:, None], cam.opencv_K(),
                             np.asarray(cam.dist, float))[:, 0]                   # [P, 2]
    p_cv = np.c_[xn * z[:, None], z]                                            # [P, 3] camera (OpenCV axes)
    c2w_cv = np.asarray(c2w_gl, float) @ GL_TO_CV
    pts = p_cv @ c2w_cv[:3, :3].T + c2w_cv[:3, 3]
    rgb = cube[v, u][:, cir_bands]
    rgb = np.clip(rgb / max(float(np.nanpercentile(rgb, 99)), 1e-6), 0, 1)
    return pts, np.nan_to_num(rgb)


def _frame_cameras(meta: dict, tf: Path) -> list[FrameCamera]:
    top = {k: meta[k] for k in ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2")
           if k in meta}
    cams = [read_frame_camera(fr, tf, f"frames[{i}].", base=top) for i, fr in enumerate(meta["frames"])]
    if any(c is None for c in cams):
        raise UserError("every frame needs intrinsics (fl_x, fl_y, cx, cy, w, h) to be written as COLMAP",
                        file=tf, field="fl_x")
    return cams


def _write_cubes(sc, project: Path) -> np.ndarray:
    """Every cube as an LZW TIFF in project/images; returns the first cube [H, W, B]."""
    first = None
    for i, f in enumerate(sc.frames):
        src = sc._sources[i]                                                     # as stored: no scale, no resampling
        cube = np.asarray(read_block_averaged(src, sc.band_indices, None, 1, RangeTally((-np.inf, np.inf)), f.name))
        tifffile.imwrite(project / "images" / f"{f.name}.tif", np.moveaxis(cube, -1, 0), photometric="minisblack",
                         planarconfig="separate", compression="lzw")
        first = cube if first is None else first
    return first


def prepare_project_dir(project: Path, overwrite: bool, resume: bool) -> None:
    """Check the folder a COLMAP project is simulated into: new, empty, an interrupted run (its
    ``.native`` staging folder, with ``resume``), or a finished project (replaced with ``overwrite``;
    folders holding anything else are refused)."""
    if project.exists() and not project.is_dir():
        raise UserError("output path exists and is not a folder", file=project)
    entries = [p for p in project.iterdir() if p.name != LOCK_NAME] if project.is_dir() else []
    if not entries:
        return
    if resume and (project / ".native").is_dir() and all(p.name in PROJECT_ENTRIES for p in entries):
        for p in entries:                                   # a conversion cut short is redone from the staging
            if p.name != ".native":
                shutil.rmtree(p) if p.is_dir() else p.unlink()
        return
    if not overwrite:
        raise UserError("output folder exists and is not empty; pass --overwrite to replace the simulation in it"
                        + (" (--resume continues only an interrupted run)" if resume else ""), file=project)
    if any(p.name not in PROJECT_ENTRIES for p in entries):
        raise UserError("output folder holds files that a simulation does not write; refusing to overwrite it "
                        "(choose an empty or new folder)", file=project)
    for p in entries:
        shutil.rmtree(p) if p.is_dir() else p.unlink()


def write_colmap_project(scene_dir: str | Path, project: str | Path, seed: int = 0, point_step: int = 4,
                         move_extras: bool = False) -> dict:
    """Write the native scene ``scene_dir`` as a COLMAP project in ``project`` (module docstring); the
    project folder must not exist or be empty. ``move_extras`` moves calibration/ and truth/ instead of
    copying them. Returns a summary (images, cameras, points, similarity scale)."""
    scene_dir, project = Path(scene_dir), Path(project)
    if project.exists() and any(p.name not in (".native", LOCK_NAME) for p in project.iterdir()):
        raise UserError("the COLMAP project folder is not empty", file=project)
    sc = read_scene(scene_dir)
    tf = scene_dir / "transforms.json"
    meta = json.loads(tf.read_text())
    cams = _frame_cameras(meta, tf)
    (project / "images").mkdir(parents=True, exist_ok=True)
    first = _write_cubes(sc, project)
    rec = pycolmap.Reconstruction()
    ids: dict[FrameCamera, int] = {}
    for cam in cams:
        if cam not in ids:
            ids[cam] = len(ids) + 1
            rec.add_camera_with_trivial_rig(pycolmap_camera(cam, ids[cam]))
    for k, (f, cam) in enumerate(zip(sc.frames, cams)):
        w2c = np.linalg.inv(np.asarray(f.c2w, float) @ GL_TO_CV)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"{f.name}.tif", camera_id=ids[cam], image_id=k + 1),
                                         pose)
    cir = np.array([int(np.argmin(abs(sc.wavelengths_nm - w))) for w in (860.0, 650.0, 550.0)])
    pts, rgb = _truth_points(scene_dir, sc.frames[0].name, cams[0], sc.frames[0].c2w, point_step, cir, first)
    for p, c in zip(pts, (rgb * 255).astype(np.uint8)):
        rec.add_point3D(p, pycolmap.Track(), c)
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    scale = float(rng.uniform(0.02, 0.2))
    rec.transform(pycolmap.Sim3d(scale, pycolmap.Rotation3d(np.array([q[1], q[2], q[3], q[0]])),   # xyzw
                                 rng.normal(size=3) * 5))
    (project / "sparse" / "0").mkdir(parents=True, exist_ok=True)
    rec.write(str(project / "sparse" / "0"))
    _write_sidecar(project, meta, sc)
    for sub in ("calibration", "truth"):
        if (scene_dir / sub).is_dir():
            (shutil.move if move_extras else shutil.copytree)(str(scene_dir / sub), str(project / sub))
    return {"images": len(sc.frames), "cameras": len(ids), "points": len(pts), "scale": scale}


def _write_sidecar(project: Path, meta: dict, sc) -> None:
    side = {k: meta[k] for k in _SIDECAR_KEYS if k in meta}
    if not any("time" in fr or "sun_zenith_deg" in fr for fr in meta["frames"]):
        side.update({k: meta[k] for k in ("sun_zenith_deg", "sun_azimuth_deg") if k in meta})
    side["frames"] = {f.name: {k: fr[k] for k in colmap_io._FRAME_KEYS if k in fr} for f, fr in zip(sc.frames, meta["frames"])}
    side["camera_positions_enu"] = {f.name: np.asarray(f.c2w)[:3, 3].tolist() for f in sc.frames}
    atomic.write_text(project / "spectral.json", atomic.json_text(side, indent=1))
