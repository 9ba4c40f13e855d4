"""brfgs compare: paired margins of two evaluated runs with a bootstrap over the held-out views."""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import pytest
import torch

from brfgs.evaluation import compare as C
from brfgs.errors import UserError


def _scores(psnr, sam, rings=None, views=None, label="run"):
    n = len(psnr)
    views = views or [f"v{i:02d}" for i in range(n)]
    return C.Scores(label, views, rings or ["18"] * n, np.asarray(psnr, float), np.asarray(sam, float))


def _metrics(views: list[tuple[str, str, float, float]], truth: bool = True, scene: str = "s") -> dict:
    """A metrics.json in the schema of docs/data-format.md: (name, ring, psnr, sam) per view."""
    rings: dict = {}
    for name, ring, _, _ in views:
        rings.setdefault(ring, {"train": [], "test": []})["test"].append(name)
    block = {"mean": {}, "views": [{"name": n, "psnr": p, "ssim": 0.9, "sam": s} for n, _, p, s in views]}
    out = {"scene": scene, "model": "BRF-GS", "split": {"rings": rings}, "against": {"observed": copy.deepcopy(block)}}
    if truth:
        out["against"]["truth"] = block
    return out


def _write_run(path, metrics: dict, name: str = "metrics.json"):
    path.mkdir(parents=True, exist_ok=True)
    (path / name).write_text(json.dumps(metrics))
    return path


def test_statistics_match_a_loop_over_the_draws():
    rng = np.random.default_rng(3)
    a = _scores(rng.normal(30, 2, 9), rng.uniform(0.02, 0.04, 9))
    b = _scores(rng.normal(29, 2, 9), rng.uniform(0.02, 0.05, 9))
    res = C.compare_block(a, b, np.arange(9), n_resamples=500, seed=7)
    idx = C.bootstrap_indices(9, 500, 7)
    m_loop, r_loop = [], []
    for row in idx:  # float64 reference, one resample at a time
        m_loop.append(sum(a.psnr_db[i] for i in row) / 9 - sum(b.psnr_db[i] for i in row) / 9)
        r_loop.append(sum(a.sam_rad[i] for i in row) / sum(b.sam_rad[i] for i in row))
    assert res["margin_db"] == pytest.approx(a.psnr_db.mean() - b.psnr_db.mean())
    assert res["sam_ratio"] == pytest.approx(a.sam_rad.mean() / b.sam_rad.mean())
    np.testing.assert_allclose(res["margin_db_ci95"], np.percentile(m_loop, [2.5, 97.5]), rtol=1e-12)
    np.testing.assert_allclose(res["sam_ratio_ci95"], np.percentile(r_loop, [2.5, 97.5]), rtol=1e-12)
    # the same seed gives the same draw; another seed another one
    assert np.array_equal(idx, C.bootstrap_indices(9, 500, 7))
    assert not np.array_equal(idx, C.bootstrap_indices(9, 500, 8))


def test_a_constant_shift_has_a_zero_width_interval():
    b = _scores([30.0, 28.0, 31.5, 25.0], [0.03, 0.02, 0.05, 0.04])
    a = _scores(b.psnr_db + 1.25, b.sam_rad * 0.7)
    res = C.compare_block(a, b, np.arange(4), 1000, 0)
    assert res["margin_db"] == pytest.approx(1.25) and res["sam_ratio"] == pytest.approx(0.7)
    np.testing.assert_allclose(res["margin_db_ci95"], [1.25, 1.25])
    np.testing.assert_allclose(res["sam_ratio_ci95"], [0.7, 0.7])
    assert "margin_db_ci95" not in C.compare_block(a, b, np.arange(2), 1000, 0)  # too few views for one


