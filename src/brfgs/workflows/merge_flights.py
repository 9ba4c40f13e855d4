"""``brfgs merge OUT A B ...``: one scene from several co-registered flights of a site.

Flights of one site at different hours or days (different suns) train one model when their frames
are in one scene, each under its own sun: the kernels then see the site under several suns. Each
frame of each flight becomes ``<flight>_<name>`` in OUT, with its pose, camera fields, time,
irradiance scale, its sun written out (the frame's own, else its flight's), its sky's diffuse fraction
written out likewise when a flight gives one and they differ (else each frame keeps the clear-sky
default of its sun), and its flight's split
(read as training reads it, ``split_seed``), so that every flight keeps its own held-out views. The
cubes, the dark frames of the first flight and the truth of simulated flights are hard-linked (copied
across file systems).

The flights must agree on what makes one scene: wavelengths and band widths, the camera
(``camera_model``, intrinsics, image size) and the georeference (both without ``origin``, or the same
origin within 0.01 m); anything else is refused in one line naming the flight's transforms.json.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from brfgs.data import atomic, read_scene
from brfgs.data.georef import check_same_origin
from brfgs.data.validation import read_json_file
from brfgs.errors import UserError

__all__ = ["merge_flights", "SAME_FIELDS"]

SAME_FIELDS = ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2", "crs")
TRUTH_MAPS = ("depth", "materials", "sun_visibility")   # truth/<map>/<name>.npy


def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _link_stem(folder: Path, stem: str, out_folder: Path, new_stem: str) -> int:
    """Link every ``folder/stem.*`` (an ENVI header and its data, a TIFF, an .npy) as ``new_stem.*``."""
    n = 0
    for p in sorted(folder.glob(f"{stem}.*")):
        if p.is_file() and p.name[len(stem)] == ".":
            _link(p, out_folder / (new_stem + p.name[len(stem):]))
            n += 1
    return n


def _check_same(first: dict, meta: dict, tf: Path, wl0: np.ndarray, wl: np.ndarray) -> None:
    if wl.shape != wl0.shape or not np.allclose(wl, wl0, rtol=0, atol=1e-6):
        raise UserError("the flights' wavelengths differ", file=tf, field="wavelengths_nm")
    fw0, fw = first.get("fwhm_nm"), meta.get("fwhm_nm")
    if (fw0 is None) != (fw is None) or (fw0 is not None and not np.allclose(fw0, fw, rtol=0, atol=1e-6)):
        raise UserError("the flights' band widths differ", file=tf, field="fwhm_nm")
    for key in SAME_FIELDS:
        if first.get(key) != meta.get(key):
            raise UserError(f"the flights' {key} differ ({first.get(key)!r} vs {meta.get(key)!r}): one scene has "
                            "one camera", file=tf, field=key)
    check_same_origin(first.get("origin"), meta.get("origin"), tf)


def _flight_names(roots: list[Path]) -> list[str]:
    names = [r.resolve().name for r in roots]
    return names if len(set(names)) == len(names) else [f"f{k}_{n}" for k, n in enumerate(names)]


def merge_flights(out_dir: str | Path, scene_paths: list, split_seed: int = 0) -> dict:
    """Write the merged scene into ``out_dir`` (new or empty); returns its transforms.json dict."""
    roots = [Path(p) for p in scene_paths]
    if len(roots) < 2:
        raise UserError("give at least two flights to merge", field="SCENES")
    if len({r.resolve() for r in roots}) != len(roots):
        raise UserError("a flight is given twice", field="SCENES")
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError("the output folder exists and is not empty: choose a new one", file=out)
    if any(out.resolve() == r.resolve() or r.resolve() in out.resolve().parents for r in roots):
        raise UserError("the output folder is inside a flight: choose one outside", file=out)
    metas = [read_json_file(r / "transforms.json") for r in roots]
    scenes = [read_scene(r, split_seed=split_seed) for r in roots]
    for r, meta, sc in zip(roots[1:], metas[1:], scenes[1:]):
        _check_same(metas[0], meta, r / "transforms.json", scenes[0].wavelengths_nm, sc.wavelengths_nm)
    given = any(sc.diffuse_fraction_source != "clear-sky default" or any(f.diffuse_fraction is not None
                                                                         for f in sc.frames) for sc in scenes)
    skies = [sc.frame_diffuse_fraction(i) for sc in scenes for i in range(len(sc.frames))] if given else []
    per_frame_sky = given and not all(np.allclose(f, skies[0], rtol=0, atol=1e-6) for f in skies)  # else each sun's default
    merged = {k: v for k, v in metas[0].items() if k not in ("frames", "sun_zenith_deg", "sun_azimuth_deg",
                                                                "dark_frames", "flights")}
    merged["flights"] = []
    frames = []
    for name, root, meta, sc in zip(_flight_names(roots), roots, metas, scenes):
        merged["flights"].append({"name": name, "source": str(root.resolve()), "frames": len(sc.frames)})
        for i, (fm, f) in enumerate(zip(meta["frames"], sc.frames)):
            frames.append(_merged_frame(fm, f, root, out, name))
            if per_frame_sky:   # flights under other skies: each frame keeps its own
                frames[-1]["diffuse_fraction"] = [round(float(v), 6) for v in sc.frame_diffuse_fraction(i)]
    merged["frames"] = frames
    darks = metas[0].get("dark_frames") or []
    for rel in darks:
        src = roots[0] / rel
        _link_stem(src.parent, src.stem, (out / rel).parent, src.stem)
    if darks:
        merged["dark_frames"] = darks
    _merge_truth(roots, out)
    atomic.write_json(out / "transforms.json", merged)
    return merged


def _merged_frame(fm: dict, f, root: Path, out: Path, flight: str) -> dict:
    """A frame of ``flight`` for the merged scene: its files linked under a new name, its sun (as the scene
    reader resolved it: its own, its time's, or its flight's) and split written out."""
    src = root / fm["file_path"]
    new = f"{flight}_{f.name}"
    rel = Path(fm["file_path"]).parent / (new + src.suffix)
    if _link_stem(src.parent, src.stem, (out / rel).parent, new) == 0:
        raise UserError("the frame's image is missing", file=root / "transforms.json", field=fm["file_path"])
    return {**fm, "file_path": rel.as_posix(), "sun_zenith_deg": f.sun_zenith_deg, "sun_azimuth_deg": f.sun_azimuth_deg,
            "split": "test" if f.split == "test" else "train"}


def _merge_truth(roots: list[Path], out: Path) -> None:
    """Link each flight's truth (clean cubes, maps) under the merged names, when every flight has truth
    with the same materials; the first flight's sigma.json, materials.json and scene.json."""
    truths = [r / "truth" for r in roots]
    if not all(t.is_dir() for t in truths):
        return
    tables = [(t / "materials.json").read_text() if (t / "materials.json").is_file() else None for t in truths]
    if len(set(tables)) != 1:
        return
    for name, t in zip(_flight_names(roots), truths):
        for sub in ("images",) + TRUTH_MAPS:
            folder = t / sub
            if folder.is_dir():
                for p in sorted(folder.iterdir()):
                    if p.is_file():
                        _link(p, out / "truth" / sub / f"{name}_{p.name}")
    for extra in ("materials.json", "sigma.json", "scene.json"):
        if (truths[0] / extra).is_file():
            _link(truths[0] / extra, out / "truth" / extra)
