"""Issue 15's machinery: ring-stratified splits and the validation split, per-ring metrics, the
decode order (eq. 13 as published vs per-pixel decoding), the paper preset and the additions study."""

from __future__ import annotations

import json
from dataclasses import fields

import numpy as np
import pytest
import torch

from brfgs.cli import main
from brfgs.data import read_scene
from brfgs.errors import UserError
from brfgs.data.splits import apportion, assign_split, nearest_view_angle_deg, spread_pick, stratified_pick, view_rings, \
    view_spacing_deg
from brfgs.data.splits import split_rule_of
from brfgs.model import RenderSettings, TrainedModel, render
from brfgs.cli.train import build_config
from brfgs.train.config import TrainConfig
from brfgs.train.config_format import REMOVED
from brfgs.train.presets import ADDITIONS, FINE, PAPER_METHOD, PRESETS, preset
from brfgs.workflows.ablate import _runs
from test_train_scene import make_plane_scene

AIR_BRF_ZENITHS = [0.0] + [18.0] * 12 + [23.0] * 12 + [38.0] * 12 + [58.0] * 12


# ----------------------------------------------------------------------------------- splits
def test_view_rings_cluster_zeniths():
    z = [0.0, 17.8, 18.2, 22.8, 23.2, 38.0, 57.7, 58.3]
    assert view_rings(z).tolist() == [0.0, 18.0, 18.0, 23.0, 23.0, 38.0, 58.0, 58.0]


def test_apportion_largest_remainder():
    rng = np.random.default_rng(0)
    assert apportion([1, 12, 12, 12, 12], 7, rng) in ([0, 2, 2, 2, 1], [0, 2, 2, 1, 2], [0, 2, 1, 2, 2],
                                                      [0, 1, 2, 2, 2])
    assert apportion([2, 3], 10, rng) == [2, 3]  # never more than a group holds
    assert apportion([5, 5], 0, rng) == [0, 0]


@pytest.mark.parametrize("seed", range(5))
def test_test_views_come_from_every_ring(seed):
    rings = view_rings(AIR_BRF_ZENITHS)
    test = stratified_pick(list(range(49)), rings, 7, seed)
    assert len(test) == 7 and len(set(test)) == 7
    for ring in (18.0, 23.0, 38.0, 58.0):
        assert 1 <= sum(rings[i] == ring for i in test) <= 2
    assert test == stratified_pick(list(range(49)), rings, 7, seed)  # deterministic


AIR_BRF_AZIMUTHS = [0.0] + [30.0 * k for k in range(12)] * 4


def _dirs(zen, azi):
    from brfgs.data.angles import direction_from_angles_deg

    return np.stack([direction_from_angles_deg(z, a) for z, a in zip(zen, azi)])


def _min_pair_angle_deg(dirs, idx):
    """Smallest angle (deg) between two of the views ``idx``: a float64 loop over pairs."""
    return min(np.degrees(np.arccos(np.clip(dirs[i] @ dirs[j], -1, 1))) for i in idx for j in idx if i < j)


def test_spread_pick_takes_the_farthest_view():
    """One ring of 6 views 60° apart at zenith 40°: with view 0 held out, the farthest view is the opposite one
    (azimuth 180°), whatever the seed; a second pick is any of the four left, each 60° from a held-out view."""
    zen, azi = [40.0] * 6, [60.0 * k for k in range(6)]
    rings, dirs = view_rings(zen), _dirs(zen, azi)
    for seed in range(4):
        assert spread_pick([1, 2, 3, 4, 5], rings, dirs, 1, seed, held=[0]) == [3]
        two = spread_pick([1, 2, 3, 4, 5], rings, dirs, 2, seed, held=[0])
        assert 3 in two and (set(two) - {3}) <= {1, 2, 4, 5}   # after 3, every other view is 60° from a held one


