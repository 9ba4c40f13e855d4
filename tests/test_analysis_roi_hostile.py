"""Hostile ROIs for `brfgs brf`: a GeoJSON `properties.name` of 5,000 characters still works (the output
folder named after it is cut and ends in a hash of the name), coordinates of 1e308 are refused in one line
naming the file and the field with no overflow warning printed, and a path too long for the file system is
one line, exit status 2."""

from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pytest

from brfgs.analysis.output import SAFE_NAME_BYTES, safe_name
from brfgs.analysis.roi_spec import parse_roi_spec
from brfgs.cli import main
from test_analysis_helpers import carpet_model, write_model_file

SQUARE = [[-4.0, -4.0], [4.0, -4.0], [4.0, 4.0], [-4.0, 4.0], [-4.0, -4.0]]
BRF = ["--bands", "480", "--step", "30", "--max-zenith", "60", "--no-polar", "--size", "8", "-q"]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    tm = carpet_model(half_m=10.0, spacing_m=2.0, n_bands=4, z_left=np.linspace(0.1, 0.4, 4),
                      z_right=np.linspace(0.5, 0.1, 4), components=("iso", "geo"))
    return write_model_file(tmp_path_factory.mktemp("roi_model") / "model.safetensors", tm)


@pytest.fixture
def run(model, tmp_path):
    (tmp_path / "run").mkdir()
    os.link(model, tmp_path / "run" / "model.safetensors")
    return tmp_path / "run"


def _geojson(path, name=None, ring=SQUARE, raw=None):
    doc = {"type": "Feature", "properties": {} if name is None else {"name": name},
           "geometry": {"type": "Polygon", "coordinates": [ring]}}
    text = json.dumps(doc)
    path.write_text(text.replace('"__V__"', raw) if raw else text)
    return path


def _brf(run, roi, capsys, *extra) -> tuple[int, str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main(["brf", str(run), "--roi", str(roi), *BRF, *extra])
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and not [str(w.message) for w in caught], [str(w.message) for w in caught]
    return rc, err


def test_a_5000_character_roi_name_works_with_a_shortened_folder_name(run, tmp_path, capsys):
    name = "meadow-" + "x" * 4993
    rc, err = _brf(run, _geojson(tmp_path / "roi.geojson", name), capsys)
    assert rc == 0, err
    (folder,) = (run / "analysis").iterdir()
    assert folder.name.startswith("brf_meadow-xxx") and len(folder.name.encode()) <= 4 + SAFE_NAME_BYTES
    assert folder.name == "brf_" + safe_name(name) and (folder / "brf.json").stat().st_size > 0


def test_long_names_that_share_their_start_get_their_own_folders(run, tmp_path, capsys):
    for end in ("a", "b"):
        rc, err = _brf(run, _geojson(tmp_path / f"{end}.geojson", "\u0646" * 3000 + end), capsys)
        assert rc == 0, err
    names = sorted(p.name for p in (run / "analysis").iterdir())
    assert len(names) == 2 and names[0] != names[1] and all(len(n.encode()) <= 4 + SAFE_NAME_BYTES for n in names)


def test_a_long_roi_name_option_works(run, tmp_path, capsys):
    rc, err = _brf(run, _geojson(tmp_path / "roi.geojson"), capsys, "--roi-name", "n" * 5000)
    assert rc == 0, err


@pytest.mark.parametrize("name, field", [("roi\u0000name", "properties.name"), ("a\nb", "properties.name"),
                                         ("\ud800", "properties.name")])
def test_an_roi_name_with_control_characters_is_refused(run, tmp_path, capsys, name, field):
    path = tmp_path / "roi.geojson"
    _geojson(path, "__N__")
    path.write_text(path.read_text().replace('"__N__"', json.dumps(name)))
    rc, err = _brf(run, path, capsys)
    assert rc == 2 and len(err.splitlines()) == 1 and "roi.geojson" in err and f"field '{field}'" in err, err
    rc, err = _brf(run, "polygon:-4,-4;4,-4;4,4", capsys, "--roi-name", "a\tb")
    assert rc == 2 and "--roi-name" in err, err


def test_safe_name_keeps_short_names_and_cuts_long_ones():
    assert safe_name("east field/2") == "east_field_2"
    long = safe_name("é" * 400)
    assert len(long.encode()) <= SAFE_NAME_BYTES and long != safe_name("é" * 401)


@pytest.mark.parametrize("raw", ["1e308", "-1e308", "1e300", "1e8"])
def test_huge_geojson_coordinates_are_refused_without_warnings(run, tmp_path, capsys, raw):
    ring = [list(p) for p in SQUARE]
    ring[2][0] = "__V__"
    rc, err = _brf(run, _geojson(tmp_path / "big.geojson", ring=ring, raw=raw), capsys)
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert "big.geojson" in err and "geometry.coordinates[0][2]" in err and "out of range" in err, err
    assert not (run / "analysis").exists()


def test_huge_polygon_text_is_refused_without_warnings(run, capsys):
    rc, err = _brf(run, "polygon:0,0;1e308,0;1e308,1e308", capsys)
    assert rc == 2 and len(err.splitlines()) == 1 and "--roi" in err and "out of range" in err, err


def test_the_roi_reader_gives_no_overflow_warning(tmp_path):
    ring = [list(p) for p in SQUARE]
    ring[1] = [1e308, 1e308]
    path = _geojson(tmp_path / "r.geojson", ring=ring)
    from brfgs.errors import UserError

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(UserError, match="out of range"):
            parse_roi_spec(str(path))


def test_an_output_path_too_long_for_the_file_system_is_one_line(run, tmp_path, capsys):
    rc, err = _brf(run, _geojson(tmp_path / "roi.geojson"), capsys, "-o", str(tmp_path / ("o" * 300)))
    assert rc == 2 and len(err.splitlines()) == 1 and "too long" in err.lower(), err
