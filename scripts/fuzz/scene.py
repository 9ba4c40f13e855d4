"""The scene surface: mutated scenes through ``brfgs inspect`` (transforms.json numbers and structure,
ENVI headers, data files, links out of the scene). A flight's fields and the cameras: scene_fields.py."""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import numpy as np

from fuzz.common import Mutation

W, H, BANDS = 8, 6, 4
HEADER_NUMBERS = ("lines", "samples", "bands", "header offset", "data type", "byte order")


VIEWS = ((0.0, 0.0), (30.0, 0.0), (30.0, 180.0))


def make_base_scene(root: Path, views: tuple = VIEWS) -> Path:
    """A valid tiny scene in the docs/data-format.md layout (ENVI cubes, two dark frames); ``views``:
    (zenith, azimuth) degrees of the cameras, 50 m from the origin."""
    from brfgs.data.cameras import Intrinsics, pose_from_view_angles
    from brfgs.data.cube_io import write_envi

    rng = np.random.default_rng(0)
    wl = np.linspace(500.0, 850.0, BANDS)
    intr = Intrinsics.from_fov(35.0, W, H)
    frames = []
    for k, (zen, az) in enumerate(views):
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
        value = rng.choice(["16.0", "abc", "1e1", "{16}", "-4", "0", "", "99999999999999999999",
                            "\u0666", "\u0661\u0666", "\uff16", "\u00b2", "6\u0000", "6_0"])
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
        value = rng.choice(["-4", "x", "16", "1e3", "\u0660"])
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