@pytest.mark.parametrize("seed", range(5))
def test_spread_split_holds_out_no_neighbours(seed):
    """On the AIR-BRF layout (nadir + 4 rings x 12 azimuths) the spread rule's test views come from every ring,
    no two test views are neighbours (the smallest angle between two is above 15°), no two held-out views
    (test and validation) are one above the other on the 18° / 23° rings (5°) or side by side on the 18° ring
    (9.2°), and every test view has a training view within 20°."""
    rings, dirs = view_rings(AIR_BRF_ZENITHS), _dirs(AIR_BRF_ZENITHS, AIR_BRF_AZIMUTHS)
    test = spread_pick(list(range(49)), rings, dirs, 7, seed)
    assert test == spread_pick(list(range(49)), rings, dirs, 7, seed)                    # deterministic
    for ring in (18.0, 23.0, 38.0, 58.0):
        assert 1 <= sum(rings[i] == ring for i in test) <= 2
    assert _min_pair_angle_deg(dirs, test) > 15.0
    train = [i for i in range(49) if i not in test]
    val = spread_pick(train, rings, dirs, 7, seed + 1, held=test)
    assert not set(val) & set(test) and _min_pair_angle_deg(dirs, test + val) > 9.3
    assert nearest_view_angle_deg(dirs[test], dirs[train]).max() < 20.1          # the 38° view below a 58° one
    # the random rule holds out neighbours on some seeds: what the spread rule is for
    rnd = [stratified_pick(list(range(49)), rings, 7, s) for s in range(20)]
    assert min(_min_pair_angle_deg(dirs, t) for t in rnd) < 9.3


def test_split_rules_and_old_runs(tmp_path):
    """``random`` is the rule of models of format 1 that name it or predate the option, exactly: their
    test views stay their test views; today's models are split by ``spread``."""
    class F:
        def __init__(self, z, a):
            self.view_zenith_deg, self.view_azimuth_deg, self.split, self.split_given = z, a, "", False

    frames = [F(z, a) for z, a in zip(AIR_BRF_ZENITHS, AIR_BRF_AZIMUTHS)]
    assign_split(frames, 3, "random", validation=True)
    rings = view_rings(AIR_BRF_ZENITHS)
    test = stratified_pick(list(range(49)), rings, 7, 3)
    assert [i for i, f in enumerate(frames) if f.split == "test"] == test
    train = [i for i in range(49) if i not in test]
    assert [i for i, f in enumerate(frames) if f.split == "validation"] == stratified_pick(train, rings, 7, 4)
    written = TrainConfig().to_dict()
    assert "split_rule" not in written and split_rule_of(written) == "spread"
    assert split_rule_of({"split_rule": "spread"}) == "spread" and split_rule_of({}) == "random"
    with pytest.raises(UserError, match="split rule"):
        read_scene(make_plane_scene(tmp_path / "s", w=8, h=6, n_bands=4, n_views=13), split_rule="nearest")


def test_head_learning_rates_decay_log_linearly_over_the_phase():
    """--lr-head-final F: every head rate goes from its start to F x it, log-linearly in the step (a
    float64 reference: start x F**(step/steps)), from --head-lr-decay-from of the phase on; the
    geometry's rates in the joint phase do not move with it; F = 1 gives the constant rates exactly."""
    from brfgs.train.phases import Phase
    from brfgs.train.schedule import learning_rates

    const, cfg = preset("fast", lr_head_final=1.0), preset("fast", lr_head_final=0.1, head_lr_decay_from=0.0)
    assert (preset("fast").lr_head_final, preset("fast").head_lr_decay_from) == (0.1, 0.75)
    for phase, steps in ((Phase.STAGE2, 40), (Phase.JOINT, 40)):
        start = learning_rates(const, phase, 0, steps, 10.0)
        for step in (0, 10, 40):
            got, ref = learning_rates(cfg, phase, step, steps, 10.0), learning_rates(const, phase, step, steps, 10.0)
            assert got.keys() == ref.keys() and {"z_iso", "z_spec", "bg_latent"} <= set(got)
            for k in got:
                want = start[k] * 0.1 ** (step / steps) if k not in ("means", "log_scales", "quats",
                                                                     "opacity_logits") else ref[k]
                assert got[k] == pytest.approx(want, rel=1e-12), (phase, step, k)
        assert learning_rates(const, phase, 40, steps, 10.0)["z_spec"] == const.lr_spec
    held = preset("fast", lr_head_final=0.1, head_lr_decay_from=0.5)  # constant for half the phase, then decaying
    for step, factor in ((0, 1.0), (20, 1.0), (30, 0.1 ** 0.5), (40, 0.1)):
        assert learning_rates(held, Phase.STAGE2, step, 40, 10.0)["z_iso"] == pytest.approx(held.lr_latent * factor)
    with pytest.raises(UserError, match="lr_head_final"):
        preset("fast", lr_head_final=0.0)
    with pytest.raises(UserError, match="head_lr_decay_from"):
        preset("fast", head_lr_decay_from=1.0)


