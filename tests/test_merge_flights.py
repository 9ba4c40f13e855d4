"""`brfgs merge OUT A B`: two flights of one site (same seed, two suns) as one scene: every frame under
its own sun with its flight's split, files linked not copied, truth kept per flight; a model trained
on it renders each frame under that frame's sun. Flights that are not one site are refused in one line."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from brfgs.cli import main
from brfgs.data import read_scene
from test_train_cli import TINY

SIM = ["--scene", "testsite", "--size", "32", "--bands", "8", "--views", "13", "--spp", "16", "--seed", "5", "-q"]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("merge")
    a, b = root / "morning", root / "noon"
    assert main(["simulate", str(a), *SIM, "--sun-zenith", "50", "--sun-azimuth", "110"]) == 0
    assert main(["simulate", str(b), *SIM, "--sun-zenith", "25", "--sun-azimuth", "170"]) == 0
    return root, a, b


def test_the_merged_scene_keeps_each_frame_its_sun_split_and_files(flights, capsys):
    root, a, b = flights
    out = root / "both"
    assert main(["merge", str(out), str(a), str(b)]) == 0
    assert "(26 frames)" in capsys.readouterr().out
    m, sa, sb = read_scene(out), read_scene(a), read_scene(b)
    assert [f.name for f in m.frames] == [f"morning_{f.name}" for f in sa.frames] + [f"noon_{f.name}" for f in sb.frames]
    for f, g in zip(m.frames, sa.frames + sb.frames):
        src = sa if g in sa.frames else sb
        assert (f.sun_zenith_deg, f.sun_azimuth_deg) == (src.sun_zenith_deg, src.sun_azimuth_deg)
        assert f.split == g.split and np.array_equal(f.c2w, g.c2w)
        assert f.path.stat().st_ino == g.path.stat().st_ino                  # linked, not copied
    assert np.array_equal(m.load_image(13), sb.load_image(0))
    assert np.array_equal(m.load_truth(13), sb.load_truth(0))
    vis = np.load(out / "truth" / "sun_visibility" / f"noon_{sb.frames[0].name}.npy")
    assert np.array_equal(vis, np.load(b / "truth" / "sun_visibility" / f"{sb.frames[0].name}.npy"))
    meta = json.loads((out / "transforms.json").read_text())
    assert [f["name"] for f in meta["flights"]] == ["morning", "noon"] and "sun_zenith_deg" not in meta


def test_a_model_of_both_flights_renders_each_under_its_sun(flights, tmp_path):
    from brfgs.model import TrainedModel

    torch.set_num_threads(1)
    root, a, b = flights
    out = tmp_path / "both"
    assert main(["merge", str(out), str(a), str(b)]) == 0
    assert main(["train", str(out), str(tmp_path / "run"), *TINY, "--backend", "torch"]) == 0
    lm = TrainedModel.load(tmp_path / "run" / "model.safetensors")
    assert lm.frame_sun(0) == (50.0, 110.0) and lm.frame_sun(13) == (25.0, 170.0)
    res = json.loads((tmp_path / "run" / "metrics.json").read_text())
    names = [v["name"] for v in res["against"]["truth"]["views"]]
    assert any(n.startswith("morning_") for n in names) and any(n.startswith("noon_") for n in names)


def test_flights_under_other_skies_keep_each_its_own(flights, tmp_path, capsys):
    """A flight with its own diffuse fraction merges with one under the clear-sky default: every merged
    frame carries its flight's sky, and training lights each frame with it."""
    from brfgs.model.camera import scene_description
    from brfgs.model.shadows import scene_diffuse_fraction
    from brfgs.train.presets import preset
    from brfgs.train.state import TrainState

    root, a, b = flights
    hazy = tmp_path / "noon"
    shutil.copytree(b, hazy)
    meta = json.loads((hazy / "transforms.json").read_text())
    meta["diffuse_fraction"] = 0.35
    (hazy / "transforms.json").write_text(json.dumps(meta))
    out = tmp_path / "both"
    assert main(["merge", str(out), str(a), str(hazy)]) == 0
    m, sa = read_scene(out), read_scene(a)
    for i in range(len(m.frames)):
        want = sa.diffuse_fraction if i < len(sa.frames) else np.full(len(sa.wavelengths_nm), 0.35)
        np.testing.assert_allclose(m.frame_diffuse_fraction(i), want, atol=1e-6)
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    assert "26 frame(s) with their own" in capsys.readouterr().out
    state = TrainState(preset("tiny", shadows=True))     # what training lights each frame with
    state.meta["scene"] = json.loads(json.dumps(scene_description(m, np.stack([f.c2w for f in m.frames]))))
    assert np.allclose(state.diffuse_fraction(13).numpy(), 0.35, atol=1e-6)
    np.testing.assert_allclose(state.diffuse_fraction(0).numpy(), sa.diffuse_fraction, atol=1e-6)
    np.testing.assert_allclose(scene_diffuse_fraction(state.meta["scene"], 20).numpy(), 0.35, atol=1e-6)


def test_flights_that_are_not_one_site_are_refused(flights, tmp_path, capsys):
    root, a, b = flights

    def refused(*scenes, out=None) -> str:
        capsys.readouterr()
        assert main(["merge", str(out or tmp_path / "o"), *map(str, scenes)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        return err[0]

    small = tmp_path / "small"
    assert main(["simulate", str(small), *[x if x != "32" else "24" for x in SIM]]) == 0
    assert "fl_x" in refused(a, small)
    bands = tmp_path / "bands"
    assert main(["simulate", str(bands), *[x if x != "8" else "6" for x in SIM]]) == 0
    assert "wavelengths" in refused(a, bands)
    geo = tmp_path / "geo"
    assert main(["simulate", str(geo), *SIM, "--origin", "47.0,8.0,400"]) == 0
    assert "origin" in refused(a, geo)
    assert "two flights" in refused(a)
    assert "twice" in refused(a, a)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x.txt").write_text("mine")
    assert "not empty" in refused(a, b, out=tmp_path / "full")
    assert (tmp_path / "full" / "x.txt").read_text() == "mine"
    assert "inside a flight" in refused(a, b, out=a / "merged")
