#!/usr/bin/env python3
"""Fuzz ``brfgs inspect`` with mutated scenes: every case must end in exit 0 on valid input or in
exit 2 with one line naming a file, never a traceback, and the scene folder must stay unchanged.

Each case copies a tiny scene (3 views, 4 bands, 2 dark frames), applies one mutation whose
expected outcome is known by construction ("valid", "invalid" or "either"), runs
``brfgs inspect`` in-process and checks the outcome. ``tests/test_fuzz_inputs.py`` drives the same
cases with hypothesis; the long run's counts are in docs/reliability.md.

    python3 scripts/fuzz_inputs.py --cases 5000 --seed 0 [--work DIR] [--show-failures 20]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import random
import shutil
import sys
import tempfile
import time
import traceback
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

W, H, BANDS = 8, 6, 4
HEADER_NUMBERS = ("lines", "samples", "bands", "header offset", "data type", "byte order")


def make_base_scene(root: Path) -> Path:
    """A valid tiny scene in the docs/data-format.md layout (ENVI cubes, two dark frames)."""
    from brfgs.data.cameras import Intrinsics, pose_from_view_angles
    from brfgs.data.cube_io import write_envi

    rng = np.random.default_rng(0)
    wl = np.linspace(500.0, 850.0, BANDS)
    intr = Intrinsics.from_fov(35.0, W, H)
    frames = []
    for k, (zen, az) in enumerate([(0.0, 0.0), (30.0, 0.0), (30.0, 180.0)]):
        write_envi(root / f"images/v{k}.hdr", (0.05 + 0.4 * rng.random((H, W, BANDS))).astype(np.float32), wl,
                   np.full(BANDS, 4.0))
        frames.append({"file_path": f"images/v{k}.hdr", "transform_matrix": pose_from_view_angles(zen, az, 50.0).tolist(),
                       "view_zenith_deg": zen, "view_azimuth_deg": az})
    for k in range(2):
        write_envi(root / f"calibration/dark_{k:02d}.hdr", rng.normal(0, 0.01, (H, W, BANDS)).astype(np.float32), wl)
    meta = {"camera_model": "PINHOLE", "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": W,
            "h": H, "wavelengths_nm": wl.tolist(), "fwhm_nm": [4.0] * BANDS, "sun_zenith_deg": 35.0,
            "sun_azimuth_deg": 150.0, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))
    return root


# ------------------------------------------------------------------------------------------ mutations
@dataclass
class Mutation:
    what: str
    expected: str  # "valid" | "invalid" | "either"


def _json(root: Path) -> dict:
    return json.loads((root / "transforms.json").read_text())


def _put_json(root: Path, meta, raw: str | None = None) -> None:
    (root / "transforms.json").write_text(raw if raw is not None else json.dumps(meta, indent=1))


def _headers(root: Path) -> list[Path]:
    return sorted(root.glob("images/*.hdr")) + sorted(root.glob("calibration/*.hdr"))


def _set_header(path: Path, key: str, value: str | None) -> None:
    lines = [ln for ln in path.read_text().splitlines() if not ln.split("=")[0].strip().lower() == key]
    if value is not None:
        lines.insert(1, f"{key} = {value}")
    path.write_text("\n".join(lines) + "\n")


def mut_transforms_number(rng: random.Random, root: Path) -> Mutation:
    meta = _json(root)
    key = rng.choice(["w", "h", "fl_x", "fl_y", "cx", "cy", "sun_zenith_deg", "sun_azimuth_deg"])
    bad = rng.choice(["10**400", "digits", "nan", "inf", "-1", "string", "null", "list", "deep", "1e400", "bool"])
    raw_value = {"10**400": str(10**400), "digits": "9" * 5000, "nan": "NaN", "inf": "Infinity", "-1": "-1",
                 "string": '"12"', "null": "null", "list": "[1, 2]", "deep": "[" * 5000 + "]" * 5000,
                 "1e400": "1e400", "bool": "true"}[bad]
    if key in ("sun_azimuth_deg", "cx", "cy") and bad == "-1":
        return Mutation(f"transforms.json {key} = -1", "either")  # azimuths wrap; a principal point may lie outside
    meta[key] = "__VALUE__"
    _put_json(root, None, json.dumps(meta, indent=1).replace('"__VALUE__"', raw_value))
    return Mutation(f"transforms.json {key} = {bad}", "invalid")


def mut_transforms_structure(rng: random.Random, root: Path) -> Mutation:
    meta = _json(root)
    kind = rng.choice(["drop_key", "truncate", "not_object", "deep_doc", "nul_path", "surrogate_path", "dotdot_path",
                       "abs_path", "wl_nan", "wl_negative", "frames_empty", "bad_matrix", "valid_reformat"])
    if kind == "drop_key":
        key = rng.choice(["w", "h", "fl_x", "wavelengths_nm", "frames", "sun_zenith_deg"])
        del meta[key]
        _put_json(root, meta)
        return Mutation(f"transforms.json without {key}", "invalid")
    if kind == "truncate":
        text = (root / "transforms.json").read_text()
        _put_json(root, None, text[: rng.randrange(1, len(text) - 2)])
        return Mutation("transforms.json truncated", "invalid")
    if kind == "not_object":
        _put_json(root, None, rng.choice(["[]", "42", '"scene"', "null"]))
        return Mutation("transforms.json not an object", "invalid")
    if kind == "deep_doc":
        _put_json(root, None, "{" + '"a": {' * 5000 + "}" * 5001)
        return Mutation("transforms.json nested 5000 deep", "invalid")
    if kind in ("nul_path", "surrogate_path", "dotdot_path", "abs_path"):
        value = {"nul_path": "images/v0\u0000.hdr", "surrogate_path": "images/v0\ud800.hdr",
                 "dotdot_path": "../outside.hdr", "abs_path": "/etc/passwd"}[kind]
        meta["frames"][rng.randrange(3)]["file_path"] = value
        _put_json(root, meta)
        return Mutation(f"file_path {kind}", "invalid")
    if kind in ("wl_nan", "wl_negative"):
        raw = json.dumps(meta, indent=1)
        meta["wavelengths_nm"][rng.randrange(BANDS)] = "__V__"
        raw = json.dumps(meta, indent=1).replace('"__V__"', "NaN" if kind == "wl_nan" else "-500.0")
        _put_json(root, None, raw)
        return Mutation(f"wavelengths_nm {kind}", "invalid")
    if kind == "frames_empty":
        meta["frames"] = []
        _put_json(root, meta)
        return Mutation("no frames", "invalid")
    if kind == "bad_matrix":
        meta["frames"][rng.randrange(3)]["transform_matrix"] = rng.choice([[[1, 0], [0, 1]], "eye", [[0] * 4] * 4])
        _put_json(root, meta)
        return Mutation("transform_matrix malformed", "invalid")
    _put_json(root, None, json.dumps(meta, indent=rng.choice([None, 0, 4]), sort_keys=rng.random() < 0.5))
    return Mutation("transforms.json reformatted", "valid")


def mut_header(rng: random.Random, root: Path) -> Mutation:
    hdr = rng.choice(_headers(root))
    kind = rng.choice(["number", "interleave", "byte_order", "offset", "data_type", "drop", "spaces", "case"])
    where = f"{hdr.parent.name}/{hdr.name}"
    if kind == "number":
        key = rng.choice(["lines", "samples", "bands"])
        value = rng.choice(["16.0", "abc", "1e1", "{16}", "-4", "0", "", "99999999999999999999"])
        _set_header(hdr, key, value)
        return Mutation(f"{where} {key} = {value!r}", "invalid")
    if kind == "interleave":
        value = rng.choice(["xyz", "", "bsq", "bil", "BIP", "b i p"])
        _set_header(hdr, "interleave", value)
        expected = {"BIP": "valid", "bsq": "either", "bil": "either"}.get(value, "invalid")
        return Mutation(f"{where} interleave = {value!r}", expected)
    if kind == "byte_order":
        value = rng.choice(["1", "2", "x", "0"])
        _set_header(hdr, "byte order", value)
        # big-endian reading of little-endian reflectance gives tiny values: wrong, but not detectably so
        return Mutation(f"{where} byte order = {value}", {"0": "valid", "1": "either"}.get(value, "invalid"))
    if kind == "offset":
        value = rng.choice(["-4", "x", "16", "1e3"])
        _set_header(hdr, "header offset", value)
        return Mutation(f"{where} header offset = {value}", "invalid")
    if kind == "data_type":
        value = rng.choice(["5", "99", "x", "4"])
        _set_header(hdr, "data type", value)
        return Mutation(f"{where} data type = {value}", "valid" if value == "4" else "invalid")
    if kind == "drop":
        key = rng.choice(["lines", "samples", "bands", "data type", "interleave"])
        _set_header(hdr, key, None)
        return Mutation(f"{where} without {key}", "invalid")
    if kind == "spaces":
        text = hdr.read_text().replace(" = ", "   =   ")
        hdr.write_text(text)
        return Mutation(f"{where} extra spaces", "valid")
    hdr.write_text(hdr.read_text().replace("interleave = bip", "INTERLEAVE = bip"))
    return Mutation(f"{where} upper-case key", "valid")


def mut_data(rng: random.Random, root: Path) -> Mutation:
    hdr = rng.choice(_headers(root))
    img = hdr.with_suffix(".img")
    where = f"{hdr.parent.name}/{img.name}"
    kind = rng.choice(["truncate", "extend", "empty", "nan_pixels", "flip_bytes", "zero_lines"])
    data = img.read_bytes()
    if kind == "truncate":
        img.write_bytes(data[: rng.randrange(0, len(data) - 1)])
        return Mutation(f"{where} truncated", "invalid")
    if kind == "extend":
        img.write_bytes(data + bytes(rng.randrange(1, 64)))
        return Mutation(f"{where} longer than its header says", "invalid")
    if kind == "empty":
        img.write_bytes(b"")
        return Mutation(f"{where} empty", "invalid")
    if kind == "zero_lines":
        _set_header(hdr, "lines", "0")
        img.write_bytes(b"")
        return Mutation(f"{hdr.name} with 0 lines", "invalid")
    arr = np.frombuffer(data, "<f4").copy()
    if kind == "nan_pixels":
        arr[rng.randrange(arr.size)] = np.nan
        img.write_bytes(arr.tobytes())
        return Mutation(f"{where} one NaN value", "valid")
    img.write_bytes(arr.byteswap().tobytes())
    return Mutation(f"{where} byte-swapped data", "either")


def mut_links(rng: random.Random, root: Path) -> Mutation:
    outside = root.parent / "outside"
    outside.mkdir(exist_ok=True)
    kind = rng.choice(["img", "hdr_dark", "transforms", "calibration"])
    if kind == "img":
        img = root / "images/v1.img"
        shutil.copy(img, outside / "v1.img")
        img.unlink()
        img.symlink_to(outside / "v1.img")
    elif kind == "hdr_dark":
        for name in ("dark_00.hdr", "dark_00.img"):
            p = root / "calibration" / name
            shutil.copy(p, outside / name)
            p.unlink()
            p.symlink_to(outside / name)
    elif kind == "transforms":
        shutil.copy(root / "transforms.json", outside / "transforms.json")
        (root / "transforms.json").unlink()
        (root / "transforms.json").symlink_to(outside / "transforms.json")
    else:
        shutil.move(str(root / "calibration"), str(outside / "calibration"))
        (root / "calibration").symlink_to(outside / "calibration")
    return Mutation(f"link outside the scene: {kind}", "invalid")


# ------------------------------------------------------------------------------------------ one case
ORIGIN = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}
BAD_NUMBERS = {"nan": "NaN", "inf": "Infinity", "1e308": "1e308", "-1e308": "-1e308", "2**63": str(2**63),
               "string": '"12"', "list": "[1, 2]", "bool": "true", "null": "null"}


def _with_raw(root: Path, meta: dict, value: str) -> None:
    """transforms.json with the placeholder "__V__" of ``meta`` replaced by the raw JSON ``value``."""
    _put_json(root, None, json.dumps(meta, indent=1).replace('"__V__"', value))


def mut_flight_fields(rng: random.Random, root: Path) -> Mutation:
    """The fields of a real flight: a frame's time, own sun, irradiance scale and camera, the origin,
    the CRS; out-of-range, malformed or mistyped values must be refused, well-formed ones accepted."""
    meta, k = _json(root), rng.randrange(3)
    fr = meta["frames"][k]
    kind = rng.choice(["time", "origin", "irradiance", "frame_sun", "frame_camera", "crs"])
    if kind == "time":
        meta["origin"] = dict(ORIGIN)
        value = rng.choice(["9999-12-31T12:00:00Z", "0001-01-01T00:00:00Z", "1677-09-21T00:13:00Z",
                            "2262-04-12T00:00:00Z", "2024-06-21T10:00:00", "2024-13-40T00:00:00Z",
                            "2024-06-21T10:00:00+25:00", "yesterday", 12, None, "2024-06-21T10:32:05Z",
                            "2024-06-21T12:32:05+02:00"])
        fr["time"] = value
        if value is None:
            del fr["time"]
        _put_json(root, meta)
        ok = value in (None, "2024-06-21T10:32:05Z", "2024-06-21T12:32:05+02:00")
        return Mutation(f"frame time {value!r}", "valid" if ok else "invalid")
    if kind == "origin":
        key = rng.choice(["latitude_deg", "longitude_deg", "altitude_m"])
        meta["origin"] = dict(ORIGIN)
        bad = rng.choice(list(BAD_NUMBERS) + ["out_of_range", "valid"])
        if bad == "valid":
            _put_json(root, meta)
            return Mutation("origin valid", "valid")
        meta["origin"][key] = "__V__"
        raw = {"latitude_deg": "91.5", "longitude_deg": "-181", "altitude_m": "1e9"}[key] if bad == "out_of_range" \
            else BAD_NUMBERS[bad]
        _with_raw(root, meta, raw)
        return Mutation(f"origin {key} = {bad}", "invalid")
    if kind in ("irradiance", "frame_sun"):
        key = "irradiance_scale" if kind == "irradiance" else rng.choice(["sun_zenith_deg", "sun_azimuth_deg"])
        if kind == "frame_sun":
            fr["sun_zenith_deg"], fr["sun_azimuth_deg"] = 40.0, 120.0
        bad = rng.choice(list(BAD_NUMBERS) + ["zero", "negative", "out_of_range", "valid"])
        raw = {"zero": "0", "negative": "-0.5", "out_of_range": "1e6", "valid": "1.1" if kind == "irradiance" else "45.0"}
        fr[key] = "__V__"
        _with_raw(root, meta, raw.get(bad) or BAD_NUMBERS[bad])
        if bad == "valid" or (kind == "frame_sun" and bad in ("zero", "negative") and key == "sun_azimuth_deg") or \
                (kind == "frame_sun" and bad == "zero") or (kind == "irradiance" and bad == "null"):  # null: not given
            return Mutation(f"frame {key} = {bad}", "valid")
        return Mutation(f"frame {key} = {bad}", "invalid")
    if kind == "frame_camera":
        key = rng.choice(["fl_x", "fl_y", "cx", "w", "h", "k1"])
        fr.update({"camera_model": "OPENCV", "fl_x": meta["fl_x"], "fl_y": meta["fl_y"], "cx": meta["cx"],
                   "cy": meta["cy"], "w": W, "h": H, "k1": -0.05, "k2": 0.0, "p1": 0.0, "p2": 0.0})
        bad = rng.choice(list(BAD_NUMBERS) + ["zero", "negative", "valid"])
        if bad == "valid":
            _put_json(root, meta)
            return Mutation("frame camera valid", "valid")
        fr[key] = "__V__"
        _with_raw(root, meta, {"zero": "0", "negative": "-3"}.get(bad) or BAD_NUMBERS[bad])
        either = key in ("cx", "k1") and bad in ("zero", "negative")  # a principal point or distortion may be so
        return Mutation(f"frame camera {key} = {bad}", "either" if either else "invalid")
    meta["origin"] = dict(ORIGIN)
    value = rng.choice(["EPSG:32632", "EPSG:99999999", "not a crs", 5])
    meta["crs"] = value
    _put_json(root, meta)
    return Mutation(f"crs {value!r}", "valid" if value == "EPSG:32632" else "invalid")


MUTATORS = (mut_transforms_number, mut_transforms_structure, mut_header, mut_data, mut_links, mut_flight_fields)


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.lstat().st_size, p.lstat().st_mtime_ns)
            for p in sorted(root.rglob("*"))}


@dataclass
class Outcome:
    mutation: Mutation
    rc: int
    stderr: str
    traceback: str | None
    scene_changed: bool

    def problems(self) -> list[str]:
        out = []
        if self.traceback is not None:
            out.append("traceback")
        elif self.rc not in (0, 2):
            out.append(f"exit {self.rc}")
        if self.rc == 2:
            lines = self.stderr.strip().splitlines()
            if len(lines) != 1 or not lines[0].startswith("brfgs: error: ") or "/" not in lines[0]:
                out.append("error not one line naming a file")
        if self.mutation.expected == "invalid" and self.rc == 0:
            out.append("invalid input accepted")
        if self.mutation.expected == "valid" and self.rc != 0:
            out.append("valid input refused")
        if self.scene_changed:
            out.append("scene folder changed")
        return out


def run_case(seed: int, base: Path, work: Path, mutator=None) -> Outcome:
    """Copy ``base``, mutate it (by ``seed``; with ``mutator`` when given, else one drawn), run
    ``brfgs inspect`` on it, report what happened."""
    from brfgs.cli import main

    rng = random.Random(seed)
    case = work / f"case{seed}"
    shutil.rmtree(case, ignore_errors=True)
    scene = case / "scene"
    shutil.copytree(base, scene)
    mutation = (mutator or rng.choice(MUTATORS))(rng, scene)
    before = snapshot(scene)
    err, tb = io.StringIO(), None
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(["inspect", str(scene), "--out", str(case / "inspect"), "--quiet"])
        except BaseException:  # a traceback is a failure of its own kind
            rc, tb = -1, traceback.format_exc()
    outcome = Outcome(mutation, rc, err.getvalue(), tb, snapshot(scene) != before)
    shutil.rmtree(case, ignore_errors=True)
    return outcome


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--show-failures", type=int, default=20)
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="brfgs-fuzz-"))
    base = make_base_scene(work / "base")
    counts, problems, failures = Counter(), Counter(), []
    t0 = time.perf_counter()
    for k in range(args.cases):
        o = run_case(args.seed * 1_000_003 + k, base, work)
        counts[("exit 0" if o.rc == 0 else "exit 2" if o.rc == 2 else "other")] += 1
        counts[f"expected {o.mutation.expected}"] += 1
        for p in o.problems():
            problems[p] += 1
            if len(failures) < args.show_failures:
                failures.append(f"{p}: {o.mutation.what}: {(o.traceback or o.stderr).strip().splitlines()[-1:]}")
    dt = time.perf_counter() - t0
    print(f"{args.cases} cases in {dt:.0f} s (seed {args.seed})")
    for k, v in sorted(counts.items()):
        print(f"  {k}: {v}")
    print("problems:", dict(problems) if problems else "none")
    for f in failures:
        print("  ", f)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
