"""``brfgs merge OUT A B ...``: one scene from several co-registered flights of a site.

Flights of one site at different hours or days (different suns) train one model when their frames
are in one scene, each under its own sun: the kernels then see the site under several suns. Each
flight gets a label: its folder's name with every character other than a letter, a digit, '.' or '-'
replaced by '-', at most 40 characters (``f<k>-<label>`` for all flights when two labels would be
equal), so that a label never holds '_'. Each frame of each flight becomes ``<label>_<name>`` in OUT,
its cube ``images/<label>_<name>.<ext>`` (with its ENVI data file), with its pose, camera fields, time,
irradiance scale, its sun written out (the frame's own, else its flight's), its sky's diffuse fraction
written out likewise when a flight gives one and they differ (else each frame keeps the clear-sky
default of its sun), and its flight's split (read as training reads it, ``split_seed``), so that every
flight keeps its own held-out views. The dark frames of the first flight become
``calibration/dark_<k>.<ext>``; the truth of simulated flights (when every flight has truth with the same
materials table) ``truth/<folder>/<label>_<file>``, found by the merged frame names as for any scene,
with the first flight's ``materials.json``, ``sigma.json`` and ``scene.json``. No two files can get one
name; a name longer than a file system takes is refused.

Files are hard-linked (copied where a link cannot be made), only regular files that lie, links
followed, inside their own flight folder; the scene is built beside OUT and renamed into place, so a
failure leaves no OUT (brfgs.workflows.merge_files). The flights must agree on what makes one scene:
wavelengths and band widths, the camera (``camera_model``, intrinsics, image size) and the georeference
(both without ``origin``, or the same origin within 0.01 m); anything else is refused in one line naming
the flight's transforms.json.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

from brfgs.data import atomic, read_scene
from brfgs.data import validation as V
from brfgs.data.cube_io import envi_image_path
from brfgs.data.georef import check_same_origin
from brfgs.errors import STORAGE_ERRNOS, UserError
from brfgs.workflows import merge_files as files

__all__ = ["merge_flights", "flight_labels", "SAME_FIELDS"]

SAME_FIELDS = ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2", "crs")
TRUTH_MAPS = ("depth", "materials", "sun_visibility")   # truth/<map>/<name>.npy
TRUTH_EXTRAS = ("materials.json", "sigma.json", "scene.json")
LABEL_CHARS = 40


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


def flight_labels(folder_names: list[str]) -> list[str]:
    """Each flight's label (see the module docstring): never empty, never holding '_', all different."""
    def clean(name: str) -> str:
        s = "".join(c if c.isalnum() and c != "_" or c in ".-" else "-" for c in name)
        return s[:LABEL_CHARS].strip(".-") or "flight"

    labels = [clean(n) for n in folder_names]
    return labels if len(set(labels)) == len(labels) else [f"f{k}-{s}" for k, s in enumerate(labels)]


def merge_flights(out_dir: str | Path, scene_paths: list, split_seed: int = 0) -> dict:
    """Write the merged scene into ``out_dir`` (new or empty); returns its transforms.json dict."""
    try:
        return _merge(Path(out_dir), [Path(p) for p in scene_paths], split_seed)
    except OSError as exc:        # a storage error goes up (exit status 3); any other is the user's path
        if exc.errno in STORAGE_ERRNOS:
            raise
        raise files.user_error(exc, "merge", exc.filename or out_dir) from None


def _flight(root: Path, split_seed: int):
    """(real path of the flight folder, its transforms.json dict, its Scene); UserError for a flight that is
    missing, not a folder, a loop of links, or not a valid scene."""
    real, st = files.real_path(root, "flight folder")
    if not stat.S_ISDIR(st.st_mode):
        raise UserError("not a folder: a flight is a scene folder with transforms.json", file=root)
    tf, _ = files.regular_inside(root / "transforms.json", real, "transforms.json")
    sc = read_scene(root, split_seed=split_seed)
    return real, V.read_json_file(tf), sc


def _merge(out: Path, roots: list[Path], split_seed: int) -> dict:
    if len(roots) < 2:
        raise UserError("give at least two flights to merge", field="SCENES")
    files.check_output(out)
    reals = [files.real_path(r, "flight folder")[0] for r in roots]
    if len(set(reals)) != len(reals):
        raise UserError("a flight is given twice", field="SCENES")
    out_real = Path(os.path.realpath(out))
    if any(out_real == r or r in out_real.parents for r in reals):
        raise UserError("the output folder is inside a flight: choose one outside", file=out)
    flights = [_flight(r, split_seed) for r in roots]
    metas, scenes = [f[1] for f in flights], [f[2] for f in flights]
    for r, meta, sc in zip(roots[1:], metas[1:], scenes[1:]):
        _check_same(metas[0], meta, r / "transforms.json", scenes[0].wavelengths_nm, sc.wavelengths_nm)
    given = any(sc.diffuse_fraction_source != "clear-sky default" or any(f.diffuse_fraction is not None
                                                                         for f in sc.frames) for sc in scenes)
    skies = [sc.frame_diffuse_fraction(i) for sc in scenes for i in range(len(sc.frames))] if given else []
    per_frame_sky = given and not all(np.allclose(f, skies[0], rtol=0, atol=1e-6) for f in skies)  # else each sun's default
    merged = {k: v for k, v in metas[0].items() if k not in ("frames", "sun_zenith_deg", "sun_azimuth_deg",
                                                                "dark_frames", "flights")}
    labels = flight_labels([r.name for r in reals])
    plan = files.Placement()
    merged["flights"], frames = [], []
    for label, root, real, meta, sc in zip(labels, roots, reals, metas, scenes):
        source = os.fsencode(real).decode("utf-8", "replace")     # printable whatever bytes the name holds
        merged["flights"].append({"name": label, "source": source, "frames": len(sc.frames)})
        for i, (fm, f) in enumerate(zip(meta["frames"], sc.frames)):
            frames.append(_merged_frame(fm, f, (root, real, i), label, plan))
            if per_frame_sky:   # flights under other skies: each frame keeps its own
                frames[-1]["diffuse_fraction"] = [round(float(v), 6) for v in sc.frame_diffuse_fraction(i)]
    merged["frames"] = frames
    if scenes[0].dark_sigma_source == "dark_frames":
        merged["dark_frames"] = _plan_darks(roots[0], reals[0], metas[0], plan)
    _plan_truth(roots, reals, labels, plan)
    with files.staged_folder(out) as stage:
        plan.write(stage)
        atomic.write_json(stage / "transforms.json", merged)
    return merged


