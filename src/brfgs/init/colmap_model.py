"""A COLMAP sparse model as plain records, and the checks every record passes whatever its file format.

The readers (:mod:`brfgs.init.colmap_read` for ``.bin``, :mod:`brfgs.init.colmap_text` for ``.txt``)
hand their records to :func:`assemble`, which refuses impossible values in one line naming the file
and the record (``camera 3``, ``image 'view_00.png'``): focal lengths that are not finite and
positive, image sizes outside 1..65,535 pixels, non-finite parameters or poses, zero quaternions,
names that are not UTF-8, too long, empty or not unique (by name and by file stem, which picks the
cube). Poses of the five-file layout (rigs, frames) are composed as COLMAP does:
cam_from_world = sensor_from_rig ∘ rig_from_world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from brfgs.errors import UserError

__all__ = ["CAMERA_MODELS", "MODEL_IDS", "Camera", "Image", "Model", "RawImage", "Rig", "Frame", "assemble",
           "check_camera", "decode_name", "pose_matrix", "MAX_SIDE", "MAX_NAME_BYTES", "MAX_COMPONENT_BYTES"]

# COLMAP's camera models: id -> (name, names of its parameters).
_MODELS = {
    0: ("SIMPLE_PINHOLE", "f cx cy"), 1: ("PINHOLE", "fx fy cx cy"), 2: ("SIMPLE_RADIAL", "f cx cy k"),
    3: ("RADIAL", "f cx cy k1 k2"), 4: ("OPENCV", "fx fy cx cy k1 k2 p1 p2"),
    5: ("OPENCV_FISHEYE", "fx fy cx cy k1 k2 k3 k4"), 6: ("FULL_OPENCV", "fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6"),
    7: ("FOV", "fx fy cx cy omega"), 8: ("SIMPLE_RADIAL_FISHEYE", "f cx cy k"), 9: ("RADIAL_FISHEYE", "f cx cy k1 k2"),
    10: ("THIN_PRISM_FISHEYE", "fx fy cx cy k1 k2 p1 p2 k3 k4 sx1 sy1"),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", "fx fy cx cy k0 k1 k2 k3 k4 k5 p0 p1 s0 s1 s2 s3"),
    12: ("SIMPLE_DIVISION", "f cx cy k"), 13: ("DIVISION", "fx fy cx cy k"), 14: ("SIMPLE_FISHEYE", "f cx cy"),
    15: ("FISHEYE", "fx fy cx cy"), 16: ("EUCM", "fx fy cx cy alpha beta"), 17: ("EQUIRECTANGULAR", "w h"),
}
# id -> (name, parameter names, indices of the focal lengths among them)
CAMERA_MODELS = {mid: (name, tuple(p.split()), tuple(k for k, v in enumerate(p.split()) if v in ("f", "fx", "fy")))
                 for mid, (name, p) in _MODELS.items()}
MODEL_IDS = {name: mid for mid, (name, _, _) in CAMERA_MODELS.items()}

MAX_SIDE = 65_535            # pixels, width and height
MAX_NAME_BYTES = 4096        # an image name as a whole (PATH_MAX)
MAX_COMPONENT_BYTES = 255    # one component of an image name (NAME_MAX)
SENSOR_CAMERA, SENSOR_IMU = 0, 1


@dataclass(frozen=True)
class Camera:
    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class Image:
    """A registered image: its name, camera and cam_from_world [3, 4] (OpenCV axes, COLMAP's frame)."""
    image_id: int
    name: str
    camera_id: int
    cam_from_world: np.ndarray


@dataclass(frozen=True)
class RawImage:
    """An images.bin/.txt record as read: pose (qw, qx, qy, qz, tx, ty, tz) still unchecked."""
    image_id: int
    name: str
    camera_id: int
    pose: tuple[float, ...]


@dataclass(frozen=True)
class Rig:
    rig_id: int
    ref_sensor: tuple[int, int] | None                                  # (sensor type, sensor id)
    sensors: dict                                                       # (type, id) -> pose tuple or None


@dataclass(frozen=True)
class Frame:
    frame_id: int
    rig_id: int
    pose: tuple[float, ...]                                             # rig_from_world
    data: tuple[tuple[int, int, int], ...]                              # (sensor type, sensor id, data id)


@dataclass(frozen=True)
class Model:
    path: Path
    layout: str                                                         # "binary" or "text"
    cameras: dict[int, Camera]
    images: list[Image]                                                 # sorted by name
    n_points: int
    files: dict[str, Path]                                              # kind ("cameras", ...) -> its file


def check_camera(cam: Camera, where: Path) -> Camera:
    """``cam`` if its size and parameters are possible, else UserError naming the camera."""
    field = f"camera {cam.camera_id}"
    for side, v in (("width", cam.width), ("height", cam.height)):
        if not 1 <= v <= MAX_SIDE:
            raise UserError(f"{side} {v} pixels is outside 1..{MAX_SIDE}", file=where, field=field)
    names = CAMERA_MODELS[MODEL_IDS[cam.model]][1]
    bad = [k for k, v in enumerate(cam.params) if not math.isfinite(v)]
    if bad:
        raise UserError(f"{cam.model} parameter {names[bad[0]]} is {cam.params[bad[0]]} (must be finite)", file=where,
                        field=field)
    focal = CAMERA_MODELS[MODEL_IDS[cam.model]][2]
    for k in focal:
        if cam.params[k] <= 0:
            raise UserError(f"focal length {names[k]} = {cam.params[k]} pixels (must be > 0)", file=where, field=field)
    return cam


def pose_matrix(pose: tuple[float, ...], where: Path, field: str) -> np.ndarray:
    """[3, 4] (R | t) of COLMAP's (qw, qx, qy, qz, tx, ty, tz); the quaternion is normalised and must be
    finite and non-zero, the translation finite."""
    if not all(math.isfinite(v) for v in pose):
        raise UserError(f"pose (qw qx qy qz tx ty tz) {' '.join(repr(v) for v in pose)} is not finite", file=where,
                        field=field)
    top = max(abs(v) for v in pose[:4])
    if top == 0:
        raise UserError("the pose quaternion (qw qx qy qz) is zero", file=where, field=field)
    q = [v / top for v in pose[:4]]                                     # no overflow or underflow in the norm
    norm = math.hypot(*q)
    w, x, y, z = (v / norm for v in q)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return np.concatenate([r, np.asarray(pose[4:], float)[:, None]], 1)


def decode_name(raw: bytes, where: Path, field: str, at: int | None = None) -> str:
    """An image name from its bytes (at byte ``at`` of a binary file): UTF-8, not empty, no control
    characters, at most MAX_NAME_BYTES in all and MAX_COMPONENT_BYTES per '/'-separated component."""
    def fail(message: str):
        raise UserError(message if at is None else f"at byte {at}: {message}", file=where, field=field)

    if len(raw) > MAX_NAME_BYTES:
        fail(f"image name of {len(raw)} bytes (at most {MAX_NAME_BYTES})")
    try:
        name = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        fail(f"image name is not UTF-8 (byte {exc.start} of the name)")
    if not name.strip() or any(ord(c) < 32 or ord(c) == 127 for c in name):
        fail(f"image name {name[:40]!r} is empty or holds control characters")
    longest = max(len(p.encode()) for p in name.split("/"))
    if longest > MAX_COMPONENT_BYTES:
        fail(f"image name {name[:40]!r}... has a component of {longest} bytes (at most {MAX_COMPONENT_BYTES})")
    return name


def _unique(items, key, label, where: Path) -> dict:
    """{key(item): item}; UserError naming ``label(key)`` for a key that appears twice."""
    out = {}
    for it in items:
        k = key(it)
        if k in out:
            raise UserError("appears twice", file=where, field=label(k))
        out[k] = it
    return out


def _sensor_from_rig(rig: Rig, camera_id: int, rigs_file: Path) -> np.ndarray:
    sensor = (SENSOR_CAMERA, camera_id)
    if rig.ref_sensor == sensor:
        return np.eye(4)[:3]
    pose = rig.sensors.get(sensor)
    if pose is None:
        what = "has no pose in" if sensor in rig.sensors else "is not a sensor of"
        raise UserError(f"camera {camera_id} {what} rig {rig.rig_id}", file=rigs_file, field=f"rig {rig.rig_id}")
    return pose_matrix(pose, rigs_file, f"rig {rig.rig_id}")


def _rig_poses(images: list[RawImage], rigs: list[Rig], frames: list[Frame], files: dict) -> dict[int, np.ndarray]:
    """image id -> cam_from_world [3, 4] through its frame's rig_from_world and its rig's sensor_from_rig."""
    rig_by_id = _unique(rigs, lambda r: r.rig_id, "rig {}".format, files["rigs"])
    frame_of = {}
    for fr in _unique(frames, lambda f: f.frame_id, "frame {}".format, files["frames"]).values():
        for stype, sid, did in fr.data:
            if stype == SENSOR_CAMERA:
                if did in frame_of:
                    raise UserError(f"image id {did} is in two frames", file=files["frames"],
                                    field=f"frame {fr.frame_id}")
                frame_of[did] = (fr, sid)
    poses = {}
    for im in images:
        field = f"image {im.name}"
        if im.image_id not in frame_of:
            raise UserError(f"image id {im.image_id} is in no frame of {files['frames'].name}", file=files["images"],
                            field=field)
        fr, sid = frame_of[im.image_id]
        if sid != im.camera_id:
            raise UserError(f"camera {im.camera_id}, but frame {fr.frame_id} has it from camera {sid}",
                            file=files["images"], field=field)
        if fr.rig_id not in rig_by_id:
            raise UserError(f"rig {fr.rig_id} is not in {files['rigs'].name}", file=files["frames"],
                            field=f"frame {fr.frame_id}")
        rig_from_world = pose_matrix(fr.pose, files["frames"], f"frame {fr.frame_id}")
        s = _sensor_from_rig(rig_by_id[fr.rig_id], im.camera_id, files["rigs"])
        poses[im.image_id] = np.concatenate([s[:, :3] @ rig_from_world[:, :3],
                                             (s[:, :3] @ rig_from_world[:, 3] + s[:, 3])[:, None]], 1)
    return poses


def assemble(path: Path, layout: str, cameras: list[Camera], images: list[RawImage], rigs: list[Rig] | None,
             frames: list[Frame] | None, n_points: int, files: dict[str, Path]) -> Model:
    """The checked :class:`Model` of a reader's records; ``rigs``/``frames`` None for the three-file
    layout (poses from the images file). ``files``: the file each kind of record came from."""
    cams = _unique(cameras, lambda c: c.camera_id, "camera {}".format, files["cameras"])
    for cam in cams.values():
        check_camera(cam, files["cameras"])
    _unique(images, lambda im: im.image_id, "image id {}".format, files["images"])
    _unique(images, lambda im: im.name, "image {}".format, files["images"])
    stems = {}
    for im in images:
        last = im.name.rsplit("/", 1)[-1]
        if last in ("", ".", ".."):
            raise UserError(f"image name {im.name!r} does not end in a file name (its stem names the cube)",
                            file=files["images"], field=f"image {im.name}")
        stem = PurePosixPath(last).stem
        if stem in stems:
            raise UserError(f"images {stems[stem]!r} and {im.name!r} share the file stem {stem!r} (the stem names "
                            "the cube)", file=files["images"], field=f"image {im.name}")
        stems[stem] = im.name
        if im.camera_id not in cams:
            raise UserError(f"camera {im.camera_id} is not in {files['cameras'].name}", file=files["images"],
                            field=f"image {im.name}")
    own = {im.image_id: pose_matrix(im.pose, files["images"], f"image {im.name}") for im in images}
    poses = own if rigs is None else _rig_poses(images, rigs, frames, files)
    out = [Image(im.image_id, im.name, im.camera_id, poses[im.image_id]) for im in images]
    return Model(Path(path), layout, cams, sorted(out, key=lambda im: im.name), n_points, dict(files))