def test_the_interval_covers_the_true_margin_about_95_percent_of_the_time():
    # views drawn i.i.d.: the paired difference has mean 0.5 dB; a correct 95 % interval covers it in
    # about 95 % of repeated experiments (a 50 % interval would cover it in about half)
    rng = np.random.default_rng(11)
    hits = 0
    for k in range(300):
        b = rng.normal(30.0, 2.0, 25)
        a = b + 0.5 + rng.normal(0.0, 0.6, 25)
        lo, hi = C.compare_block(_scores(a, np.full(25, 0.03)), _scores(b, np.full(25, 0.03)), np.arange(25),
                                 1000, k)["margin_db_ci95"]
        hits += lo <= 0.5 <= hi
    assert 0.88 <= hits / 300 <= 0.99


def test_seeds_are_averaged_per_view_and_paired_in_order():
    flat = ["all"] * 3  # no view rings in the files
    a1, a2 = _scores([30, 31, 32], [0.02] * 3, flat), _scores([32, 33, 34], [0.04] * 3, flat)
    b1, b2 = _scores([29, 30, 31], [0.04] * 3, flat), _scores([29, 30, 31], [0.04] * 3, flat)
    res = C.compare([a1, a2], [b1, b2], n_resamples=200, seed=0)
    assert res["all"]["psnr_a_db"] == pytest.approx(32.0) and res["all"]["margin_db"] == pytest.approx(2.0)
    assert res["all"]["sam_ratio"] == pytest.approx(0.75)
    assert [p["margin_db"] for p in res["seed_pairs"]] == pytest.approx([1.0, 3.0])
    assert [p["sam_ratio"] for p in res["seed_pairs"]] == pytest.approx([0.5, 1.0])
    no_rings = C.compare([a1], [b1], n_resamples=200)
    assert no_rings["rings"] == {} and no_rings["all"]["n_views"] == 3
    mixed = C.compare([_scores([1, 2, 3], [0.1] * 3, rings=["58", "all", "nadir"])],
                      [_scores([1, 2, 2], [0.1] * 3, rings=["58", "all", "nadir"])], n_resamples=200)
    assert list(mixed["rings"]) == ["58", "nadir", "all"]
    with pytest.raises(UserError, match="as many runs"):
        C.compare([a1, a2], [b1], n_resamples=200)
    with pytest.raises(UserError, match="different views"):
        C.compare([a1], [_scores([1, 2, 3], [0.1] * 3, views=["x", "y", "z"])])


def test_read_scores_maps_views_to_rings_and_names_bad_fields(tmp_path):
    views = [("v2_z58", "58", 25.0, 0.05), ("v1_z18", "18", 32.0, 0.02), ("v3_z18", "18", 31.0, 0.03)]
    run = _write_run(tmp_path / "run", _metrics(views))
    s = C.read_scores(run)
    assert s.views == ["v1_z18", "v2_z58", "v3_z18"] and s.rings == ["18", "58", "18"] and s.scene == "s"
    assert list(s.psnr_db) == [32.0, 25.0, 31.0]
    with pytest.raises(UserError, match="metrics_validation.json"):
        C.read_scores(run, split="validation")
    with pytest.raises(UserError, match=r"metrics_train.json.*brfgs evaluate RUN --split train"):
        C.read_scores(run, split="train")
    bad = _metrics(views)
    bad["against"]["truth"]["views"][1]["sam"] = None
    bad["against"]["truth"]["views"][1]["sam_reason"] = "no truth cube"
    with pytest.raises(UserError, match=r"field 'against.truth.views\[1\].sam'.*no truth cube"):
        C.read_scores(_write_run(tmp_path / "bad", bad))
    with pytest.raises(UserError, match="use --against observed"):
        C.read_scores(_write_run(tmp_path / "obs", _metrics(views, truth=False)))
    assert C.read_scores(tmp_path / "obs", against="observed").views == s.views
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "metrics.json").write_text("{not json")
    with pytest.raises(UserError, match="not valid JSON"):
        C.read_scores(tmp_path / "junk")