def test_config_file_predating_options_reruns_with_their_values_of_then(tmp_path):
    """``brfgs train --config RUN/config.json`` reads a config.json of format 1 (brfgs 0.1) as the run
    folder does: an option the file predates takes its value of then, not today's default; a removed
    option at its neutral value is dropped, one that was on is refused naming it; today's file is kept."""
    old = tmp_path / "config.json"
    fmt1 = {**{k: v for k, v in TrainConfig().to_dict().items() if k not in ("format_version", "strategy", "mcmc",
                                                                          "max_gaussians")},
            "densify": {**TrainConfig().to_dict()["densify"], "mode": "adc", "max_gaussians": 777, "mcmc_growth": 0.05},
            **{k: (0.2 if v is None else v) for k, v in REMOVED.items()}}  # as brfgs 0.1 wrote them
    gone = {"dssim_per_band", "stage1_kernels", "lr_head_final", "head_lr_decay_from"}
    old.write_text(json.dumps({k: v for k, v in fmt1.items() if k not in gone}))
    cfg = build_config({}, old)
    assert (cfg.dssim_per_band, cfg.stage1_kernels, cfg.max_gaussians, cfg.strategy) == (False, False, 777, "adc")
    assert (cfg.lr_head_final, cfg.head_lr_decay_from) == (1.0, 0.0)  # constant head rates before the option
    assert cfg == TrainConfig.from_run_config(old)
    assert build_config({("max_gaussians",): 512}, old).max_gaussians == 512  # the command line overrides the file
    for removed, value in (("far_field_plane", True), ("refine_steps", 300), ("split_rule", "random")):
        old.write_text(json.dumps({**fmt1, removed: value}))
        with pytest.raises(UserError, match=removed):
            build_config({}, old)
    old.write_text(json.dumps({**fmt1, "densify": {**fmt1["densify"], "mode": "mcmc", "mcmc_growth": 0.2}}))
    cfg = build_config({}, old)
    assert (cfg.strategy, cfg.mcmc.growth, cfg.mcmc.refine_every) == ("mcmc", 0.2, fmt1["densify"]["refine_every"])
    old.write_text(TrainConfig().to_json())
    assert build_config({}, old) == TrainConfig()
    old.write_text(json.dumps({**TrainConfig().to_dict(), "format_version": 3}))
    with pytest.raises(UserError, match="format"):
        build_config({}, old)


def test_nearest_view_angle_against_the_spherical_law_of_cosines():
    """Angles to the nearest training view from (zenith, azimuth) pairs, against a float64 loop over the
    spherical law of cosines (an independent formula: no direction vectors)."""
    from brfgs.data.angles import direction_from_angles_deg

    rng = np.random.default_rng(0)
    held = np.column_stack([rng.uniform(0, 70, 9), rng.uniform(0, 360, 9)])
    train = np.column_stack([rng.uniform(0, 70, 13), rng.uniform(0, 360, 13)])
    dirs = lambda za: np.stack([direction_from_angles_deg(z, a) for z, a in za])  # noqa: E731
    got = nearest_view_angle_deg(dirs(held), dirs(train))
    want = []
    for z1, a1 in np.radians(held):
        c = [np.cos(z1) * np.cos(z2) + np.sin(z1) * np.sin(z2) * np.cos(a1 - a2) for z2, a2 in np.radians(train)]
        want.append(np.degrees(np.arccos(min(1.0, max(c)))))
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert nearest_view_angle_deg(dirs(train[:1]), dirs(train))[0] < 1e-4      # a training view itself: 0°
    assert np.isnan(nearest_view_angle_deg(dirs(held), np.zeros((0, 3)))).all()


