"""`brfgs simulate`: files written (docs/data-format.md layout + truth/), noise model, determinism, errors."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from brfgs.cli import main
from brfgs.data.cameras import Intrinsics, paper_view_angles, pose_from_view_angles
from brfgs.errors import UserError
from brfgs.sim import SimConfig, render_views, simulate


def _cube(path_hdr: Path, h: int, w: int) -> np.ndarray:
    """ENVI bip float32 cube [H, W, B] next to ``path_hdr``."""
    data = np.fromfile(path_hdr.with_suffix(".img"), dtype="<f4")
    return data.reshape(h, w, -1)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    cfg = SimConfig.tiny("testsite")
    out = simulate(tmp_path_factory.mktemp("sim") / "scene", cfg, progress=False)
    return out, cfg


def test_transforms_json_layout(tiny):
    out, cfg = tiny
    T = json.loads((out / "transforms.json").read_text())
    intr = Intrinsics.from_fov(35.0, cfg.size, cfg.size)
    assert T["camera_model"] == "PINHOLE"
    for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        assert T[k] == pytest.approx(getattr(intr, k))
    wl = np.array(T["wavelengths_nm"])
    assert len(wl) == cfg.bands and wl[0] == 350.0 and wl[-1] == 1000.0 and (np.diff(wl) > 0).all()
    assert len(T["fwhm_nm"]) == cfg.bands
    assert T["sun_zenith_deg"] == cfg.sun_zenith_deg and T["sun_azimuth_deg"] == cfg.sun_azimuth_deg
    assert len(T["dark_frames"]) == cfg.n_dark
    assert all((out / p).is_file() and (out / p).with_suffix(".img").is_file() for p in T["dark_frames"])
    angles = paper_view_angles(cfg.views)
    assert len(T["frames"]) == cfg.views
    for f, (z, a) in zip(T["frames"], angles):
        assert f["file_path"].startswith("images/") and f["file_path"].endswith(".hdr")
        assert (out / f["file_path"]).is_file()
        assert f["view_zenith_deg"] == z and f["view_azimuth_deg"] == a and f["distance_m"] == cfg.distance_m
        np.testing.assert_allclose(np.array(f["transform_matrix"]), pose_from_view_angles(z, a, cfg.distance_m))
    hdr = (out / T["frames"][0]["file_path"]).read_text()
    assert "wavelength" in hdr and "fwhm" in hdr and "interleave = bip" in hdr


def test_truth_layout(tiny):
    out, cfg = tiny
    T = json.loads((out / "transforms.json").read_text())
    table = json.loads((out / "truth" / "materials.json").read_text())
    ids_in_table = {int(k) for k in table["materials"]}
    for entry in table["materials"].values():
        assert len(entry["spectrum"]) == cfg.bands and entry["name"]
    seen = set()
    for f in T["frames"]:
        name = Path(f["file_path"]).stem
        clean = _cube(out / "truth" / "images" / f"{name}.hdr", cfg.size, cfg.size)
        assert clean.shape == (cfg.size, cfg.size, cfg.bands) and np.isfinite(clean).all()
        depth = np.load(out / "truth" / "depth" / f"{name}.npy")
        mat = np.load(out / "truth" / "materials" / f"{name}.npy")
        assert depth.dtype == np.float32 and depth.shape == (cfg.size, cfg.size)
        assert mat.dtype == np.int16 and mat.shape == (cfg.size, cfg.size)
        # the scene fills every view; depth is positive and near the camera distance
        assert (mat > 0).all() and np.isfinite(depth).all()
        assert 0.7 * cfg.distance_m < np.median(depth) < 1.3 * cfg.distance_m
        seen |= set(np.unique(mat).tolist())
    assert seen <= ids_in_table
    names = {table["materials"][str(i)]["name"] for i in seen}
    assert {"grass", "broadleaf", "roof", "water"} <= names
    sig = json.loads((out / "truth" / "sigma.json").read_text())
    np.testing.assert_allclose(sig["dark_sigma"], cfg.sigma_b(), rtol=1e-12)
    scene = json.loads((out / "truth" / "scene.json").read_text())
    assert SimConfig.from_json(scene["config"]) == cfg
    assert scene["renderer"]["name"] == "mitsuba"


def test_dark_frames_sigma_matches_configured(tiny):
    out, cfg = tiny
    T = json.loads((out / "transforms.json").read_text())
    darks = np.stack([_cube(out / p, cfg.size, cfg.size) for p in T["dark_frames"]])  # [K, H, W, B]
    measured = darks.reshape(-1, cfg.bands).std(0)
    np.testing.assert_allclose(measured, cfg.sigma_b(), rtol=0.06)
    assert abs(darks.mean()) < 0.002


def test_observation_noise_model(tiny):
    """obs − clean has the configured σ² = σ_b² + k²·ρ in every band."""
    out, cfg = tiny
    T = json.loads((out / "transforms.json").read_text())
    sigma = cfg.sigma_b()
    z = []
    for f in T["frames"]:
        name = Path(f["file_path"]).stem
        obs = _cube(out / f["file_path"], cfg.size, cfg.size).astype(np.float64)
        clean = _cube(out / "truth" / "images" / f"{name}.hdr", cfg.size, cfg.size).astype(np.float64)
        z.append((obs - clean) / np.sqrt(sigma ** 2 + cfg.shot_coeff ** 2 * np.maximum(clean, 0)))
    z = np.stack(z).reshape(-1, cfg.bands)
    np.testing.assert_allclose(z.std(0), 1.0, atol=0.05)
    assert np.abs(z.mean(0)).max() < 0.05


def test_previews_written(tiny):
    out, cfg = tiny
    from PIL import Image

    for name in ("preview_cir_nadir.png", "preview_cir_oblique.png"):
        im = Image.open(out / name)
        assert im.size == (cfg.size, cfg.size) and im.mode == "RGB"
        a = np.asarray(im)
        assert a.std() > 10  # not blank


def test_render_views_reproduces_acquisition(tiny):
    """The extra-view renderer gives the acquisition's clean cube for the same view direction
    (config read back from truth/scene.json)."""
    from brfgs.sim import render_scene_views

    out, cfg = tiny
    z, a = paper_view_angles(cfg.views)[5]
    res = render_scene_views(out, [(z, a)])
    T = json.loads((out / "transforms.json").read_text())
    name = Path(T["frames"][5]["file_path"]).stem
    clean = _cube(out / "truth" / "images" / f"{name}.hdr", cfg.size, cfg.size)
    np.testing.assert_array_equal(res["reflectance"][0], clean)
    np.testing.assert_array_equal(res["material"][0], np.load(out / "truth" / "materials" / f"{name}.npy"))


def _digest(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_cli_is_deterministic_and_resumes(tmp_path, monkeypatch):
    args = ["--scene", "testsite", "--size", "16", "--bands", "5", "--views", "13", "--spp", "4",
            "--dark-frames", "2", "--seed", "3", "--quiet"]
    assert main(["simulate", str(tmp_path / "a"), *args]) == 0
    assert main(["simulate", str(tmp_path / "b"), *args]) == 0
    da, db = _digest(tmp_path / "a"), _digest(tmp_path / "b")
    assert len(da) > 13 * 4 and da == db
    # an interrupted run resumes to the same bytes
    import brfgs.sim.acquisition as simmod

    real_observe, calls = simmod.observe, []

    def failing_observe(*a, **k):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return real_observe(*a, **k)

    monkeypatch.setattr(simmod, "observe", failing_observe)
    assert main(["simulate", str(tmp_path / "c"), *args]) == 130
    monkeypatch.setattr(simmod, "observe", real_observe)
    assert not (tmp_path / "c" / "transforms.json").exists()
    assert main(["simulate", str(tmp_path / "c"), *args]) == 2  # not empty: refuses without --resume
    assert main(["simulate", str(tmp_path / "c"), *args, "--resume"]) == 0
    assert _digest(tmp_path / "c") == da


@pytest.mark.parametrize("opts,field", [
    (["--scene", "moon"], "scene"),
    (["--size", "4"], "size"),
    (["--sun-zenith", "95"], "zenith"),
    (["--sun-zenith", "-1"], "zenith"),
    (["--spp", "3"], "spp"),
    (["--spp", "32"], "power of 4"),  # the default ldsampler needs a square power of two
    (["--spp", "3", "--sampler", "independent"], "spp"),
    (["--sampler", "halton"], "sampler"),
    (["--views", "10"], "views"),
    (["--rings", "15,15"], "rings"),
    (["--rings", "80"], "rings"),
    (["--rings", "30", "--azimuths", "0"], "azimuths"),
    (["--rings", "30,x"], "--rings"),
])
def test_cli_bad_options_exit_2(tmp_path, capsys, opts, field):
    rc = main(["simulate", str(tmp_path / "x"), "--size", "16", "--bands", "3", "--views", "13", *opts])
    assert rc == 2
    assert field in capsys.readouterr().err
    assert not (tmp_path / "x" / "transforms.json").exists()


def test_library_bad_options_raise_user_error(tmp_path):
    with pytest.raises(UserError):
        simulate(tmp_path / "x", SimConfig.tiny("nowhere"))
    with pytest.raises(UserError):
        render_views(SimConfig.tiny(), [(95.0, 0.0)])
    with pytest.raises(UserError, match="power of 4"):
        render_views(SimConfig.tiny(), [(0.0, 0.0)], spp=8)


def test_old_scene_config_reads_as_independent_sampler():
    """Scenes written before the sampler option (no 'sampler' key) were rendered with independent samples."""
    cfg = SimConfig.tiny(spp=8, sampler="independent")
    d = cfg.to_json()
    d.pop("sampler")
    old = SimConfig.from_json(d)
    assert old.sampler == "independent" and old.spp == 8
    old.validate()
    assert SimConfig.from_json(SimConfig.tiny().to_json()).sampler == "ldsampler"


def test_never_overwrites_without_flag(tmp_path, capsys):
    out = tmp_path / "scene"
    out.mkdir()
    keep = out / "notes.txt"
    keep.write_text("user data")
    args = ["--size", "8", "--bands", "3", "--views", "1", "--spp", "1", "--dark-frames", "1", "--quiet"]
    assert main(["simulate", str(out), *args]) == 2
    assert "overwrite" in capsys.readouterr().err
    # --overwrite refuses a folder that holds no simulation (only foreign files)
    assert main(["simulate", str(out), *args, "--overwrite"]) == 2
    assert keep.read_text() == "user data"
    # a simulation folder can be replaced with --overwrite; foreign files are kept
    sim = tmp_path / "sim"
    assert main(["simulate", str(sim), *args]) == 0
    (sim / "notes.txt").write_text("mine")
    assert main(["simulate", str(sim), *args]) == 2
    before = _digest(sim)
    assert main(["simulate", str(sim), *args, "--seed", "1", "--overwrite"]) == 0
    assert (sim / "notes.txt").read_text() == "mine"
    after = _digest(sim)
    assert set(after) == set(before)
    assert after["images/v00_z00_a000.img"] != before["images/v00_z00_a000.img"]  # another seed, other data
    assert json.loads((sim / "truth" / "scene.json").read_text())["config"]["seed"] == 1


def test_another_view_layout(tmp_path):
    """--rings / --azimuths: nadir + 5 azimuths on 10° and 65° rings, read back with those rings."""
    from brfgs.data.scene import read_scene

    out = tmp_path / "rings"
    assert main(["simulate", str(out), "--size", "16", "--bands", "3", "--spp", "4", "--dark-frames", "2",
                 "--rings", "65,10", "--azimuths", "5", "--quiet"]) == 0
    meta = json.loads((out / "transforms.json").read_text())
    got = [(f["view_zenith_deg"], f["view_azimuth_deg"]) for f in meta["frames"]]
    want = [(0.0, 0.0)] + [(z, a) for z in (10.0, 65.0) for a in (0.0, 72.0, 144.0, 216.0, 288.0)]
    assert got == want
    cfg = SimConfig.from_json(json.loads((out / "truth" / "scene.json").read_text())["config"])
    assert cfg.rings_deg == (65.0, 10.0) and cfg.n_views() == 11 and cfg.view_angles() == want
    sc = read_scene(out)
    rings = sc.rings()
    assert sorted(set(rings.values()), key=float) == ["0", "10", "65"]
    assert {rings[sc.frames[i].name] for i in sc.test_indices} >= {"10", "65"}   # held out from every ring


def test_a_texture_less_simulated_scene_trains(tmp_path, capsys):
    """`brfgs simulate --scene flat` (no texture by design) then `brfgs train`: the known poses start
    from the ground plane the cameras look at instead of failing on the missing features."""
    scene, run = tmp_path / "flat", tmp_path / "run"
    assert main(["simulate", str(scene), "--scene", "flat", "--size", "32", "--views", "13", "--spp", "4", "--bands",
                 "16", "--dark-frames", "2", "--quiet"]) == 0
    assert main(["train", str(scene), str(run), "--preset", "tiny", "--threads", "1", "--quiet"]) == 0
    report = json.loads((run / "init" / "init_report.json").read_text())
    assert report["poses"] == "known" and "too little texture" in report["fallback"]
    assert json.loads((run / "metrics.json").read_text())["against"]["truth"]["mean"]["psnr"] > 10