def test_cli_compares_evaluated_runs(tmp_path, capsys):
    from brfgs.cli import main
    from test_train_cli import TINY
    from test_train_scene import make_plane_scene
    torch.set_num_threads(1)
    scene = make_plane_scene(tmp_path / "scene", w=64, h=48, n_bands=12)
    run = tmp_path / "run"
    assert main(["train", str(scene), str(run), *TINY]) == 0  # the real metrics.json of brfgs evaluate
    m = json.loads((run / "metrics.json").read_text())
    for v in m["against"]["truth"]["views"]:
        v["psnr"] += 0.5
        v["sam"] *= 0.8
    better = _write_run(tmp_path / "better", m)
    capsys.readouterr()
    assert main(["compare", str(better), str(run), "--json", str(tmp_path / "cmp.json")]) == 0
    out = capsys.readouterr().out
    res = json.loads((tmp_path / "cmp.json").read_text())
    n = len(m["against"]["truth"]["views"])
    assert res["all"]["n_views"] == n and res["all"]["margin_db"] == pytest.approx(0.5)
    assert res["all"]["sam_ratio"] == pytest.approx(0.8)
    assert sum(blk["n_views"] for blk in res["rings"].values()) == n and "all" not in res["rings"]
    assert "| all |" in out and "+0.50" in out and "0.800" in out
    # observed scores were left alone: no margin there
    assert main(["compare", str(better), str(run), "--against", "observed"]) == 0
    assert "| all |" in capsys.readouterr().out
    # user errors: one line naming the file, exit 2
    assert main(["compare", str(better), str(tmp_path / "missing")]) == 2
    assert "missing/metrics.json" in capsys.readouterr().err
    assert main(["compare", f"{better},{run}", str(run)]) == 2
    assert "as many runs" in capsys.readouterr().err
    assert main(["compare", str(better), str(run), "--split", "held-out"]) == 2
    assert "--split" in capsys.readouterr().err


def _scene_pair(rng, n, shift_db, ratio, rings=None):
    b = _scores(rng.normal(30, 2, n), rng.uniform(0.02, 0.04, n), rings)
    a = _scores(b.psnr_db + shift_db + rng.normal(0, 0.3, n), b.sam_rad * ratio * rng.uniform(0.9, 1.1, n), rings)
    return a, b


def test_pooled_statistics_match_a_loop_over_the_stratified_draws():
    from brfgs.evaluation import compare_scenes as CS
    rng = np.random.default_rng(5)
    pairs = [_scene_pair(rng, n, d, r) for n, d, r in [(7, 0.5, 0.9), (5, -0.2, 1.1), (9, 0.1, 1.0)]]
    res = CS.compare_scenes([a for a, _ in pairs], [b for _, b in pairs], n_resamples=400, seed=3)
    per_m = [a.psnr_db.mean() - b.psnr_db.mean() for a, b in pairs]
    per_r = [a.sam_rad.mean() / b.sam_rad.mean() for a, b in pairs]
    assert res["all"]["margin_db"] == pytest.approx(np.mean(per_m))
    assert res["all"]["sam_ratio"] == pytest.approx(np.prod(per_r) ** (1 / 3))
    m_loop, r_loop = [], []
    draws = [C.bootstrap_indices(len(a.views), 400, 3 + i) for i, (a, _) in enumerate(pairs)]  # scene i: seed + i
    for k in range(400):  # float64 reference, one resample at a time
        ms, rs = [], []
        for (a, b), idx in zip(pairs, draws):
            row = idx[k]
            ms.append(sum(a.psnr_db[i] for i in row) / len(row) - sum(b.psnr_db[i] for i in row) / len(row))
            rs.append(sum(a.sam_rad[i] for i in row) / sum(b.sam_rad[i] for i in row))
        m_loop.append(sum(ms) / 3)
        r_loop.append(float(np.prod(rs)) ** (1 / 3))
    np.testing.assert_allclose(res["all"]["margin_db_ci95"], np.percentile(m_loop, [2.5, 97.5]), rtol=1e-12)
    np.testing.assert_allclose(res["all"]["sam_ratio_ci95"], np.percentile(r_loop, [2.5, 97.5]), rtol=1e-12)
    # each scene's row is brfgs compare's block with that scene's seed
    for i, (a, b) in enumerate(pairs):
        ref = C.compare_block(a, b, np.arange(len(a.views)), 400, 3 + i)
        assert res["scenes"][i]["margin_db_ci95"] == ref["margin_db_ci95"]


