"""Band selection on a small self-made scene: EFC ranking, the Table 2 strategies, bands.json, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_init_toy_scene import make_toy_scene

from brfgs.bands import STRATEGIES, TABLE2_STRATEGIES, compute_band_stats, select_bands
from brfgs.data import read_scene
from brfgs.errors import UserError


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = make_toy_scene(tmp_path_factory.mktemp("bands") / "toy", size=48, n_bands=24, n_views=13)
    return read_scene(root)


@pytest.fixture(scope="module")
def stats(scene):
    return compute_band_stats(scene)


def test_efc_prefers_signal_over_noisy_ends(scene, stats):
    sel = select_bands(scene, "efc", top=3, stats=stats)
    wl = sel.selected_wavelengths_nm
    assert len(wl) == 3 and all(450 <= w <= 900 for w in wl), wl
    # the EFC ranking is the order of the view-averaged EFC
    assert np.all(np.diff(stats.efc_mean[sel.selected]) <= 0)
    assert stats.efc_mean[sel.selected[0]] == stats.efc_mean.max()
    # the ends of the range, where dark noise dominates, are far down
    assert stats.efc_mean[0] < 0.2 * stats.efc_mean.max() and stats.efc_mean[-1] < 0.2 * stats.efc_mean.max()
    assert stats.efc.shape == stats.features.shape == (13, 24)
    # eq. 6 is scene-wide: no single (view, band) pair can exceed its keypoint count
    assert np.all(stats.efc <= stats.features + 1e-9)


def test_strategies(scene, stats):
    wl = scene.wavelengths_nm
    near = lambda t: int(np.argmin(np.abs(wl - t)))  # noqa: E731
    got = {s: select_bands(scene, s, stats=stats).selected for s in STRATEGIES}
    assert got["rgb"] == [near(650), near(550), near(450)]
    assert got["cir"] == [near(850), near(650), near(550)]
    assert got["central"] == [near(675)]
    assert got["all"] == list(range(len(wl)))
    assert got["max-snr"] == [int(np.argmax(stats.snr))]
    assert got["max-features"] == [int(np.argmax(stats.features_mean))]
    assert got["efc-top1"] == got["efc-top3"][:1] == got["efc"][:1]
    assert len(got["efc-top3"]) == 3
    assert set(TABLE2_STRATEGIES) <= set(STRATEGIES) and len(TABLE2_STRATEGIES) == 8
    with pytest.raises(UserError, match="unknown band-selection strategy"):
        select_bands(scene, "best", stats=stats)
    with pytest.raises(UserError, match="--top"):
        select_bands(scene, "efc", top=0, stats=stats)
    # SNR = mean reflectance / sigma
    assert np.allclose(stats.snr, stats.mean_reflectance / (stats.sigma + 1e-6))


def test_bands_json_schema(scene, stats):
    js = select_bands(scene, "efc", top=2, stats=stats).to_json()
    assert js["strategy"] == "efc" and len(js["selected"]) == 2
    assert set(js["selected"][0]) >= {"index", "wavelength_nm", "efc"}
    assert len(js["bands"]) == 24
    assert set(js["bands"][0]) >= {"index", "wavelength_nm", "efc", "features", "sigma", "snr"}
    json.dumps(js)  # plain JSON types
    # a strategy that needs no statistics still writes the schema (null statistics)
    js = select_bands(scene, "rgb").to_json()
    assert js["bands"][0]["efc"] is None and len(js["selected"]) == 3


def test_cli_select_bands(scene, tmp_path):
    from brfgs.cli import main

    out = tmp_path / "sel"
    assert main(["select-bands", str(scene.root), "--out", str(out), "--top", "2", "-q"]) == 0
    js = json.loads((out / "bands.json").read_text())
    assert len(js["selected"]) == 2 and (out / "bands.png").stat().st_size > 1000
    # never overwrite a result without --overwrite, never write into the scene folder
    assert main(["select-bands", str(scene.root), "--out", str(out), "-q"]) == 2
    assert len(json.loads((out / "bands.json").read_text())["selected"]) == 2
    assert main(["select-bands", str(scene.root), "--out", str(out), "-q", "--overwrite"]) == 0
    assert len(json.loads((out / "bands.json").read_text())["selected"]) == 3
    assert main(["select-bands", str(scene.root), "--out", str(scene.root / "sel"), "-q"]) == 2
    assert not (scene.root / "sel").exists()


def test_detect_downscale(scene):
    st = compute_band_stats(scene, views=[0, 1], detect_max_px=24)
    assert st.detect_downscale == 2 and st.efc.shape == (2, 24)


def test_efc_min_separation(scene, stats):
    plain = select_bands(scene, "efc", top=3, stats=stats)
    sep = select_bands(scene, "efc", top=3, stats=stats, min_separation_nm=60.0)
    wl = scene.wavelengths_nm
    assert sep.selected[0] == plain.selected[0] and len(sep.selected) == 3
    assert all(abs(wl[a] - wl[b]) >= 60.0 for a in sep.selected for b in sep.selected if a != b)
    assert sep.to_json()["min_separation_nm"] == 60.0 and "min_separation_nm" not in plain.to_json()
