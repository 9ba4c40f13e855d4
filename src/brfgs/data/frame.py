"""The frames of a scene's transforms.json: poses, nominal view angles, requested split and how to
read each cube (header checks only; brfgs.data.scene reads the pixels)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brfgs.data import validation as V
from brfgs.data.angles import angles_from_direction
from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.data.cube_io import CubeSource, open_cube
from brfgs.data.undistort import FrameCamera, read_frame_camera
from brfgs.errors import UserError

TRANSFORMS = "transforms.json"


@dataclass
class Frame:
    """One image of the acquisition."""

    name: str
    path: Path                      # cube file (header for ENVI)
    c2w: np.ndarray                 # [4, 4] OpenGL camera-to-world
    view_zenith_deg: float
    view_azimuth_deg: float
    split: str                      # "train" | "validation" | "test"
    split_given: bool = False       # True if transforms.json fixed it
    camera: FrameCamera | None = None   # its own (distorted or other) camera, resampled on reading
    sun_zenith_deg: float = float("nan")    # the sun of this frame (brfgs.data.sun)
    sun_azimuth_deg: float = float("nan")
    time_utc: str | None = None
    irradiance_scale: float = 1.0           # downwelling irradiance / nominal (sensor or panel): images are divided
    diffuse_fraction: np.ndarray | None = None  # [B] its own sky share of the irradiance (else the scene's)



def read_frames(root: Path, tf: Path, frames_meta, wl_all: np.ndarray, cameras: tuple[Intrinsics, dict],
                 allow_outside_links: bool = False) -> tuple[list[Frame], list[CubeSource]]:
    """Frames of transforms.json (poses, nominal angles, requested split) and how to read their cubes."""
    if not isinstance(frames_meta, list):
        raise UserError("expected a list of frames", file=tf, field="frames")
    if len(frames_meta) < V.MIN_FRAMES:
        raise UserError(f"found {len(frames_meta)} frames, at least {V.MIN_FRAMES} are needed for a "
                        f"multi-angle reconstruction", file=tf, field="frames")
    frames: list[Frame] = []
    sources: list[CubeSource] = []
    names: set[str] = set()
    for k, fm in enumerate(frames_meta):
        frame, src = _read_frame(root, tf, k, fm, names, wl_all, (*cameras, allow_outside_links))
        frames.append(frame)
        sources.append(src)
    return frames, sources


def _read_frame(root: Path, tf: Path, k: int, fm, names: set[str], wl_all: np.ndarray,
                camera: tuple[Intrinsics, dict, bool]) -> tuple[Frame, CubeSource]:
    """Frame ``k`` of transforms.json and its cube source; adds its name to ``names``.
    ``camera``: (full-resolution pinhole intrinsics, top-level camera keys, allow_outside_links)."""
    full_intr, cam_keys, allow_outside_links = camera
    fld = f"frames[{k}]"
    if not isinstance(fm, dict):
        raise UserError("expected an object", file=tf, field=fld)
    if "file_path" not in fm:
        raise UserError("required field missing", file=tf, field=f"{fld}.file_path")
    cube_path = V.path_inside(root, fm["file_path"], tf, f"{fld}.file_path", allow_outside_links)
    name = Path(fm["file_path"]).stem
    if name in names:
        raise UserError(f"duplicate frame name {name!r}", file=tf, field=f"{fld}.file_path")
    names.add(name)
    fld = f"frames[{k}] ('{name}')"
    vz = va = None
    if fm.get("view_zenith_deg") is not None:
        vz = V.number(fm["view_zenith_deg"], tf, f"{fld}.view_zenith_deg", lo=0.0, hi=89.999)
    if fm.get("view_azimuth_deg") is not None:
        va = V.number(fm["view_azimuth_deg"], tf, f"{fld}.view_azimuth_deg", lo=-360.0, hi=360.0)
    if fm.get("transform_matrix") is not None:
        c2w = V.transform_matrix(fm["transform_matrix"], tf, f"{fld}.transform_matrix")
    else:
        if vz is None or va is None or fm.get("distance_m") is None:
            raise UserError("needs either transform_matrix or view_zenith_deg, view_azimuth_deg and "
                            "distance_m", file=tf, field=fld)
        c2w = pose_from_view_angles(vz, va, V.camera_distance(fm["distance_m"], tf, f"{fld}.distance_m"))
    V.camera_position(c2w, tf, f"{fld}.transform_matrix", above_ground=vz is None or va is None)
    if vz is None or va is None:  # derive nominal angles from the camera centre
        zr, ar = angles_from_direction(c2w[:3, 3])
        vz, va = float(np.degrees(zr)), float(np.degrees(ar))
    split = fm.get("split")
    if split is not None and split not in ("train", "test"):
        raise UserError(f"split must be 'train' or 'test', found {split!r}", file=tf, field=f"{fld}.split")
    src = open_cube(cube_path, wl_all, tf, name, allow_outside_links)
    own = read_frame_camera(fm, tf, f"{fld}.", cam_keys)
    w, h = own.intrinsics.w, own.intrinsics.h
    if (src.lines, src.samples) != (h, w):
        raise UserError(f"cube is {src.samples}x{src.lines} pixels but {TRANSFORMS} gives w={w}, h={h}; "
                        f"the intrinsics do not fit this image", file=cube_path, field="samples/lines")
    own = None if own.is_pinhole_like(full_intr) else own
    return Frame(name, cube_path, c2w, vz, va, split or "", split is not None, own), src
