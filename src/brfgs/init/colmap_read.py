"""COLMAP sparse models read in bounded time and memory: :func:`read_model`.

A model folder holds ``cameras``, ``images`` and ``points3D`` (COLMAP's three-file layout) and, as
COLMAP 3.12+ and pycolmap write them, ``rigs`` and ``frames`` — all ``.bin`` or all ``.txt``. The
binary files are memory-mapped and walked with a cursor that checks, before each read, that the
record fits in the bytes left: a count read from the file (up to 2^64 − 1) is compared with the room
its records need before any loop or allocation, so a cut or corrupted file is refused in one line
naming the file and the byte offset, never read past its end, and a file with bytes after its last
record is refused too. What brfgs needs (cameras, image names and poses) is kept; the rest (2D
points, 3D points and their tracks) is only checked for its structure. The values are checked by
:func:`brfgs.init.colmap_model.assemble`.
"""

from __future__ import annotations

import mmap
import struct
from pathlib import Path

from brfgs.errors import UserError
from brfgs.init.colmap_model import (CAMERA_MODELS, MAX_NAME_BYTES, SENSOR_CAMERA, SENSOR_IMU, Camera, Frame,
                                     Model, RawImage, Rig, assemble, decode_name)
from brfgs.init.colmap_text import read_text_files

__all__ = ["read_model", "model_files"]

_U32, _U64 = struct.Struct("<I"), struct.Struct("<Q")
_CAMERA = struct.Struct("<IiQQ")              # camera_id, model_id, width, height
_IMAGE = struct.Struct("<I7dI")               # image_id, qw qx qy qz tx ty tz, camera_id
_POINT = struct.Struct("<Q3d3BdQ")            # point3D_id, xyz, rgb, error, track length
_RIG = struct.Struct("<II")                   # rig_id, number of sensors
_SENSOR = struct.Struct("<iI")                # sensor type, sensor id
_POSE = struct.Struct("<7d")                  # qw qx qy qz tx ty tz
_FRAME = struct.Struct("<II7dI")              # frame_id, rig_id, rig_from_world, number of data ids
_DATA = struct.Struct("<iIQ")                 # sensor type, sensor id, data id
_POINT2D, _TRACK_ELEMENT = 24, 8              # bytes of one 2D point (x, y, point3D_id), one track element


class _Cursor:
    """A read-only memory map of one file and a position in it; every read first checks the bytes left."""

    def __init__(self, path: Path):
        self.path, self.pos = path, 0
        with open(path, "rb") as f:
            self.size = f.seek(0, 2)
            self.buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if self.size else b""

    def close(self) -> None:
        if isinstance(self.buf, mmap.mmap):
            self.buf.close()

    def need(self, n: int, what: str) -> None:
        if n > self.size - self.pos:
            raise UserError(f"truncated or corrupt at byte {self.pos}: {n} bytes needed for {what}, the file has "
                            f"{self.size - self.pos} left (of {self.size})", file=self.path)

    def read(self, fmt: struct.Struct, what: str) -> tuple:
        self.need(fmt.size, what)
        out = fmt.unpack_from(self.buf, self.pos)
        self.pos += fmt.size
        return out

    def skip(self, n: int, what: str) -> None:
        self.need(n, what)
        self.pos += n

    def count(self, fmt: struct.Struct, least: int, what: str) -> int:
        """A count of records of at least ``least`` bytes each; refused when they cannot fit in the rest."""
        at = self.pos
        (n,) = self.read(fmt, f"the number of {what}")
        if n * least > self.size - self.pos:
            raise UserError(f"truncated or corrupt at byte {at}: {n} {what} need at least {n * least} bytes, the "
                            f"file has {self.size - self.pos} left (of {self.size})", file=self.path)
        return n

    def cstring(self, what: str) -> bytes:
        """Bytes up to a NUL (consumed); at most MAX_NAME_BYTES before it."""
        end = self.buf.find(b"\0", self.pos, min(self.size, self.pos + MAX_NAME_BYTES + 1))
        if end < 0 and self.size - self.pos <= MAX_NAME_BYTES:
            raise UserError(f"truncated or corrupt at byte {self.pos}: {what} has no terminating NUL before the end "
                            f"of the file (byte {self.size})", file=self.path)
        if end < 0:
            raise UserError(f"at byte {self.pos}: {what} is longer than {MAX_NAME_BYTES} bytes", file=self.path)
        raw = bytes(self.buf[self.pos:end])
        self.pos = end + 1
        return raw

    def finish(self) -> None:
        if self.pos != self.size:
            raise UserError(f"{self.size - self.pos} bytes after the last record (at byte {self.pos}); the file "
                            "is corrupt or not a COLMAP model file", file=self.path)


def _walk(path: Path, body):
    cur = _Cursor(path)
    try:
        out = body(cur)
        cur.finish()
        return out
    finally:
        cur.close()


def _cameras(cur: _Cursor) -> list[Camera]:
    out = []
    for _ in range(cur.count(_U64, _CAMERA.size, "cameras")):
        at = cur.pos
        cid, mid, w, h = cur.read(_CAMERA, "a camera record")
        if mid not in CAMERA_MODELS:
            raise UserError(f"at byte {at}: unknown camera model id {mid}", file=cur.path, field=f"camera {cid}")
        name, n = CAMERA_MODELS[mid][0], len(CAMERA_MODELS[mid][1])
        params = cur.read(struct.Struct(f"<{n}d"), f"the {n} parameters of camera {cid} ({name})")
        out.append(Camera(cid, name, w, h, params))
    return out