def _plan_cube(shown: Path, real_root: Path, rel_stem: str, what: str, plan: files.Placement,
               field: str | None = None) -> str:
    """Plan the cube ``shown`` (and, for an ENVI header, its data file, as the reader finds it) as
    ``rel_stem`` + its suffix in OUT; returns the cube's path relative to OUT."""
    src, st = files.regular_inside(shown, real_root, what)
    folder, stem = rel_stem.rsplit("/", 1)
    name = files.check_name(stem + src.suffix, shown, field)
    plan.add(f"{folder}/{name}", shown, src, st)
    if src.suffix.lower() == ".hdr":
        data = envi_image_path(src)
        if data is None:
            raise UserError(f"{what}: ENVI data file (.img) next to the header not found", file=shown)
        data_real, data_st = files.regular_inside(data, real_root, f"ENVI data file of the {what}")
        data_name = files.check_name(stem + data.name[len(src.stem):], data, field)
        plan.add(f"{folder}/{data_name}", data, data_real, data_st)
    return f"{folder}/{name}"


def _merged_frame(fm: dict, f, where: tuple[Path, Path, int], label: str, plan: files.Placement) -> dict:
    """A frame of the flight ``where`` = (folder, real folder, frame index) for the merged scene: its files
    planned as ``images/<label>_<name>.*``, its sun (as the scene reader resolved it: its own, its time's,
    or its flight's) and split written out."""
    root, real, i = where
    field = f"frames[{i}].file_path"
    rel = _plan_cube(root / fm["file_path"], real, f"images/{label}_{f.name}", f"cube of frame '{f.name}'",
                     plan, field)
    V.path_text(rel, root / "transforms.json", field)
    return {**fm, "file_path": rel, "sun_zenith_deg": f.sun_zenith_deg, "sun_azimuth_deg": f.sun_azimuth_deg,
            "split": "test" if f.split == "test" else "train"}


def _plan_darks(root: Path, real: Path, meta: dict, plan: files.Placement) -> list[str]:
    """Plan the dark frames the reader read from the first flight (``dark_frames``, else
    ``calibration/dark_*.hdr``) as ``calibration/dark_<k>.*``; returns their paths relative to OUT."""
    tf = root / "transforms.json"
    listed = meta.get("dark_frames")
    if listed is not None:
        shown = [root / V.path_text(p, tf, f"dark_frames[{i}]") for i, p in enumerate(listed)]
    else:
        cal = files.folder_inside(root / "calibration", real, "calibration folder")
        shown = sorted(root / "calibration" / e.name for e in os.scandir(cal)
                       if e.name.startswith("dark_") and e.name.endswith(".hdr"))
    return [_plan_cube(p, real, f"calibration/dark_{k:02d}", f"dark frame {p.name}", plan)
            for k, p in enumerate(shown)]


def _plan_truth(roots: list[Path], reals: list[Path], labels: list[str], plan: files.Placement) -> None:
    """Plan each flight's truth (clean cubes, maps) under the merged names, when every flight has truth
    with the same materials; the first flight's sigma.json, materials.json and scene.json."""
    truths = [r / "truth" for r in roots]
    if not all(t.is_dir() for t in truths):
        return
    for t, real in zip(truths, reals):
        files.folder_inside(t, real, "truth folder")
    tables = [_small_file(t / "materials.json", real) for t, real in zip(truths, reals)]
    if len(set(tables)) != 1:
        return
    for label, t, real in zip(labels, truths, reals):
        for sub in ("images",) + TRUTH_MAPS:
            folder = t / sub
            if not os.path.lexists(folder):
                continue
            files.folder_inside(folder, real, f"truth/{sub} folder")
            for name in sorted(os.listdir(folder)):
                p = folder / name
                src, st = files.regular_inside(p, real, f"truth file {sub}/{name}")
                plan.add(f"truth/{sub}/{files.check_name(f'{label}_{name}', p)}", p, src, st)
    for extra in TRUTH_EXTRAS:
        p = truths[0] / extra
        if os.path.lexists(p):
            src, st = files.regular_inside(p, reals[0], f"truth file {extra}")
            plan.add(f"truth/{extra}", p, src, st)


def _small_file(path: Path, real_root: Path) -> bytes | None:
    """The bytes of a flight's small JSON file (a regular file inside the flight), or None when absent."""
    if not os.path.lexists(path):
        return None
    src, st = files.regular_inside(path, real_root, f"truth file {path.name}")
    if st.st_size > V.MAX_JSON_BYTES:
        raise UserError(f"{st.st_size} bytes, more than the {V.MAX_JSON_BYTES} bytes it may have", file=path)
    return src.read_bytes()
