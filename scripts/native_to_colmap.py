"""Rewrite a simulated scene as a user's COLMAP project, to test `brfgs import colmap` end to end.

    brfgs init SCENE INIT --poses known            # writes INIT/sparse/0 (ENU metres)
    python scripts/native_to_colmap.py SCENE INIT/sparse/0 PROJECT [--seed 0]
    brfgs import colmap PROJECT                    # -> PROJECT/transforms.json

PROJECT gets: images/<name>.tif (band-first, LZW-compressed TIFF cubes), sparse/0 (the COLMAP model
moved into an arbitrary frame by a random similarity, as SfM leaves it), spectral.json (wavelengths,
fwhm, origin, dark frames, per-image time / sun / irradiance_scale / split, and GPS-like
camera_positions_enu of every image for the Sim3 alignment), and copies of calibration/ and truth/.
"""

from __future__ import annotations

import zlib  # noqa: F401  (before pycolmap)
import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pycolmap
import tifffile

from brfgs.data.cube_io import read_block_averaged
from brfgs.data.scene import read_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path)
    ap.add_argument("sparse", type=Path)
    ap.add_argument("project", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    sc = read_scene(a.scene)
    meta = json.loads((a.scene / "transforms.json").read_text())
    (a.project / "images").mkdir(parents=True, exist_ok=False)
    for i, f in enumerate(sc.frames):
        src = sc._sources[i]                                                         # as stored: no scale, no resampling
        cube = np.asarray(read_block_averaged(src, sc.band_indices, None, 1, (-np.inf, np.inf), f.name))
        tifffile.imwrite(a.project / "images" / f"{f.name}.tif", np.moveaxis(cube, -1, 0), photometric="minisblack",
                         planarconfig="separate", compression="lzw")
    for sub in ("calibration", "truth"):
        if (a.scene / sub).is_dir():
            shutil.copytree(a.scene / sub, a.project / sub)
    rec = pycolmap.Reconstruction(str(a.sparse))
    if meta.get("camera_model") == "OPENCV":                  # the lens of the flight, as COLMAP would model it
        cam = pycolmap.Camera.create_from_model_name(1, "OPENCV", float(meta["fl_x"]), int(meta["w"]), int(meta["h"]))
        cam.params = np.array([meta[k] for k in ("fl_x", "fl_y", "cx", "cy", "k1", "k2", "p1", "p2")], float)
        rec.cameras[1] = cam
    rng = np.random.default_rng(a.seed)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    rot = pycolmap.Rotation3d(np.array([q[1], q[2], q[3], q[0]]))                   # xyzw
    rec.transform(pycolmap.Sim3d(float(rng.uniform(0.02, 0.2)), rot, rng.normal(size=3) * 5))
    (a.project / "sparse" / "0").mkdir(parents=True)
    rec.write(str(a.project / "sparse" / "0"))
    side = {k: meta[k] for k in ("wavelengths_nm", "fwhm_nm", "origin", "dark_frames", "dark_sigma") if k in meta}
    if not any("time" in fr or "sun_zenith_deg" in fr for fr in meta["frames"]):
        side.update({k: meta[k] for k in ("sun_zenith_deg", "sun_azimuth_deg")})
    keys = ("time", "sun_zenith_deg", "sun_azimuth_deg", "irradiance_scale", "split")
    side["frames"] = {f.name: {k: fr[k] for k in keys if k in fr} for f, fr in zip(sc.frames, meta["frames"])}
    side["camera_positions_enu"] = {f.name: f.c2w[:3, 3].tolist() for f in sc.frames}
    (a.project / "spectral.json").write_text(json.dumps(side, indent=1))
    print(f"wrote {a.project}: {len(sc.frames)} LZW TIFF cubes, sparse/0 in a random frame, spectral.json")


if __name__ == "__main__":
    main()