def test_pooled_rows_weigh_scenes_equally_and_tally_the_verdicts():
    from brfgs.evaluation import compare_scenes as CS
    rings = ["18", "18", "58", "58", "58"]
    b1 = _scores([30, 31, 25, 26, 24], [0.03, 0.02, 0.05, 0.04, 0.06], rings)
    b2 = _scores([28, 29, 27, 22, 23, 21, 20, 24, 25], [0.03] * 9, ["18", "18"] + ["58"] * 7)
    a1 = _scores(b1.psnr_db + 1.0, b1.sam_rad * 0.8, rings)   # better everywhere by a constant
    a2 = _scores(b2.psnr_db - 0.5, b2.sam_rad * 1.25, b2.rings)  # worse everywhere by a constant
    res = CS.compare_scenes([a1, a2], [b1, b2], n_resamples=300)
    assert res["all"]["margin_db"] == pytest.approx(0.25)  # (1.0 − 0.5) / 2, not weighted by views
    assert res["all"]["sam_ratio"] == pytest.approx(1.0)  # sqrt(0.8 × 1.25)
    np.testing.assert_allclose(res["all"]["margin_db_ci95"], [0.25, 0.25])
    assert [s["psnr_verdict"] for s in res["scenes"]] == [1, -1]  # better beyond the views' noise, worse
    assert [s["sam_verdict"] for s in res["scenes"]] == [1, -1]
    assert list(res["rings"]) == ["18", "58"] and res["rings"]["58"]["n_views"] == 10
    lines = CS.report_lines(res)
    assert any(line.startswith("| **mean of 2 scenes** | 14 |") for line in lines)
    # a scene with one view in a ring gives the pooled ring no interval; a ring one scene lacks is left out
    c = _scores([30, 31, 32, 29], [0.03] * 4, ["18", "18", "18", "38"])
    res = CS.compare_scenes([a1, _scores(c.psnr_db + 1, c.sam_rad, c.rings)], [b1, c], n_resamples=300)
    assert list(res["rings"]) == ["18"]
    with pytest.raises(UserError, match="as many runs"):
        CS.compare_scenes([a1, a2], [b1])
    with pytest.raises(UserError, match="two or more scenes"):
        CS.compare_scenes([a1], [b1])
    with pytest.raises(UserError, match="different views"):
        CS.compare_scenes([a1, a2], [b2, b1])


def test_seeds_of_one_scene_are_averaged_and_the_scene_counts_once():
    from brfgs.evaluation import compare_scenes as CS
    rng = np.random.default_rng(8)
    s1 = [_scene_pair(rng, 7, d, r) for d, r in [(0.6, 0.9), (0.2, 1.0)]]  # two training seeds of scene "s1"
    s2 = _scene_pair(rng, 5, -0.3, 1.1)
    for k, (a, b) in enumerate(s1):
        a.scene = b.scene = "s1"
        a.label, b.label = f"a_seed{k}", f"b_seed{k}"
    s2[0].scene = s2[1].scene = "s2"
    runs_a = [s1[0][0], s2[0], s1[1][0]]  # the seeds need not be given side by side
    runs_b = [s1[0][1], s2[1], s1[1][1]]
    res = CS.compare_scenes(runs_a, runs_b, n_resamples=300, seed=1)
    assert len(res["scenes"]) == 2 and [s["n_seeds"] for s in res["scenes"]] == [2, 1]
    a_mean, b_mean = C.seed_mean([s1[0][0], s1[1][0]]), C.seed_mean([s1[0][1], s1[1][1]])
    ref = C.compare_block(a_mean, b_mean, np.arange(7), 300, 1)  # scene 0's row: the per-view seed means
    assert res["scenes"][0]["margin_db"] == pytest.approx(np.mean([a.psnr_db.mean() - b.psnr_db.mean() for a, b in s1]))
    assert res["scenes"][0]["margin_db_ci95"] == ref["margin_db_ci95"]
    assert res["scenes"][0]["sam_ratio_ci95"] == ref["sam_ratio_ci95"]
    m2 = s2[0].psnr_db.mean() - s2[1].psnr_db.mean()
    assert res["all"]["margin_db"] == pytest.approx((ref["margin_db"] + m2) / 2)  # each scene once, not each pair
    assert res["all"]["n_scenes"] == 2 and res["all"]["n_views"] == 12