def _images(cur: _Cursor) -> list[RawImage]:
    out = []
    for _ in range(cur.count(_U64, _IMAGE.size + 1 + _U64.size, "images")):
        iid, *pose, cid = cur.read(_IMAGE, "an image record")
        at = cur.pos
        name = decode_name(cur.cstring(f"the name of image id {iid}"), cur.path, f"image id {iid}", at)
        (n2d,) = cur.read(_U64, f"the number of 2D points of image {name!r}")
        cur.skip(n2d * _POINT2D, f"the {n2d} 2D points of image {name!r}")
        out.append(RawImage(iid, name, cid, tuple(pose)))
    return out


def _points(cur: _Cursor) -> int:
    n = cur.count(_U64, _POINT.size, "3D points")
    for _ in range(n):
        pid, *_, track = cur.read(_POINT, "a 3D point record")
        cur.skip(track * _TRACK_ELEMENT, f"the track of {track} elements of 3D point {pid}")
    return n


def _sensor(cur: _Cursor, rid: int) -> tuple[int, int]:
    at = cur.pos
    stype, sid = cur.read(_SENSOR, f"a sensor of rig {rid}")
    if stype not in (SENSOR_CAMERA, SENSOR_IMU):
        raise UserError(f"at byte {at}: unknown sensor type {stype}", file=cur.path, field=f"rig {rid}")
    return stype, sid


def _rigs(cur: _Cursor) -> list[Rig]:
    out = []
    for _ in range(cur.count(_U64, _RIG.size, "rigs")):
        rid, n = cur.read(_RIG, "a rig record")
        if n:
            cur.need(_SENSOR.size + (n - 1) * (_SENSOR.size + 1), f"the {n} sensors of rig {rid}")
        ref = _sensor(cur, rid) if n else None
        sensors = {}
        for _ in range(max(n - 1, 0)):
            sensor = _sensor(cur, rid)
            (has_pose,) = cur.read(struct.Struct("<B"), f"a sensor of rig {rid}")
            if has_pose > 1:
                raise UserError(f"at byte {cur.pos - 1}: has_pose is {has_pose} (0 or 1)", file=cur.path,
                                field=f"rig {rid}")
            sensors[sensor] = cur.read(_POSE, f"a sensor pose of rig {rid}") if has_pose else None
        out.append(Rig(rid, ref, sensors))
    return out


def _frames(cur: _Cursor) -> list[Frame]:
    out = []
    for _ in range(cur.count(_U64, _FRAME.size, "frames")):
        fid, rid, *pose, n = cur.read(_FRAME, "a frame record")
        cur.need(n * _DATA.size, f"the {n} data ids of frame {fid}")
        data = []
        for _ in range(n):
            at = cur.pos
            stype, sid, did = cur.read(_DATA, f"a data id of frame {fid}")
            if stype not in (SENSOR_CAMERA, SENSOR_IMU):
                raise UserError(f"at byte {at}: unknown sensor type {stype}", file=cur.path, field=f"frame {fid}")
            data.append((stype, sid, did))
        out.append(Frame(fid, rid, tuple(pose), tuple(data)))
    return out


KINDS = ("cameras", "images", "points3D", "rigs", "frames")


def model_files(path: Path) -> tuple[str, dict[str, Path]]:
    """("binary" | "text", {kind: file}) of a model folder: cameras, images and points3D, with rigs and
    frames when both are there; UserError naming what is missing."""
    path = Path(path)
    for ext, layout in ((".bin", "binary"), (".txt", "text")):
        files = {k: path / f"{k}{ext}" for k in KINDS}
        there = {k for k, p in files.items() if p.is_file()}
        if "cameras" not in there:
            continue
        missing = [files[k].name for k in KINDS[:3] if k not in there]
        if missing:
            raise UserError(f"the COLMAP model lacks {' and '.join(missing)}", file=path)
        if len(there & {"rigs", "frames"}) == 1:
            lone, other = ("rigs", "frames") if "rigs" in there else ("frames", "rigs")
            raise UserError(f"{files[lone].name} without {files[other].name}", file=path)
        return layout, {k: p for k, p in files.items() if k in there}
    raise UserError("not a COLMAP sparse model (no cameras.bin or cameras.txt)", file=path)


def read_model(path: Path) -> Model:
    """The checked :class:`~brfgs.init.colmap_model.Model` of a COLMAP model folder (binary or text)."""
    layout, files = model_files(path)
    if layout == "text":
        rec = read_text_files(files)
    else:
        rec = {"cameras": _walk(files["cameras"], _cameras), "images": _walk(files["images"], _images),
               "points3D": _walk(files["points3D"], _points),
               "rigs": _walk(files["rigs"], _rigs) if "rigs" in files else None,
               "frames": _walk(files["frames"], _frames) if "frames" in files else None}
    return assemble(Path(path), layout, rec["cameras"], rec["images"], rec["rigs"], rec["frames"], rec["points3D"],
                    files)
