"""Georeferencing: the origin and CRS fields, ENU ↔ lon/lat ↔ UTM against independent references
(pyproj's geodesic, the UTM zone formula), and georeferenced products where a known ground point
lands within one pixel of its lon/lat."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from brfgs.data.georef import MapFrame, Origin, default_crs, read_georef
from brfgs.errors import UserError

MUNICH = {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 520.0}


@pytest.mark.parametrize("meta, field", [
    ({"origin": {"latitude_deg": 95.0, "longitude_deg": 11.5}}, "origin.latitude_deg"),
    ({"origin": {"latitude_deg": 48.0, "longitude_deg": "east"}}, "origin.longitude_deg"),
    ({"origin": {"longitude_deg": 11.5}}, "origin.latitude_deg"),
    ({"origin": {"latitude_deg": 48.0, "longitude_deg": 11.5, "height": 3}}, "origin"),
    ({"origin": [48.0, 11.5]}, "origin"),
    ({"origin": MUNICH, "crs": "EPSG:99999999"}, "crs"),
    ({"origin": MUNICH, "crs": "EPSG:4326"}, "crs"),                 # geographic, not a map in metres
    ({"crs": "EPSG:32632"}, "crs"),                                  # a CRS without an origin
])
def test_bad_georef_fields_name_the_field(meta, field, tmp_path):
    with pytest.raises(UserError) as exc:
        read_georef(meta, tmp_path / "transforms.json")
    assert exc.value.field == field


def test_utm_zone_of_the_origin():
    assert default_crs(Origin(48.1, 11.5)) == "EPSG:32632"            # zone = floor((lon + 180) / 6) + 1
    assert default_crs(Origin(-33.9, 18.4)) == "EPSG:32734"           # southern hemisphere: 327zz
    assert default_crs(Origin(40.0, -105.3)) == "EPSG:32613"
    assert read_georef({"origin": MUNICH}) == (Origin(48.1, 11.5, 520.0), None)


def test_enu_distances_and_directions_match_the_geodesic():
    """100 m east / north of the origin in ENU is 100 m away on the ellipsoid (pyproj.Geod), at azimuth 90° / 0°."""
    from pyproj import Geod

    mf = MapFrame(Origin(48.1, 11.5, 0.0), "EPSG:32632")             # on the ellipsoid: no height scaling
    ll = mf.enu_to_lonlat([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 100.0, 0.0]])
    np.testing.assert_allclose(ll[0], [11.5, 48.1, 0.0], atol=1e-6)
    geod = Geod(ellps="WGS84")
    for k, az_want in ((1, 90.0), (2, 0.0)):
        az, _, dist = geod.inv(ll[0, 0], ll[0, 1], ll[k, 0], ll[k, 1])
        assert dist == pytest.approx(100.0, abs=2e-3) and az == pytest.approx(az_want, abs=1e-3)
    back = mf.lonlat_to_enu(mf.enu_to_lonlat([[37.5, -12.25, 3.0]]))
    np.testing.assert_allclose(back, [[37.5, -12.25, 3.0]], atol=1e-6)
    # grid convergence east of the central meridian (9° E): γ ≈ Δλ sin φ, grid north clockwise of true north
    az, k = mf.north_azimuth_deg([0.0, 0.0, 0.0], 200.0)
    assert az == pytest.approx(2.5 * math.sin(math.radians(48.1)), abs=0.01)
    assert k == pytest.approx(0.9996 * (1 + (2.5 * math.pi / 180 * math.cos(math.radians(48.1))) ** 2 / 2), abs=2e-5)
    assert mf.enu_to_map_affine([0.0, 0.0, 0.0], 300.0)[1] < 1e-3      # affine over a flight: < 1 mm


def test_products_are_georeferenced_and_a_ground_point_lands_within_a_pixel(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from brfgs.products.report import ProductsOptions, products_report
    from test_analysis_helpers import carpet_model, write_model_file

    bm = carpet_model(half_m=10.0, n_bands=4, z_left=[0.1] * 4, z_right=[0.1] * 4, components=("iso",))
    marker_m = np.array([6.5, -5.5, 0.0])                            # 8.5 m from the centre: a 1.9° rotation error = 1 px
    means = bm.gaussians.params["means"].numpy()
    k = int(np.argmin(np.linalg.norm(means[:, :2] - marker_m[:2], axis=1)))
    means[k, 2] = 0.05                                               # a small bright Gaussian on the ground,
    bm.gaussians.params["log_scales"][k] = np.log(0.12)                 # just above the carpet (seen first)
    marker_m = means[k].astype(float)
    bm.gaussians.params["z_iso"][k] = 0.9
    bm.scene["origin"] = MUNICH
    write_model_file(tmp_path / "run" / "model.safetensors", bm)
    rep = products_report(tmp_path / "run", ProductsOptions(size=(60,), half_extent_m=8.0, check_decoder=False,
                                                            mcd43=False, backend="cpu", progress=False), tmp_path / "p")
    info = rep.info
    assert info["map"]["crs"] == "EPSG:32632" and info["map"]["max_affine_residual_m"] < 1e-3
    mf = MapFrame(Origin(**MUNICH), "EPSG:32632")
    want = mf.lonlat_to_map(mf.enu_to_lonlat(marker_m[None]))[0]        # the marker's lon/lat → UTM
    with rasterio.open(tmp_path / "p" / "nbar.tif") as ds:
        assert ds.crs.to_epsg() == 32632 and np.isnan(ds.nodata) and ds.count == 4
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        band = ds.read(1)
        px = ds.transform.a
        excess = np.clip(band - 0.1 * 1.05, 0, None)                    # above the carpet's 0.1
        rows, cols = np.indices(band.shape)
        r, c = (excess * rows).sum() / excess.sum(), (excess * cols).sum() / excess.sum()
        got = np.array(ds.transform @ (c + 0.5, r + 0.5))
        assert np.linalg.norm(got - want) < 0.5 * px, (got, want, px)
        tif_transform = ds.transform
    with rasterio.open(tmp_path / "p" / "dsm.tif") as ds:                # heights above the ellipsoid
        assert ds.count == 1 and ds.crs.to_epsg() == 32632 and np.array(ds.transform)[:6] == pytest.approx(
            np.array(tif_transform)[:6])
        assert np.nanmedian(ds.read(1)) == pytest.approx(520.0, abs=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(tmp_path / "p" / "nbar.img") as ds:         # the ENVI copy: same grid via map info
            assert ds.crs.to_epsg() == 32632
            np.testing.assert_allclose(np.array(ds.transform)[:6], np.array(tif_transform)[:6], atol=1e-3)


def test_scene_origin_reaches_the_model_and_bad_origin_exits_2(tmp_path, capsys):
    import json

    from brfgs.cli import main
    from brfgs.data.scene import read_scene
    from brfgs.model.camera import scene_description
    from brfgs.sim.acquisition import _transforms
    from brfgs.sim.config import SimConfig
    from test_analysis_brf import _write_scene_from_model
    from test_analysis_helpers import carpet_model

    cfg = SimConfig.tiny(origin=(48.1, 11.5))
    assert _transforms(cfg, [], [])["origin"] == {"latitude_deg": 48.1, "longitude_deg": 11.5, "altitude_m": 0.0}
    assert SimConfig.from_json(json.loads(json.dumps(cfg.to_json()))) == cfg
    root = _write_scene_from_model(tmp_path / "scene", carpet_model(half_m=4.0, n_bands=4), with_truth=False)
    tf = root / "transforms.json"
    meta = json.loads(tf.read_text())
    meta["origin"] = MUNICH
    tf.write_text(json.dumps(meta))
    sc = read_scene(root)
    assert sc.origin == Origin(48.1, 11.5, 520.0) and sc.crs is None
    desc = scene_description(sc, np.stack([f.c2w for f in sc.frames]))
    assert desc["origin"] == MUNICH
    meta["origin"] = {"latitude_deg": 48.1, "longitude_deg": 200.0}
    tf.write_text(json.dumps(meta))
    assert main(["inspect", str(root)]) == 2
    err = capsys.readouterr().err
    assert "origin.longitude_deg" in err and "transforms.json" in err and "Traceback" not in err
    with pytest.raises(UserError, match="origin"):
        SimConfig.tiny(origin=(95.0, 0.0)).validate()


def test_envi_map_info_names_the_utm_zone_for_any_proj_datum_name():
    """PROJ 9.5 names WGS 84's datum "World Geodetic System 1984 ensemble": the UTM zone and hemisphere
    come from the EPSG code, or from the zone and a datum name that starts with WGS 84's."""
    from types import SimpleNamespace

    from pyproj import CRS

    from brfgs.products.georaster import MapGrid, envi_map_info, utm_zone_of

    assert utm_zone_of(CRS.from_epsg(32632)) == (32, "North")
    assert utm_zone_of(CRS.from_epsg(32755)) == (55, "South")
    for name in ("World Geodetic System 1984", "World Geodetic System 1984 ensemble"):
        fake = SimpleNamespace(to_epsg=lambda: None, utm_zone="33S", datum=SimpleNamespace(name=name))
        assert utm_zone_of(fake) == (33, "South")
    other = SimpleNamespace(to_epsg=lambda: None, utm_zone="33N", datum=SimpleNamespace(name="European Terrestrial"))
    assert utm_zone_of(other) is None and utm_zone_of(CRS.from_epsg(3857)) is None
    info = envi_map_info(MapGrid(crs="EPSG:32632", upper_left=(500000.0, 5330000.0), pixel_size=0.5, width=4,
                                 height=4, max_affine_residual_m=0.0))["map info"]
    assert info[0] == "UTM" and info[7:9] == ["32", "North"]