def test_view_spacing_of_the_air_brf_layout_and_a_closer_ring():
    """Each view's angle to its nearest other view, from the spherical law of cosines in float64: on the AIR-BRF
    layout 5° on the 18° and 23° rings (one above the other), 15° at 38° (the 23° view below), 20° at 58° (the
    38° view below; the 58° ring's azimuth neighbours are 25.3° apart); a 53° ring brings the 58° views to 5°."""
    def law(zen, azi):
        z, a = np.radians(zen), np.radians(azi)
        c = np.cos(z)[:, None] * np.cos(z)[None] + np.sin(z)[:, None] * np.sin(z)[None] * np.cos(a[:, None] - a[None])
        np.fill_diagonal(c, -1.0)
        return np.degrees(np.arccos(np.clip(c.max(1), -1, 1)))

    zen, azi = np.array(AIR_BRF_ZENITHS), np.array(AIR_BRF_AZIMUTHS)
    got = view_spacing_deg(_dirs(zen, azi))
    np.testing.assert_allclose(got, law(zen, azi), atol=1e-6)
    for ring, want in ((18.0, 5.0), (23.0, 5.0), (38.0, 15.0), (58.0, 20.0)):
        np.testing.assert_allclose(got[zen == ring], want, atol=1e-6)
    zen5, azi5 = np.concatenate([zen, np.full(12, 53.0)]), np.concatenate([azi, np.arange(12) * 30.0])
    np.testing.assert_allclose(view_spacing_deg(_dirs(zen5, azi5))[zen5 == 58.0], 5.0, atol=1e-6)
    assert np.isnan(view_spacing_deg(_dirs([10.0], [0.0]))).all()
    zr, ar = np.random.default_rng(0).uniform(0, 70, 1500), np.random.default_rng(1).uniform(0, 360, 1500)
    np.testing.assert_allclose(view_spacing_deg(_dirs(zr, ar)), law(zr, ar), atol=1e-5)   # blocks of 1024 rows


def test_scene_split_validation_and_rings(tmp_path):
    root = make_plane_scene(tmp_path / "s", w=16, h=12, n_bands=4, n_views=25)
    plain = read_scene(root)
    val = read_scene(root, validation=True)
    assert plain.test_indices == val.test_indices  # the validation split never moves test views
    assert not set(val.validation_indices) & set(val.test_indices)
    assert set(val.validation_indices) <= set(plain.train_indices)
    assert len(val.validation_indices) == round(len(plain.train_indices) / 6)
    rec = val.split_record()
    assert set(rec["rings"]) == {"0", "18", "38"}  # 25 views: nadir + 12 at 18° + 12 at 38°
    near = rec["nearest_train_view_deg"]            # every held-out view, none of the training views
    assert set(near) == set(rec["test"]) | set(rec["validation"])
    # at best the 18° neighbour 30° of azimuth away (2 asin(sin 18° sin 15°) = 9.2°), at worst the view on the
    # next ring at the same azimuth (20°) when both ring neighbours are held out too
    assert all(9.1 <= a <= 20.1 for a in near.values()) and min(near.values()) < 9.3
    for ring in ("18", "38"):  # 4 test views in all: two per ring
        assert len(rec["rings"][ring]["test"]) == 2
    assert "validation" not in plain.split_record()


