"""Polygon ROIs from GeoJSON files (scene ENU metres): same area as the text polygon, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brfgs.analysis import roi as R
from brfgs.analysis import roi_spec
from brfgs.cli import main
from brfgs.errors import UserError
from test_analysis_helpers import carpet_model, write_model_file

SQUARE = [[3.0, -5.0], [9.0, -5.0], [9.0, 5.0], [3.0, 5.0]]
TEXT = "polygon:" + ";".join(f"{x:g},{y:g}" for x, y in SQUARE)


def _poly(ring, z=None):
    ring = [list(p) + ([z] if z is not None else []) for p in ring]
    return {"type": "Polygon", "coordinates": [ring + [ring[0]]]}       # closed, as GeoJSON requires


def _write(path, obj):
    path.write_text(json.dumps(obj))
    return path


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("geojson_run")
    bm = carpet_model(half_m=12.0, n_bands=4, geo=0.2, components=("iso", "geo"))
    write_model_file(root / "run" / "model.safetensors", bm)       # no scene: model only
    return root / "run"


@pytest.mark.parametrize("layout", ["geometry", "feature", "collection", "z", "prefix"])
def test_geojson_selects_the_same_gaussians_as_the_text_polygon(tmp_path, layout):
    geom = _poly(SQUARE, z=12.5 if layout == "z" else None)
    obj = {"geometry": geom, "z": geom, "prefix": geom,
           "feature": {"type": "Feature", "properties": {"name": "east"}, "geometry": geom},
           "collection": {"type": "FeatureCollection",
                          "features": [{"type": "Feature", "properties": {}, "geometry": geom}]}}[layout]
    path = _write(tmp_path / "roi.geojson", obj)
    spec = roi_spec.parse_roi_spec(f"geojson:{path}" if layout == "prefix" else str(path))
    ref = roi_spec.parse_roi_spec(TEXT)
    assert spec.kind == "polygon"
    assert spec.name == ("east" if layout == "feature" else "roi")
    np.testing.assert_array_equal(spec.polygon_xy_m, ref.polygon_xy_m)
    a = R.PolygonROI(spec.polygon_xy_m, polygons=spec.polygons, source=spec.source)
    b = R.PolygonROI(ref.polygon_xy_m)
    means = carpet_model(half_m=12.0).gaussians.means.double().numpy()
    np.testing.assert_array_equal(a.contains(means), b.contains(means))
    assert a.contains(means).sum() == 6 * 10                      # 1 m carpet: 6 x 10 Gaussian centres
    np.testing.assert_allclose(a.centre_m, b.centre_m)
    assert a.radius_m == pytest.approx(b.radius_m) and a.area_m2 == pytest.approx(60.0)
    assert a.describe()["source"]["file"] == str(path)


def test_multipolygon_with_hole_and_feature_union(tmp_path):
    outer = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]
    hole = [[4.0, 4.0], [6.0, 4.0], [6.0, 6.0], [4.0, 6.0]]
    far = [[20.0, 0.0], [22.0, 0.0], [22.0, 2.0], [20.0, 2.0]]
    mp = {"type": "MultiPolygon", "coordinates": [[outer + [outer[0]], hole + [hole[0]]], [far + [far[0]]]]}
    spec = roi_spec.parse_roi_spec(str(_write(tmp_path / "mp.json", mp)))
    roi = R.PolygonROI(spec.polygon_xy_m, polygons=spec.polygons)
    pts = np.array([[1.0, 1.0, 0], [5.0, 5.0, 0], [21.0, 1.0, 0], [15.0, 1.0, 0], [9.5, 9.5, 3.0]])
    assert roi.contains(pts).tolist() == [True, False, True, False, True]
    assert roi.area_m2 == pytest.approx(100.0 - 4.0 + 4.0)
    # a FeatureCollection of overlapping features is their union (not even-odd)
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": None, "geometry": _poly(outer)},
        {"type": "Feature", "properties": None, "geometry": _poly([[5.0, 5.0], [15.0, 5.0], [15.0, 15.0], [5.0, 15.0]])}]}
    spec = roi_spec.parse_roi_spec(str(_write(tmp_path / "fc.geojson", fc)))
    roi = R.PolygonROI(spec.polygon_xy_m, polygons=spec.polygons)
    assert roi.contains(np.array([[7.0, 7.0, 0], [12.0, 12.0, 0], [2.0, 2.0, 0], [2.0, 12.0, 0]])).tolist() == \
        [True, True, True, False]


def test_crs_must_be_local(tmp_path):
    geom = _poly(SQUARE)
    ok = dict(geom, crs={"type": "name", "properties": {"name": "local-ENU"}})
    assert roi_spec.parse_roi_spec(str(_write(tmp_path / "ok.geojson", ok))).kind == "polygon"
    assert roi_spec.parse_roi_spec(str(_write(tmp_path / "null.geojson", dict(geom, crs=None)))).kind == "polygon"
    lonlat = dict(geom, crs={"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}})
    assert roi_spec.parse_roi_spec(str(_write(tmp_path / "ll.geojson", lonlat))).lonlat   # WGS 84 lon/lat
    for crs in ({"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32650"}},
                {"type": "link", "properties": {"href": "http://example.com/crs/42"}}):
        bad = _write(tmp_path / "bad.geojson", {"type": "Feature", "properties": {}, "geometry": geom, "crs": crs})
        with pytest.raises(UserError, match="local ENU") as e:
            roi_spec.parse_roi_spec(str(bad))
        assert e.value.file == str(bad) and e.value.field == "crs"


BAD = {
    "json": ("{not json", None, "not valid JSON"),
    "huge_int": ('{"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, ' + "1" + "0" * 400 + '], [0, 0]]]}',
                 "coordinates[0][2]", "out-of-range"),
    "digits": ('{"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, ' + "7" * 5000 + '], [0, 0]]]}', None,
               "not valid JSON"),
    "deep": ("[" * 5000 + "]" * 5000, None, "nested deeper"),
    "nan": ('{"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, NaN], [0, 0]]]}', "coordinates[0][2]",
            "non-finite"),
    "not_utf8": (b"\xff\xfe{", None, "UTF-8"),
    "four_numbers": ({"type": "Polygon", "coordinates": [[[0, 0, 0, 0], [1, 0], [1, 1], [0, 0]]]},
                     "coordinates[0][0]", "position"),
    "point": ({"type": "Point", "coordinates": [1.0, 2.0]}, "type", "Polygon or MultiPolygon"),
    "short_ring": ({"type": "Polygon", "coordinates": [[[0, 0], [1, 1], [0, 0]]]}, "coordinates[0]", "at least 3"),
    "text_coord": ({"type": "Polygon", "coordinates": [[[0, 0], [1, "a"], [1, 1], [0, 0]]]}, "coordinates[0][1]",
                   "position"),
    "no_geometry": ({"type": "Feature", "properties": {}, "geometry": None}, "geometry", "no geometry"),
    "empty_fc": ({"type": "FeatureCollection", "features": []}, "features", "non-empty"),
    "nested": ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "LineString",
                "coordinates": [[0, 0], [1, 1]]}}]}, "features[0].geometry.type", "Polygon"),
    "epsg": ({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 0]]],
              "crs": {"type": "name", "properties": {"name": "EPSG:32632"}}}, "crs", "local ENU"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_malformed_geojson_is_exit_2_naming_the_file(run_dir, tmp_path, capsys, case):
    content, field, words = BAD[case]
    path = tmp_path / f"{case}.geojson"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content if isinstance(content, str) else json.dumps(content))
    out = tmp_path / "out"
    assert main(["brf", str(run_dir), "--roi", str(path), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and words in err and "Traceback" not in err, err
    if field:
        assert f"field '{field}'" in err, err
    assert not out.exists()


def test_missing_file_and_lonlat_polygon(run_dir, tmp_path, capsys):
    missing = tmp_path / "nope.geojson"
    assert main(["brf", str(run_dir), "--roi", str(missing), "-q", "-o", str(tmp_path / "o1")]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "not found" in err
    lonlat = _write(tmp_path / "lonlat.geojson", _poly([[116.30, 39.90], [116.31, 39.90], [116.31, 39.91]]))
    assert main(["brf", str(run_dir), "--roi", str(lonlat), "-q", "-o", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert str(lonlat) in err and "outside the model" in err and "longitude" in err and "Traceback" not in err


def test_brf_command_gives_the_same_curve_for_geojson_and_text(run_dir, tmp_path):
    path = _write(tmp_path / "east.geojson", {"type": "Feature", "properties": {"name": "east"}, "geometry": _poly(SQUARE)})
    common = ["--bands", "480,860", "--step", "30", "--max-zenith", "60", "--no-polar", "--size", "16", "-q"]
    assert main(["brf", str(run_dir), "--roi", str(path), "-o", str(tmp_path / "g")] + common) == 0
    assert main(["brf", str(run_dir), "--roi", TEXT, "-o", str(tmp_path / "t")] + common) == 0
    g = (tmp_path / "g" / "principal_plane.csv").read_text()
    assert g == (tmp_path / "t" / "principal_plane.csv").read_text()
    roi = json.loads((tmp_path / "g" / "roi.json").read_text())
    assert roi["name"] == "east" and roi["source"] == {"kind": "geojson", "file": str(path), "n_polygons": 1,
                                                       "coordinates": "ENU metres"}


def test_lonlat_roi_on_a_georeferenced_model(tmp_path, capsys):
    """A WGS 84 lon/lat GeoJSON (crs CRS84, or lonlat:PATH without crs) selects the same ground as the
    same polygon in ENU metres when the scene has an origin; without an origin it is refused."""
    from brfgs.data.georef import MapFrame, Origin

    origin = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}
    bm = carpet_model(half_m=12.0, n_bands=4)
    bm.scene["origin"] = origin
    write_model_file(tmp_path / "geo" / "model.safetensors", bm)
    from brfgs.model import TrainedModel

    tm = TrainedModel.load(tmp_path / "geo")
    mf = MapFrame(Origin(48.1, 11.5, 520.0), "EPSG:32632")
    enu = np.array([[2.0, 2.0], [9.0, 2.5], [8.0, 9.0], [3.0, 8.0]])
    ll = mf.enu_to_lonlat(np.c_[enu, np.full(4, 520.0 - 520.0)])[:, :2]
    crs84 = {"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}}
    for spec_text in (str(_write(tmp_path / "a.geojson", dict(_poly(ll.tolist()), crs=crs84))),
                      "lonlat:" + str(_write(tmp_path / "b.geojson", _poly(ll.tolist())))):
        roi = roi_spec.resolve_roi(roi_spec.parse_roi_spec(spec_text), tm)
        np.testing.assert_allclose(roi.polygons[0][0], enu, atol=1e-3)
    # the same file on a model without an origin: a clear error
    write_model_file(tmp_path / "plain" / "model.safetensors", carpet_model(half_m=12.0, n_bands=4))
    assert main(["brf", str(tmp_path / "plain"), "--roi", "lonlat:" + str(tmp_path / "b.geojson"), "-q",
                 "-o", str(tmp_path / "o")]) == 2
    assert "georeferenced" in capsys.readouterr().err
