"""The sidecar surface: a tiny COLMAP project (the scene surface's 3 views as a COLMAP model whose first
image has the identity pose, COLMAP's own gauge, aligned by ``camera_positions_enu``) with a mutated
``spectral.json``, through ``brfgs import colmap`` and then ``brfgs inspect`` on what it wrote.

Values the import must refuse itself (NaN / Infinity / 1e400 anywhere, a ``frames`` or
``camera_positions_enu`` stem that names no image and no cube, an unaligned model) carry ``step="import"``;
other bad values may be refused by the scene reader when ``inspect`` reads the imported scene."""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import numpy as np

from fuzz.common import Mutation, Outcome, run_cli, snapshot
from fuzz.scene import make_base_scene

SIDECAR = "spectral.json"
STEMS = ("v0", "v1", "v2", "v3", "v4")
VIEWS = ((0.0, 0.0), (30.0, 0.0), (30.0, 180.0), (30.0, 90.0), (30.0, 270.0))   # pycolmap's Sim3 needs > 3


def make_base_project(root: Path) -> Path:
    """The scene surface's base scene as a COLMAP project: images/, calibration/, sparse/0, spectral.json."""
    from brfgs.data.cameras import GL_TO_CV, Intrinsics
    from brfgs.init.colmap_io import write_colmap_model

    scene = make_base_scene(root.parent / f"{root.name}_scene", VIEWS)
    meta = json.loads((scene / "transforms.json").read_text())
    root.mkdir(parents=True)
    for sub in ("images", "calibration"):
        shutil.copytree(scene / sub, root / sub)
    c2w = [np.asarray(f["transform_matrix"], float) for f in meta["frames"]]
    r0, c0, s = (c2w[0] @ GL_TO_CV)[:3, :3], c2w[0][:3, 3], 0.07      # COLMAP frame = frame 0's camera, scaled
    colmap = []
    for m in c2w:
        out = np.eye(4)
        out[:3, :3] = r0.T @ m[:3, :3]
        out[:3, 3] = s * r0.T @ (m[:3, 3] - c0)
        colmap.append(out)
    intr = Intrinsics(meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"], meta["w"], meta["h"])
    write_colmap_model(root / "sparse" / "0", intr, [f"{n}.png" for n in STEMS], np.stack(colmap), np.ones(5, bool),
                       np.zeros((0, 3)))
    side = {k: meta[k] for k in ("wavelengths_nm", "fwhm_nm", "sun_zenith_deg", "sun_azimuth_deg")}
    side["camera_positions_enu"] = {n: m[:3, 3].tolist() for n, m in zip(STEMS, c2w)}
    side["frames"] = {"v1": {"irradiance_scale": 1.05}}
    (root / SIDECAR).write_text(json.dumps(side, indent=1))
    shutil.rmtree(scene)
    return root


def _put(root: Path, side: dict, raw_value: str | None = None) -> None:
    text = json.dumps(side, indent=1)
    (root / SIDECAR).write_text(text.replace('"__V__"', raw_value) if raw_value is not None else text)


def _set(side: dict, path: tuple, value) -> None:
    obj = side
    for key in path[:-1]:
        obj = obj.setdefault(key, {})
    obj[path[-1]] = value


NUMBER_FIELDS = (("sun_zenith_deg",), ("sun_azimuth_deg",), ("wavelengths_nm", 2), ("fwhm_nm", 0),
                 ("camera_positions_enu", "v2", 1), ("frames", "v1", "irradiance_scale"),
                 ("frames", "v0", "sun_zenith_deg"), ("diffuse_fraction",), ("dark_sigma", 3),
                 ("origin", "altitude_m"), ("frames", "v2", "diffuse_fraction"))


def mut_sidecar_numbers(rng: random.Random, root: Path) -> Mutation:
    """NaN, ±Infinity, 1e400 or an integer beyond the float range anywhere: refused by the import,
    naming spectral.json and the field."""
    side = json.loads((root / SIDECAR).read_text())
    path = rng.choice(NUMBER_FIELDS)
    if path[0] == "origin":
        side["origin"] = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}
    if path[0] == "dark_sigma":
        side["dark_sigma"] = [0.01] * 4
    if path[-1] == "sun_zenith_deg":
        side["frames"]["v0"] = {"sun_zenith_deg": 40.0, "sun_azimuth_deg": 100.0}
    if isinstance(path[-1], int):
        obj = side
        for key in path[:-2]:
            obj = obj[key]
        obj[path[-2]][path[-1]] = "__V__"
    else:
        _set(side, path, "__V__")
    raw = rng.choice(["NaN", "Infinity", "-Infinity", "1e400", "-1e999", str(10 ** 400)])
    _put(root, side, raw)
    return Mutation(f"{SIDECAR} {'.'.join(map(str, path))} = {raw[:12]}", "invalid", names=SIDECAR, step="import")