# ----------------------------------------------------------------------------- presets
def test_paper_preset_is_the_published_method():
    p, f = preset("paper"), preset("fast")
    for name, add in ADDITIONS.items():
        for k, v in add.paper.items():
            assert getattr(p, k) == v, (name, k)
            assert getattr(f, k) != v, f"the fast preset should have addition {name} on ({k})"
    assert p.decode == "gaussian" and not p.learn_normals
    assert p.lambda_normal == p.lambda_flat == p.lambda_depth_smooth == 0
    assert p.lr_spec == p.lr_latent and not p.stage1_cir_bands
    fast_paper = preset("paper-fast")
    for fld in fields(TrainConfig):  # paper-fast = fast's schedule + the paper's method
        if fld.name in PAPER_METHOD:
            assert getattr(fast_paper, fld.name) == PAPER_METHOD[fld.name]
        elif fld.name != "preset":
            assert getattr(fast_paper, fld.name) == getattr(f, fld.name), fld.name
    assert set(PRESETS) >= {"fast", "paper", "paper-fast", "fine", "tiny"}


def test_fine_preset_is_fast_with_supersampled_pixels_and_absgrad():
    f, fine = preset("fast"), preset("fine")
    assert (fine.supersample, fine.supersample_start, fine.densify.absgrad, fine.densify.grow_grad2d) == (2, 0.5, True, 0.0004)
    assert (f.supersample, f.supersample_start, f.densify.absgrad, f.densify.grow_grad2d) == (1, 0.0, False, 0.0002)
    changed = {fld.name for fld in fields(TrainConfig) if getattr(fine, fld.name) != getattr(f, fld.name)}
    assert changed == {"preset", "supersample", "supersample_start", "densify"}
    assert {k for k in vars(fine.densify) if getattr(fine.densify, k) != getattr(f.densify, k)} == {"absgrad", "grow_grad2d"}
    # on the command line an option given beside the preset changes only itself
    cfg = build_config({("preset",): "fine", ("densify", "grow_grad2d"): 0.001})
    assert cfg.densify.absgrad and cfg.densify.grow_grad2d == 0.001 and cfg.supersample == 2
    assert set(FINE) == {"supersample", "supersample_start", "densify"}


def test_additions_study_runs():
    base = preset("tiny")
    runs = {name: (cfg, src) for name, _, cfg, src in _runs("additions", base)}
    assert runs["default"][0].to_json() == TrainConfig.from_dict(base.to_dict()).to_json()
    assert runs["paper"][0].decode == "gaussian"
    for name, add in ADDITIONS.items():
        no, plus = runs[f"no_{name}"], runs[f"paper_{name}"]
        for k, v in add.paper.items():
            assert getattr(no[0], k) == v and getattr(plus[0], k) == getattr(base, k)
        # everything else as in its reference run
        diff = {f.name for f in fields(TrainConfig) if getattr(no[0], f.name) != getattr(base, f.name)}
        assert diff == {k for k, v in add.paper.items() if getattr(base, k) != v}
        assert no[1] == ("default" if add.stage == 2 else None) and plus[1] == ("paper" if add.stage == 2 else None)


# ------------------------------------------------------------------------- decode order
@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("dec")
    scene = make_plane_scene(root / "scene", w=64, h=48, n_bands=8)
    out = root / "run"
    assert main(["train", str(scene), str(out), "--preset", "tiny", "--stage1-steps", "20", "--stage2-steps", "20",
                 "--decode", "gaussian", "--validation", "--threads", "1", "--quiet"]) == 0
    return scene, out


class _Linear(torch.nn.Module):
    """A linear 'decoder' z -> z W + b: blending commutes with it, so both decode orders agree."""

    def __init__(self, d: int, b: int):
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.w = torch.randn(d, b, generator=g) * 0.1
        self.b = torch.rand(b, generator=g) * 0.2

    def decode(self, z):
        return z @ self.w + self.b


