"""Tiny COLMAP models written byte by byte for the reader's tests (COLMAP's documented binary and text
layouts, written out here independently of brfgs's reader; pycolmap reads what they write, tested in
test_import_colmap_binary.py), and the project folder `brfgs import colmap` expects around them."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

__all__ = ["Cam", "Img", "Pt", "TINY", "write_bin", "write_txt", "make_project", "run_import", "import_error"]


@dataclass(frozen=True)
class Cam:
    camera_id: int = 1
    model_id: int = 1                                   # PINHOLE
    width: int = 24
    height: int = 16
    params: tuple = (30.0, 31.0, 12.0, 8.0)
    model_name: str = "PINHOLE"


@dataclass(frozen=True)
class Img:
    image_id: int
    name: bytes
    pose: tuple = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)    # qw qx qy qz tx ty tz (cam_from_world)
    camera_id: int = 1
    points2d: tuple = ((3.0, 4.0, 1),)                  # (x, y, point3D_id)


@dataclass(frozen=True)
class Pt:
    point_id: int = 1
    xyz: tuple = (0.5, -0.25, 5.0)
    rgb: tuple = (10, 20, 30)
    error: float = 0.5
    track: tuple = ((1, 0), (2, 0))                     # (image_id, point2D_idx)


_Q = tuple(float(v) for v in np.array([0.9, 0.1, -0.2, 0.3]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3]))


@dataclass(frozen=True)
class Records:
    cameras: tuple = (Cam(),)
    images: tuple = field(default_factory=lambda: (
        Img(1, b"v0.png", (1.0, 0.0, 0.0, 0.0, 0.1, -0.2, 1.0)),
        Img(2, b"v1.png", (*_Q, 0.5, 0.0, 2.0), points2d=((5.0, 6.0, 1), (7.0, 1.0, -1)))))
    points: tuple = (Pt(),)

    def with_camera(self, **kw) -> Records:
        return replace(self, cameras=(replace(self.cameras[0], **kw),))

    def with_image(self, k: int, **kw) -> Records:
        ims = list(self.images)
        ims[k] = replace(ims[k], **kw)
        return replace(self, images=tuple(ims))


TINY = Records()


def write_bin(folder: Path, rec: Records) -> Path:
    """cameras.bin, images.bin and points3D.bin (COLMAP's three-file binary layout)."""
    folder.mkdir(parents=True, exist_ok=True)
    b = struct.pack("<Q", len(rec.cameras))
    for c in rec.cameras:
        b += struct.pack("<IiQQ", c.camera_id, c.model_id, c.width, c.height) + struct.pack(f"<{len(c.params)}d",
                                                                                           *c.params)
    (folder / "cameras.bin").write_bytes(b)
    b = struct.pack("<Q", len(rec.images))
    for im in rec.images:
        b += struct.pack("<I7dI", im.image_id, *im.pose, im.camera_id) + im.name + b"\0"
        b += struct.pack("<Q", len(im.points2d))
        for x, y, pid in im.points2d:
            b += struct.pack("<ddQ", x, y, pid % 2**64)
    (folder / "images.bin").write_bytes(b)
    b = struct.pack("<Q", len(rec.points))
    for p in rec.points:
        b += struct.pack("<Q3d3BdQ", p.point_id, *p.xyz, *p.rgb, p.error, len(p.track))
        b += b"".join(struct.pack("<II", i, k) for i, k in p.track)
    (folder / "points3D.bin").write_bytes(b)
    return folder


def write_txt(folder: Path, rec: Records) -> Path:
    """cameras.txt, images.txt and points3D.txt (COLMAP's three-file text layout)."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:"]
    lines += [" ".join(map(repr, (c.camera_id,))) + f" {c.model_name} {c.width} {c.height} "
              + " ".join(repr(float(v)) for v in c.params) for c in rec.cameras]
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    out = b"# Image list with two lines of data per image:\n"
    for im in rec.images:
        out += f"{im.image_id} {' '.join(repr(float(v)) for v in im.pose)} {im.camera_id} ".encode() + im.name + b"\n"
        out += " ".join(f"{x!r} {y!r} {pid}" for x, y, pid in im.points2d).encode() + b"\n"
    (folder / "images.txt").write_bytes(out)
    lines = ["# 3D point list with one line of data per point:"]
    lines += [f"{p.point_id} {' '.join(map(repr, p.xyz))} {' '.join(map(str, p.rgb))} {p.error!r} "
              + " ".join(f"{i} {k}" for i, k in p.track) for p in rec.points]
    (folder / "points3D.txt").write_text("\n".join(lines) + "\n")
    return folder


def make_project(root: Path, rec: Records = TINY, fmt: str = "bin") -> Path:
    """``root`` with sparse/0 (``rec`` as ``fmt`` "bin" or "txt") and an empty cube file per image stem
    (`brfgs import colmap` only looks the cubes up)."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    for im in rec.images:
        try:
            stem = Path(im.name.decode()).stem
            if 0 < len(stem.encode()) <= 250 and "/" not in stem:
                (root / "images" / f"{stem}.npy").write_bytes(np.zeros(1).tobytes())
        except (UnicodeDecodeError, ValueError, OSError):
            pass
    (write_bin if fmt == "bin" else write_txt)(root / "sparse" / "0", rec)
    return root


def run_import(root: Path, capsys, *extra: str) -> tuple[int, str]:
    """(exit status, stderr) of `brfgs import colmap ROOT --overwrite`."""
    from brfgs.cli import main

    rc = main(["import", "colmap", str(root), "--overwrite", *extra])
    return rc, capsys.readouterr().err.strip()


def import_error(root: Path) -> str | None:
    """What `brfgs import colmap ROOT --overwrite` would print after "brfgs: error: " (None: it succeeds),
    through the library call (the command line's own start-up costs ~40 ms a call; tests that sweep
    hundreds of files use this, and run_import on a sample)."""
    from brfgs.errors import UserError
    from brfgs.init.colmap_io import import_colmap

    try:
        import_colmap(root, root / "sparse" / "0", root / "images", None, overwrite=True)
    except UserError as exc:
        return str(exc)
    return None
