"""The scene surface, continued: a flight's fields (times, origin, a frame's own sun, irradiance, camera,
CRS) and where the cameras are (at the origin, below the ground, 100 km away, matrices of big integers
or strings, paths that name a folder, times with control characters)."""

from __future__ import annotations

import json
import random
from pathlib import Path

from fuzz.common import Mutation
from fuzz.scene import H, W, _json, _put_json

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


def mut_cameras(rng: random.Random, root: Path) -> Mutation:
    """Where a frame's camera is and how its matrix, path and time are written."""
    meta, k = _json(root), rng.randrange(3)
    fr = meta["frames"][k]
    kind = rng.choice(["origin", "below", "far", "near_limit", "big_int", "string_element", "bool_element",
                       "trailing_slash", "dot_path", "time_control", "time_digits", "distance_far"])
    if kind in ("origin", "below"):          # no view angles: they would come from the camera centre
        del fr["view_zenith_deg"], fr["view_azimuth_deg"]
        m = fr["transform_matrix"]
        m[0][3], m[1][3], m[2][3] = (0.0, 0.0, 0.0) if kind == "origin" else (m[0][3], m[1][3], -rng.uniform(0, 80))
        _put_json(root, meta)
        return Mutation(f"frame camera {kind}, no view angles", "invalid")
    if kind in ("far", "near_limit"):
        d = rng.choice([1e300, 2e5, 1e6]) if kind == "far" else rng.choice([5e4, 9e4])
        fr["transform_matrix"][2][3] = d
        _put_json(root, meta)
        return Mutation(f"frame camera {d:g} m up", "invalid" if kind == "far" else "valid")
    if kind in ("big_int", "string_element", "bool_element"):
        i, j = rng.randrange(4), rng.randrange(4)
        fr["transform_matrix"][i][j] = "__V__"
        raw = {"big_int": str(10 ** rng.choice([309, 400, 4000])), "string_element": rng.choice(['"1"', '"\u0661"']),
               "bool_element": "true"}[kind]
        _put_json(root, None, json.dumps(meta, indent=1).replace('"__V__"', raw))
        return Mutation(f"transform_matrix[{i}][{j}] {kind}", "invalid")
    if kind in ("trailing_slash", "dot_path"):
        fr["file_path"] = fr["file_path"] + rng.choice(["/", "//", "\\"]) if kind == "trailing_slash" else \
            rng.choice(["images/.", "images/..", "."])
        _put_json(root, meta)
        return Mutation(f"file_path {fr['file_path']!r}", "invalid")
    if kind == "distance_far":
        fr.pop("transform_matrix")
        fr["distance_m"] = rng.choice([1e300, 1.5e5])
        _put_json(root, meta)
        return Mutation(f"distance_m {fr['distance_m']:g}", "invalid")
    meta["origin"] = dict(ORIGIN)
    good = "2024-06-21T10:32:05Z"
    fr["time"] = good + rng.choice(["\u0000", "\n", "\t", "\x7f", " "]) if kind == "time_control" else \
        rng.choice(["\u0662\u0660\u0662\u0664-06-21T10:32:05Z", "2024-06-21T10:32:05Z\u00a0", "\uff12024-06-21T10:32:05Z"])
    _put_json(root, meta)
    return Mutation(f"frame time {fr['time']!r}", "invalid")