def test_decode_orders_agree_for_a_linear_decoder(trained):
    _, out = trained
    tm = TrainedModel.load(out / "model.safetensors")
    assert tm.render_settings.decode_order == "gaussian"
    tm.decoder = _Linear(tm.gaussians.latent_dim, 8)
    cam = tm.cameras[3]
    a = render(tm, cam, decode_order="gaussian", backend="torch")
    b = render(tm, cam, decode_order="pixel", backend="torch")
    assert a.latent is None and b.latent is not None
    np.testing.assert_allclose(a.cube, b.cube, atol=2e-5)
    # and, by hand: blended per-Gaussian spectra plus (1 - alpha) x decoded background
    np.testing.assert_allclose(b.cube, b.latent @ tm.decoder.w.numpy() + tm.decoder.b.numpy(), atol=2e-5)


def test_decode_orders_differ_for_the_trained_decoder(trained):
    _, out = trained
    tm = TrainedModel.load(out / "model.safetensors")
    a = render(tm, tm.cameras[3], backend="torch")  # the model's order: gaussian
    b = render(tm, tm.cameras[3], decode_order="pixel", backend="torch")
    assert np.isfinite(a.cube).all() and a.cube.shape == b.cube.shape
    assert 0 < np.abs(a.cube - b.cube).max() < 0.2


def test_validation_metrics_and_rings(trained):
    scene, out = trained
    val = json.loads((out / "metrics_validation.json").read_text())
    test = json.loads((out / "metrics.json").read_text())
    assert val["evaluated_split"] == "validation" and test["evaluated_split"] == "test"
    names_val = [v["name"] for v in val["against"]["truth"]["views"]]
    assert names_val == val["split"]["validation"] and not set(names_val) & set(test["split"]["test"])
    assert set(names_val).isdisjoint(test["split"]["train"])
    rings = test["against"]["truth"]["rings"]
    assert sum(r["n_views"] for r in rings.values()) == len(test["split"]["test"])
    for ring, m in rings.items():
        views = [v["psnr"] for v in test["against"]["truth"]["views"] if v["name"] in test["split"]["rings"][ring]["test"]]
        assert m["psnr"] == pytest.approx(np.mean(views))
    # each held-out view carries its angle to the nearest training view (split.json's), each ring
    # their mean and largest: how far the ring's metrics extrapolate from the training views
    near = test["split"]["nearest_train_view_deg"]
    for block in (test, val):
        views = block["against"]["truth"]["views"]
        assert all(v["nearest_train_view_deg"] == near[v["name"]] > 0 for v in views)
        for ring, m in block["against"]["truth"]["rings"].items():
            ang = [near[n] for n in block["split"]["rings"][ring][block["evaluated_split"]]]
            assert m["nearest_train_view_deg"]["mean"] == pytest.approx(np.mean(ang), abs=0.05)
            assert m["nearest_train_view_deg"]["max"] == max(ang)


def test_evaluate_scores_the_training_views_on_request(trained, capsys):
    """--split train: the fit of the model's own training views (metrics_train.json), none held out."""
    _, out = trained
    assert main(["evaluate", str(out), "--split", "train", "--quiet", "--no-images"]) == 0
    assert "metrics_train.json" in capsys.readouterr().out
    fit = json.loads((out / "metrics_train.json").read_text())
    test = json.loads((out / "metrics.json").read_text())
    assert fit["evaluated_split"] == "train"
    views = fit["against"]["truth"]["views"]
    assert [v["name"] for v in views] == test["split"]["train"]
    assert not any("nearest_train_view_deg" in v for v in views)  # a training view is its own nearest
    rings = fit["against"]["truth"]["rings"]
    assert sum(r["n_views"] for r in rings.values()) == len(views)
    assert all("nearest_train_view_deg" not in r for r in rings.values())
    assert fit["against"]["truth"]["mean"]["psnr"] == pytest.approx(np.mean([v["psnr"] for v in views]))


