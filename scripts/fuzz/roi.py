"""The ROI surface: mutated GeoJSON ROIs (and ``polygon:`` text) through ``brfgs brf`` on the tiny model of
model.py (a 20 m x 20 m carpet around the origin). A valid ROI lies over the carpet; an error names the
GeoJSON file (or ``--roi`` for text)."""

from __future__ import annotations

import json
import os
import random
import shutil
from pathlib import Path

from fuzz.common import Mutation, Outcome, run_cli, snapshot
from fuzz.model import HALF_M, brf_args

SQUARE = [[-4.0, -4.0], [4.0, -4.0], [4.0, 4.0], [-4.0, 4.0], [-4.0, -4.0]]


def _feature(name=None, coords=None) -> dict:
    props = {} if name is None else {"name": name}
    return {"type": "Feature", "properties": props,
            "geometry": {"type": "Polygon", "coordinates": [coords or [list(p) for p in SQUARE]]}}


def mut_roi_coordinates(rng: random.Random, folder: Path) -> tuple[Mutation, str]:
    """A vertex's coordinate: huge, non-finite, mistyped, or a harmless variation."""
    ring = [list(p) for p in SQUARE]
    k, c = rng.randrange(4), rng.randrange(2)
    kind = rng.choice(["1e308", "-1e308", "1e300", "1e400", "NaN", "Infinity", "10**400", "string", "bool", "null",
                       "z", "4d", "1e8", "outside", "inside", "ints"])
    raw = {"1e308": "1e308", "-1e308": "-1e308", "1e300": "1e300", "1e400": "1e400", "NaN": "NaN",
           "Infinity": "Infinity", "10**400": str(10 ** 400), "string": '"4"', "bool": "true", "null": "null",
           "1e8": "1e8"}.get(kind)
    if kind == "z":
        ring = [p + [rng.uniform(-5, 5)] for p in ring]
    elif kind == "4d":
        ring[k] = ring[k] + [0.0, 1.0]
    elif kind == "inside":
        ring[k][c] *= rng.uniform(0.2, 2.0)
    elif kind == "ints":
        ring = [[int(v) for v in p] for p in ring]
    elif kind == "outside":                    # the whole polygon beside the carpet: wrong coordinates
        ring = [[p[0] + 10 * HALF_M, p[1]] for p in ring]
    else:
        ring[k][c] = "__V__"
        if k == 0:
            ring[4][c] = "__V__"
    text = json.dumps(_feature(coords=ring)).replace('"__V__"', raw or '"__V__"')
    (folder / "roi.geojson").write_text(text)
    valid = kind in ("z", "inside", "ints")
    return Mutation(f"ROI vertex {kind}", "valid" if valid else "invalid", names="roi.geojson"), "roi.geojson"


def mut_roi_structure(rng: random.Random, folder: Path) -> tuple[Mutation, str]:
    """The GeoJSON document around the polygon, and the ROI's name."""
    kind = rng.choice(["long_name", "unicode_name", "slash_name", "dot_name", "collection", "multi", "point",
                       "empty_features", "truncated", "not_json", "deep", "lonlat_crs", "utm_crs", "hole_only",
                       "self_cross", "nul_name"])
    doc: object = _feature()
    expected = "invalid"
    if kind in ("long_name", "unicode_name", "slash_name", "dot_name", "nul_name"):
        name = {"long_name": "x" * rng.choice([300, 5000, 100_000]), "unicode_name": "\u0646\u0647\u0631" * 200,
                "slash_name": "../../etc/" + "a/" * 50, "dot_name": rng.choice([".", "..", "..."]),
                "nul_name": rng.choice(["roi\u0000name", "a\nb", "\u001b[31mred", "\ud800"])}[kind]
        doc, expected = _feature(name), "invalid" if kind == "nul_name" else "valid"   # a NUL: refused
    elif kind == "collection":
        doc, expected = {"type": "FeatureCollection", "features": [_feature("a"), _feature("b")]}, "valid"
    elif kind == "multi":
        doc = {"type": "MultiPolygon", "coordinates": [[SQUARE], [[[p[0] + 5, p[1]] for p in SQUARE]]]}
        expected = "valid"
    elif kind == "point":
        doc = {"type": "Point", "coordinates": [0, 0]}
    elif kind == "empty_features":
        doc = {"type": "FeatureCollection", "features": []}
    elif kind == "lonlat_crs":                 # lon/lat needs a georeferenced scene; the model has none
        doc = dict(_feature(), crs={"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}})
    elif kind == "utm_crs":
        doc = dict(_feature(), crs={"type": "name", "properties": {"name": "EPSG:32632"}})
    elif kind == "hole_only":
        doc = _feature(coords=[[0, 0], [0, 0], [0, 0], [0, 0]])
    elif kind == "self_cross":                  # a bow tie: area 0 by the shoelace formula
        doc = _feature(coords=[[-4, -4], [4, 4], [4, -4], [-4, 4], [-4, -4]])
    path = folder / "roi.geojson"
    text = json.dumps(doc)
    if kind == "truncated":
        text = text[: rng.randrange(1, len(text) - 1)]
    elif kind == "not_json":
        text = rng.choice(["", "\x00\x01", "{'type': 'Feature'}", "\ufeff" + text])
    elif kind == "deep":
        text = "[" * 5000 + "]" * 5000
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    return Mutation(f"ROI {kind}", expected, names="roi.geojson"), "roi.geojson"


def mut_roi_text(rng: random.Random, folder: Path) -> tuple[Mutation, str]:
    """``--roi polygon:...`` text (the error names --roi)."""
    kind = rng.choice(["valid", "huge", "nan", "digits", "two", "underscore", "empty"])
    text = {"valid": "polygon:-4,-4;4,-4;4,4;-4,4", "huge": "polygon:0,0;1e308,0;1e308,1e308",
            "nan": "polygon:0,0;nan,0;1,1", "digits": "polygon:0,0;\u0664,0;4,4", "two": "polygon:0,0;1,1",
            "underscore": "polygon:0,0;4_0,0;4,4", "empty": "polygon:"}[kind]
    return Mutation(f"--roi {text[:40]!r}", "valid" if kind == "valid" else "invalid", names="--roi"), text


MUTATORS = (mut_roi_coordinates, mut_roi_structure, mut_roi_text)


def run_case(seed: int, base: Path, work: Path, mutator=None) -> Outcome:
    """Write a mutated ROI, run ``brfgs brf`` on a run folder holding (a hard link to) the model of the run
    ``base``, into its default output folder RUN/analysis/brf_<ROI name>; the ROI file and the model must
    stay unchanged."""
    rng = random.Random(seed)
    case = work / f"case{seed}"
    shutil.rmtree(case, ignore_errors=True)
    (case / "in").mkdir(parents=True)
    (case / "run").mkdir()
    os.link(base / "model.safetensors", case / "run" / "model.safetensors")
    mutation, roi = (mutator or rng.choice(MUTATORS))(rng, case / "in")
    roi = str(case / "in" / roi) if roi.endswith(".geojson") else roi
    before, model_before = snapshot(case / "in"), snapshot(base)
    rc, err, tb = run_cli(brf_args(case / "run", roi, None))
    outcome = Outcome(mutation, rc, err, tb, snapshot(case / "in") != before or snapshot(base) != model_before)
    shutil.rmtree(case, ignore_errors=True)
    return outcome
