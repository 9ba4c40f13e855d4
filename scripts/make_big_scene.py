"""Upsample a simulated scene's cubes by an integer factor into a large synthetic scene on disk (to
measure the memory of training on 49 views of 1024² × 164-band cubes).

    python scripts/make_big_scene.py /tmp/scenes/ts128 /tmp/big1024 --factor 8

Every cube is resized bilinearly (OpenCV, band by band in groups) and written as an ENVI float32 BIP cube
(SPy's memory-mapped writer); the
camera's focal length, principal point and size scale with it (the poses, sun and split are kept), the
noise σ_b is carried as `dark_sigma` (the dark frames are not upsampled), truth/ is not copied (metrics are
then against the observed views). Writes one cube at a time: the peak memory is two upsampled cubes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

import spectral.io.envi as envi

from brfgs.data.scene import read_scene


def upsample(cube: np.ndarray, factor: int) -> np.ndarray:  # [H, W, B] -> [fH, fW, B]
    h, w, b = cube.shape
    out = np.empty((h * factor, w * factor, b), np.float32)
    for b0 in range(0, b, 4):
        part = np.ascontiguousarray(cube[..., b0:b0 + 4])
        res = cv2.resize(part, (w * factor, h * factor), interpolation=cv2.INTER_LINEAR)
        out[..., b0:b0 + part.shape[2]] = res.reshape(h * factor, w * factor, -1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--factor", type=int, default=8)
    a = ap.parse_args()
    sc = read_scene(a.src)
    meta = json.loads((a.src / "transforms.json").read_text())
    (a.dst / "images").mkdir(parents=True, exist_ok=False)
    for i, f in enumerate(sc.frames):
        big = upsample(np.asarray(sc.load_image(i), np.float32), a.factor)
        meta_hdr = {"lines": big.shape[0], "samples": big.shape[1], "bands": big.shape[2], "byte order": 0,
                    "wavelength": [float(w) for w in sc.wavelengths_nm], "wavelength units": "nm"}
        img = envi.create_image(str(a.dst / "images" / f"{f.name}.hdr"), meta_hdr, dtype=np.float32,
                                interleave="bip", ext=".img")
        img.open_memmap(writable=True)[:] = big                       # SPy's memory-mapped writer: fast
        del img
        meta["frames"][i]["file_path"] = f"images/{f.name}.hdr"
        print(f"{i + 1}/{len(sc.frames)} {f.name}", flush=True)
    for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        meta[k] = meta[k] * a.factor
    meta.pop("dark_frames", None)
    meta["dark_sigma"] = [float(s) for s in sc.dark_sigma]
    meta.pop("simulator", None)
    (a.dst / "transforms.json").write_text(json.dumps(meta, indent=1))
    print(f"wrote {a.dst}: {len(sc.frames)} cubes of {meta['w']}x{meta['h']}x{len(sc.wavelengths_nm)}")


if __name__ == "__main__":
    main()