def test_validation_split_needs_a_validation_run(trained, tmp_path, capsys):
    root, _ = trained
    out = tmp_path / "r"
    assert main(["train", str(root), str(out), "--preset", "tiny", "--stage1-steps", "2", "--stage2-steps", "2",
                 "--threads", "1", "--quiet", "--no-evaluate"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(out), "--split", "validation", "--quiet"]) == 2
    assert "--validation" in capsys.readouterr().err


def test_antialiased_model_trains_and_renders_with_the_filter(trained, tmp_path):
    """--antialias is a model property: it trains with the filter and renders with it (less alpha
    than the same model rendered without the opacity compensation)."""
    scene, _ = trained
    out = tmp_path / "aa"
    assert main(["train", str(scene), str(out), "--preset", "tiny", "--stage1-steps", "20", "--stage2-steps", "4",
                 "--antialias", "--threads", "1", "--quiet", "--no-evaluate"]) == 0
    tm = TrainedModel.load(out / "model.safetensors")
    assert tm.render_settings.antialias and json.loads((out / "config.json").read_text())["antialias"] is True
    with_filter = render(tm, tm.cameras[0], backend="torch")
    tm.render_settings = RenderSettings(decode_order=tm.render_settings.decode_order, antialias=False)
    without = render(tm, tm.cameras[0], backend="torch")
    assert np.isfinite(with_filter.cube).all()
    assert with_filter.alpha.sum() < without.alpha.sum()


def test_supersampling_starts_late_in_geometry_phases_only(trained, tmp_path, monkeypatch):
    """--supersample-start f: a geometry phase rasterizes one sample per pixel before f of its
    steps and s x s after; stage 2 supersamples from its first step."""
    from brfgs.train import step as step_mod
    cfg = preset("fine")
    cfg.supersample_start = 0.5
    assert [step_mod.supersample_now(cfg, step_mod.Phase.STAGE1, k, 10) for k in (0, 4, 5, 9)] == [1, 1, 2, 2]
    assert step_mod.supersample_now(cfg, step_mod.Phase.STAGE2, 0, 10) == 2
    seen, orig = [], step_mod._rasterize
    monkeypatch.setattr(step_mod, "_rasterize", lambda *a, **k: seen.append(k["ss"]) or orig(*a, **k))
    scene, _ = trained
    assert main(["train", str(scene), str(tmp_path / "late"), "--preset", "tiny", "--stage1-steps", "10",
                 "--stage2-steps", "4", "--supersample", "2", "--supersample-start", "0.5", "--threads", "1",
                 "--quiet", "--no-evaluate"]) == 0
    assert seen == [1] * 5 + [2] * 9
    assert main(["train", str(scene), str(tmp_path / "bad"), "--supersample-start", "1.5", "--quiet"]) == 2


def test_table2_runs_fit_the_selected_bands_only_in_stage_1():
    runs = _runs("bands", preset("fast"))
    assert len(runs) == 8 and len({cfg.band_strategy for _, _, cfg, _ in runs}) == 8
    assert all(not cfg.stage1_cir_bands for _, _, cfg, _ in runs)
    # every other option as given: the paper's tables with the paper's method come from --preset paper-fast
    assert all(cfg.lr_spec == 1e-2 for _, _, cfg, _ in _runs("kernels", preset("paper-fast")))