def test_cli_pools_scenes(tmp_path, capsys):
    from brfgs.cli import main
    rng = np.random.default_rng(2)
    runs = {}
    for scene in ("s1", "s2", "s3"):
        base = [(f"v{i}", "18" if i < 4 else "58", float(rng.normal(30, 2)), float(rng.uniform(0.02, 0.04)))
                for i in range(7)]  # the simulator names the views alike in every scene
        runs[scene] = (_write_run(tmp_path / scene / "a", _metrics([(n, r, p + 0.4, s * 0.9) for n, r, p, s in base],
                                                                   scene=scene), "metrics_validation.json"),
                       _write_run(tmp_path / scene / "b", _metrics(base, scene=scene), "metrics_validation.json"))
    a = ",".join(str(v[0]) for v in runs.values())
    b = ",".join(str(v[1]) for v in runs.values())
    capsys.readouterr()
    assert main(["compare", a, b, "--scenes", "--split", "validation", "--json", str(tmp_path / "p.json")]) == 0
    out = capsys.readouterr().out
    res = json.loads((tmp_path / "p.json").read_text())
    assert res["all"]["margin_db"] == pytest.approx(0.4) and res["all"]["sam_ratio"] == pytest.approx(0.9)
    assert len(res["scenes"]) == 3 and res["split"] == "validation"
    assert "**mean of 3 scenes** | 21 |" in out and "mean, 58° ring" in out and "on 3/0/0 scenes" in out
    assert f"| s2: {runs['s2'][0]} vs {runs['s2'][1]} | 7 |" in out  # rows named by the scene
    assert main(["compare", a, str(runs["s1"][1]), "--scenes", "--split", "validation"]) == 2
    assert "as many runs" in capsys.readouterr().err
    # a pair from two scenes (same view names), or one scene given twice: an input error naming it
    swapped = f"{runs['s2'][1]},{runs['s1'][1]},{runs['s3'][1]}"
    assert main(["compare", a, swapped, "--scenes", "--split", "validation"]) == 2
    assert "different scenes" in capsys.readouterr().err
    twice = f"{runs['s1'][0]},{runs['s1'][0]},{runs['s2'][0]}"
    assert main(["compare", twice, f"{runs['s1'][1]},{runs['s1'][1]},{runs['s2'][1]}", "--scenes", "--split",
                 "validation"]) == 2
    assert "given twice for scene" in capsys.readouterr().err
    # two pairs of one scene only are its seeds: nothing to pool over scenes
    seeds_only = f"{runs['s1'][0]},{tmp_path / 's1' / 'a2'}"
    shutil.copytree(runs["s1"][0], tmp_path / "s1" / "a2")
    shutil.copytree(runs["s1"][1], tmp_path / "s1" / "b2")
    assert main(["compare", seeds_only, f"{runs['s1'][1]},{tmp_path / 's1' / 'b2'}", "--scenes", "--split",
                 "validation"]) == 2
    assert "two or more scenes, got 1" in capsys.readouterr().err
    assert main(["compare", str(runs["s1"][0]), str(runs["s2"][1]), "--split", "validation"]) == 2
    assert "different scenes" in capsys.readouterr().err