def mut_sidecar_frames(rng: random.Random, root: Path) -> Mutation:
    """The per-image ``frames`` (and ``camera_positions_enu``) keyed by image stem."""
    side = json.loads((root / SIDECAR).read_text())
    kind = rng.choice(["typo", "typo_positions", "unknown_key", "not_object", "entry_not_object", "split_test",
                       "split_bad", "time", "time_no_origin", "irradiance_bad", "empty", "unicode_stem"])
    if kind in ("typo", "unicode_stem"):
        stem = rng.choice(["v9", "V1", "v1.png", "v1 ", "images/v1", ""]) if kind == "typo" else \
            rng.choice(["v\u0661", "\u0076\u0030\u0301", "v0\u0000"])
        side["frames"][stem] = {"irradiance_scale": 1.0}
        _put(root, side)
        return Mutation(f"frames.{stem!r}: no such image", "invalid", names=SIDECAR, step="import")
    if kind == "typo_positions":
        side["camera_positions_enu"]["v7"] = side["camera_positions_enu"].pop(rng.choice(STEMS))
        _put(root, side)
        return Mutation("camera_positions_enu names no image", "invalid", names=SIDECAR, step="import")
    if kind in ("unknown_key", "not_object", "entry_not_object"):
        if kind == "unknown_key":
            side["frames"]["v0"] = {"irradiance": 1.0}
        elif kind == "not_object":
            side["frames"] = rng.choice([[1, 2], "v0", 3])
        else:
            side["frames"]["v2"] = rng.choice([[1], "x", 1.0, None])
        _put(root, side)
        return Mutation(f"frames {kind}", "invalid", names=SIDECAR, step="import")
    if kind in ("split_test", "split_bad", "irradiance_bad"):
        value = {"split_test": ("split", "test"), "split_bad": ("split", rng.choice(["x", "TEST", 1])),
                 "irradiance_bad": ("irradiance_scale", rng.choice([0, -1, "1.0", True]))}[kind]
        side["frames"].setdefault("v2", {})[value[0]] = value[1]
        _put(root, side)
        return Mutation(f"frames.v2.{value[0]} = {value[1]!r}", "valid" if kind == "split_test" else "invalid")
    if kind in ("time", "time_no_origin"):
        if kind == "time":
            side["origin"] = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}
        side["frames"]["v0"] = {"time": "2024-06-21T10:32:05Z"}
        _put(root, side)
        return Mutation(f"frames.v0.time ({kind})", "valid" if kind == "time" else "invalid")
    side["frames"] = {}
    _put(root, side)
    return Mutation("frames empty", "valid")


def mut_sidecar_alignment(rng: random.Random, root: Path) -> Mutation:
    """The alignment of the COLMAP frame to ENU metres."""
    side = json.loads((root / SIDECAR).read_text())
    kind = rng.choice(["none", "scaled", "far", "digits", "shifted_down", "two_positions", "valid_subset"])
    pos = side["camera_positions_enu"]
    if kind == "none":                       # the first image has the identity pose: COLMAP's gauge, not ENU
        del side["camera_positions_enu"]
        _put(root, side)
        return Mutation("no alignment, identity gauge", "invalid", names="images.bin", step="import")
    if kind in ("scaled", "far"):
        f = rng.choice([1e4, 1e6]) if kind == "far" else rng.choice([2.0, 0.5])
        side["camera_positions_enu"] = {k: [f * c for c in v] for k, v in pos.items()}
        _put(root, side)
        return Mutation(f"camera positions x{f:g}", "invalid" if kind == "far" else "valid", names="images.bin",
                        step="import" if kind == "far" else None)
    if kind == "digits":
        pos["v1"] = [str(c) for c in pos["v1"]] if rng.random() < 0.5 else ["\u0661", 0, 50]
        _put(root, side)
        return Mutation("camera position as strings", "invalid", names=SIDECAR, step="import")
    if kind == "shifted_down":
        side["camera_positions_enu"] = {k: [v[0], v[1], v[2] - 100.0] for k, v in pos.items()}
        _put(root, side)
        return Mutation("camera positions below the ground", "invalid", names="images.bin", step="import")
    if kind == "two_positions":
        del pos["v2"], pos["v3"], pos["v4"]
        _put(root, side)
        return Mutation("two camera positions", "invalid", names=SIDECAR, step="import")
    _put(root, side)
    return Mutation("sidecar as made", "valid")


MUTATORS = (mut_sidecar_numbers, mut_sidecar_frames, mut_sidecar_alignment)


def run_case(seed: int, base: Path, work: Path, mutator=None) -> Outcome:
    """Copy the project ``base``, mutate its sidecar, run ``brfgs import colmap`` and, when it exits 0,
    ``brfgs inspect`` on the project; the project must stay as it was apart from the transforms.json the
    import writes (none when it refuses)."""
    rng = random.Random(seed)
    case = work / f"case{seed}"
    shutil.rmtree(case, ignore_errors=True)
    project = case / "project"
    shutil.copytree(base, project)
    mutation = (mutator or rng.choice(MUTATORS))(rng, project)
    before = snapshot(project, skip=("transforms.json",))
    rc, err, tb = run_cli(["import", "colmap", str(project)])
    changed = (rc != 0 and (project / "transforms.json").exists())
    if rc == 0 and tb is None and mutation.step != "import":  # else: accepted where it must be refused
        rc, err, tb = run_cli(["inspect", str(project), "--out", str(case / "inspect"), "--quiet"])
    outcome = Outcome(mutation, rc, err, tb, changed or snapshot(project, skip=("transforms.json",)) != before)
    shutil.rmtree(case, ignore_errors=True)
    return outcome