def test_stage1_kernel_colours_follow_the_kernels(trained, tmp_path):
    """--stage1-kernels (the default): a stage-1 colour is c_iso + c_vol K_Ross + c_geo K_Li (eq. 12 on
    the stage-1 bands), against the float64 MODIS kernels of brfgs.brdf.reference; a run trains them,
    --stage1-flat-colours (the paper) does not have them."""
    from brfgs.brdf.reference import li_sparse_r_ref, ross_thick_ref
    from brfgs.brdf.geometry import view_directions
    from brfgs.model.features import stage1_colors
    from brfgs.model.gaussians import GaussianModel
    g = torch.Generator().manual_seed(0)
    n, k = 5, 3
    params = {"means": torch.randn(n, 3, generator=g) * 5, "log_scales": torch.zeros(n, 3), "quats": torch.tensor([[1.0, 0, 0, 0]] * n),
              "opacity_logits": torch.zeros(n), "colors": torch.rand(n, k, generator=g),
              "colors_kernels": torch.randn(n, 2, k, generator=g)}
    gm = GaussianModel(params, "brf", 4, k)
    tm = TrainedModel.load(trained[1] / "model.safetensors")
    cam = tm.cameras[3]
    sun = torch.tensor([0.3, -0.2, 0.0])
    sun[2] = (1 - (sun[:2] ** 2).sum()).sqrt()
    got = stage1_colors(gm, cam, sun).detach().numpy()
    wo = view_directions(gm.means, cam.centre).detach().numpy().astype(np.float64)  # [N, 3]
    wi = np.broadcast_to(sun.numpy().astype(np.float64), wo.shape)
    ti, tv = (torch.as_tensor(np.arccos(w[:, 2])) for w in (wi, wo))  # zeniths, rad
    phi = torch.as_tensor(np.arctan2(wi[:, 1], wi[:, 0]) - np.arctan2(wo[:, 1], wo[:, 0]))  # relative azimuth
    kv, kg = ross_thick_ref(ti, tv, phi).numpy(), li_sparse_r_ref(ti, tv, phi).numpy()  # [N], float64
    c = params["colors"].numpy().astype(np.float64)
    ck = params["colors_kernels"].numpy().astype(np.float64)
    np.testing.assert_allclose(got, c + kv[:, None] * ck[:, 0] + kg[:, None] * ck[:, 1], rtol=1e-4, atol=1e-5)

    gm64 = GaussianModel({name: v.double() for name, v in params.items()}, "brf", 4, k)

    def colours64(means, colors, kernels):  # float64: the gradients against finite differences
        gm64.params.update(means=means, colors=colors, colors_kernels=kernels)
        return stage1_colors(gm64, cam, sun.double())
    leaves = [params[name].double().requires_grad_(True) for name in ("means", "colors", "colors_kernels")]
    assert torch.autograd.gradcheck(colours64, leaves, eps=1e-6, atol=1e-6)
    p = tm.gaussians.params  # the default (an addition) trains them
    assert p["colors_kernels"].shape[1:] == (2, p["colors"].shape[1]) and p["colors_kernels"].abs().sum() > 0
    scene, _ = trained
    out = tmp_path / "flat"  # the paper's view-independent stage-1 colours
    assert main(["train", str(scene), str(out), "--preset", "tiny", "--stage1-steps", "12", "--stage2-steps", "4",
                 "--stage1-flat-colours", "--threads", "1", "--quiet", "--no-evaluate"]) == 0
    assert "colors_kernels" not in TrainedModel.load(out / "model.safetensors").gaussians.params
    assert not preset("paper").stage1_kernels and not preset("paper-fast").stage1_kernels


def test_every_phase_scores_whole_views_unless_the_image_is_larger_than_a_patch():
    """Stage 2 renders the whole 64 x 64 view whatever ``stage2_rays`` is (it samples pixels after
    rendering), and so do the joint phase and stage 2 with --decode gaussian; --patch-px patches only
    cut larger images."""
    from types import SimpleNamespace

    import torch

    from brfgs.train.phases import Phase
    from brfgs.train.step import pick_view

    def window(phase, **cfg):
        st = SimpleNamespace(perm=[], gen=torch.Generator().manual_seed(0))
        return pick_view(st, [0, 1, 2], 64, 64, TrainConfig(**cfg), phase)[1]

    assert TrainConfig().stage2_rays == 0
    assert window(Phase.STAGE2) is None and window(Phase.STAGE2, stage2_rays=2048) is None
    assert window(Phase.JOINT) is None and window(Phase.STAGE2, decode="gaussian") is None
    assert window(Phase.STAGE1, patch_px=32)[2:] == (32, 32)
    with pytest.raises(UserError, match="patch_px"):
        TrainConfig(patch_px=-1).validate()


