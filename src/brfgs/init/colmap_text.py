"""COLMAP's text model files (cameras, images, points3D, rigs, frames ``.txt``) as the records of
:mod:`brfgs.init.colmap_model`; each malformed line is refused in one line naming the file, the line
number and, where known, the record. Lines are read one at a time, at most :data:`MAX_LINE` bytes each,
so that memory stays bounded whatever the file holds; the values are checked by
:func:`brfgs.init.colmap_model.assemble` as for the binary files.
"""

from __future__ import annotations

from pathlib import Path

from brfgs.errors import UserError
from brfgs.init.colmap_model import (CAMERA_MODELS, MODEL_IDS, SENSOR_CAMERA, SENSOR_IMU, Camera, Frame, RawImage,
                                     Rig, decode_name)

__all__ = ["read_text_files", "MAX_LINE"]

MAX_LINE = 16 * 2**20           # bytes of one line (an image's 2D points: ~400,000 of them)
_SENSOR_TYPES = {b"CAMERA": SENSOR_CAMERA, b"IMU": SENSOR_IMU}


class _Line:
    """One line's tokens with the file and line number, for parsing with one-line errors."""

    def __init__(self, path: Path, no: int, tokens: list[bytes], field: str | None = None):
        self.path, self.no, self.tokens, self.k, self.field = path, no, tokens, 0, field

    def fail(self, message: str):
        raise UserError(f"line {self.no}: {message}", file=self.path, field=self.field)

    def take(self, what: str) -> bytes:
        if self.k >= len(self.tokens):
            self.fail(f"ends before {what}")
        self.k += 1
        return self.tokens[self.k - 1]

    def int(self, what: str) -> int:
        tok = self.take(what)
        try:
            return int(tok)
        except ValueError:
            self.fail(f"{what} {tok[:40]!r} is not an integer")

    def float(self, what: str) -> float:
        tok = self.take(what)
        try:
            return float(tok)
        except ValueError:
            self.fail(f"{what} {tok[:40]!r} is not a number")

    def floats(self, n: int, what: str) -> tuple[float, ...]:
        return tuple(self.float(what) for _ in range(n))

    def sensor(self) -> tuple[int, int]:
        tok = self.take("a sensor type")
        if tok not in _SENSOR_TYPES:
            self.fail(f"unknown sensor type {tok[:40]!r} (CAMERA or IMU)")
        return _SENSOR_TYPES[tok], self.int("a sensor id")

    def end(self) -> None:
        if self.k != len(self.tokens):
            self.fail(f"{len(self.tokens) - self.k} values after the record's last one")


def _lines(path: Path, keep_blank: bool = False):
    """(line number, raw line without its end) of each line; comments (#) and, unless ``keep_blank``,
    blank lines left out."""
    with open(path, "rb") as f:
        no = 0
        while True:
            raw = f.readline(MAX_LINE + 1)
            if not raw:
                return
            no += 1
            if len(raw) > MAX_LINE:
                raise UserError(f"line {no} is longer than {MAX_LINE} bytes", file=path)
            raw = raw.rstrip(b"\r\n")
            if raw.lstrip().startswith(b"#") or (not raw.strip() and not keep_blank):
                continue
            yield no, raw


def _cameras(path: Path) -> list[Camera]:
    out = []
    for no, raw in _lines(path):
        ln = _Line(path, no, raw.split())
        cid = ln.int("the camera id")
        ln.field = f"camera {cid}"
        model = ln.take("the camera model").decode("ascii", "replace")
        if model not in MODEL_IDS:
            ln.fail(f"unknown camera model {model[:40]!r}")
        w, h = ln.int("the width"), ln.int("the height")
        n = len(CAMERA_MODELS[MODEL_IDS[model]][1])
        if len(ln.tokens) - ln.k != n:
            ln.fail(f"{model} has {n} parameters, the line {len(ln.tokens) - ln.k}")
        out.append(Camera(cid, model, w, h, ln.floats(n, "a parameter")))
    return out


def _images(path: Path) -> list[RawImage]:
    """Two lines per image: id, pose, camera id and name; then its 2D points (x y point3D_id)*, maybe blank."""
    out, head = [], None
    for no, raw in _lines(path, keep_blank=True):
        if head is None:
            if not raw.strip():
                continue
            parts = raw.split(maxsplit=9)
            ln = _Line(path, no, parts[:9])
            iid = ln.int("the image id")
            ln.field = f"image id {iid}"
            pose, cid = ln.floats(7, "a pose value"), ln.int("the camera id")
            if len(parts) < 10:
                ln.fail("ends before the image name")
            head = RawImage(iid, decode_name(parts[9].strip(), path, f"image id {iid}"), cid, pose)
            continue
        if len(raw.split()) % 3:
            _Line(path, no, [], f"image {head.name}").fail("2D points are not (x, y, point3D_id) triples")
        out.append(head)
        head = None
    return out + ([head] if head is not None else [])


def _points(path: Path) -> int:
    n = 0
    for no, raw in _lines(path):
        ln = _Line(path, no, raw.split())
        pid = ln.int("the 3D point id")
        ln.field = f"3D point {pid}"
        ln.floats(3, "a coordinate")
        if not all(0 <= ln.int("a colour value") <= 255 for _ in range(3)):
            ln.fail("a colour value is outside 0..255")
        ln.float("the error")
        if (len(ln.tokens) - ln.k) % 2:
            ln.fail("the track is not (image_id, point2D_idx) pairs")
        n += 1
    return n


def _rigs(path: Path) -> list[Rig]:
    out = []
    for no, raw in _lines(path):
        ln = _Line(path, no, raw.split())
        rid = ln.int("the rig id")
        ln.field = f"rig {rid}"
        n = ln.int("the number of sensors")
        if n < 0 or n > len(ln.tokens):
            ln.fail(f"{n} sensors on a line of {len(ln.tokens)} values")
        ref = ln.sensor() if n else None
        sensors = {}
        for _ in range(max(n - 1, 0)):
            sensor = ln.sensor()
            has_pose = ln.int("has_pose")
            if has_pose not in (0, 1):
                ln.fail(f"has_pose is {has_pose} (0 or 1)")
            sensors[sensor] = ln.floats(7, "a sensor pose value") if has_pose else None
        ln.end()
        out.append(Rig(rid, ref, sensors))
    return out


def _frames(path: Path) -> list[Frame]:
    out = []
    for no, raw in _lines(path):
        ln = _Line(path, no, raw.split())
        fid = ln.int("the frame id")
        ln.field = f"frame {fid}"
        rid, pose, n = ln.int("the rig id"), ln.floats(7, "a pose value"), ln.int("the number of data ids")
        if n < 0 or 3 * n != len(ln.tokens) - ln.k:
            ln.fail(f"{n} data ids, but {len(ln.tokens) - ln.k} values follow (3 per data id)")
        data = tuple((*ln.sensor(), ln.int("a data id")) for _ in range(n))
        out.append(Frame(fid, rid, pose, data))
    return out


def read_text_files(files: dict[str, Path]) -> dict:
    """{kind: records} of a text model's files (rigs and frames None when the model has none)."""
    return {"cameras": _cameras(files["cameras"]), "images": _images(files["images"]),
            "points3D": _points(files["points3D"]),
            "rigs": _rigs(files["rigs"]) if "rigs" in files else None,
            "frames": _frames(files["frames"]) if "frames" in files else None}
