"""CLI: brfgs train / evaluate / ablate in-process on a tiny scene; metrics.json schema."""

import json

import pytest
import torch

from brfgs.cli import main
from brfgs.data import read_scene
from test_train_scene import make_plane_scene

KEYS = ("psnr", "ssim", "lpips", "sam", "psnr_spectral")
TINY = ["--preset", "tiny", "--quiet", "--threads", "1", "--stage1-steps", "6", "--stage2-steps", "4"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("cli") / "scene", w=64, h=48, n_bands=12)


def _check_block(block, n_test, spectral=True):
    assert len(block["views"]) == n_test
    for m in [block["mean"], *block["views"]]:
        for k in KEYS:
            assert k in m
            if m[k] is None:
                assert m[f"{k}_reason"]
        if spectral:
            assert m["sam"] is not None and 0 <= m["sam"] < 1.6
        assert m["psnr"] is not None and m["ssim"] is not None


def test_train_evaluate_cli(scene, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", str(scene), str(out), *TINY]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["scene"] == "scene" and m["model"] == "BRF-GS"
    sc = read_scene(scene)  # the default split, spread over the view directions: 13 views (nadir + a 38° ring)
    test = [sc.frames[i].name for i in sc.test_indices]
    assert m["split"]["test"] == test and m["split"]["split_rule"] == "spread" and len(test) == 2
    az = sorted(sc.frames[i].view_azimuth_deg for i in sc.test_indices)  # the ring's two held-out views: opposite
    assert {sc.rings()[n] for n in test} == {"38"} and az[1] - az[0] == pytest.approx(180.0)
    _check_block(m["against"]["observed"], 2)
    _check_block(m["against"]["truth"], 2)
    assert m["settings"]["config"]["stage1_steps"] == 6
    assert (out / "eval" / "renders" / f"{test[0]}.hdr").is_file()
    assert (out / "eval" / "cir" / f"{test[0]}_vs_truth.png").is_file()
    # a finished run is never overwritten without --overwrite (exit status 2, message)
    assert main(["train", str(scene), str(out), *TINY]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["evaluate", str(out), "--quiet", "--no-images", "--backend", "torch"]) == 0
    # 3DGS-on-CIR baseline: no spectra, SAM null with reason
    out2 = tmp_path / "cir"
    assert main(["train", str(scene), str(out2), *TINY, "--variant", "cir"]) == 0
    m2 = json.loads((out2 / "metrics.json").read_text())
    _check_block(m2["against"]["truth"], 2, spectral=False)
    assert m2["against"]["truth"]["mean"]["sam"] is None and "CIR" in m2["against"]["truth"]["mean"]["sam_reason"]


def test_bad_options_are_user_errors(scene, tmp_path, capsys):
    assert main(["train", str(scene), str(tmp_path / "x"), "--variant", "nope", "--quiet"]) == 2
    assert "variant" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing"), "--quiet"]) == 2
    for opts, field in ((["--supersample", "5"], "supersample"), (["--lambda-normal", "-1"], "lambda_normal"),
                        (["--lambda-flat", "-0.1"], "lambda_flat"), (["--lambda-depth-smooth", "-1"], "lambda_depth_smooth"),
                        (["--strategy", "other"], "strategy"), (["--lr-spec", "0"], "lr_spec"),
                        (["--mcmc-growth", "-0.1"], "mcmc.growth"), (["--max-gaussians", "-1"], "max_gaussians"),
                        (["--init-fill", "dream"], "init_fill")):
        capsys.readouterr()
        assert main(["train", str(scene), str(tmp_path / "y"), *opts, "--quiet"]) == 2
        assert field in capsys.readouterr().err
        assert not (tmp_path / "y" / "run.json").exists()


def test_ablate_training_cli(scene, tmp_path):
    out = tmp_path / "abl"
    assert main(["ablate", str(scene), str(out), "--study", "training", "--preset", "tiny", "--quiet",
                 "--threads", "1", "--stage1-steps", "4", "--stage2-steps", "4"]) == 0
    md = (out / "table_training.md").read_text()
    assert "Joint optimization" in md and "BRF-GS (Full)" in md
    csv = (out / "table_training.csv").read_text().splitlines()
    assert len(csv) == 3 and "sam_truth" in csv[0]
    # each row against its reference (joint against full): the margin and SAM ratio of the per-view scores
    rows = {r["run"]: r for r in ablate_rows(out, "training")}
    assert "vs" not in rows["full"] and rows["joint"]["vs"] == "full"
    views = {n: json.loads((out / n / "metrics.json").read_text())["against"]["observed"]["views"]
             for n in ("joint", "full")}
    psnr = {n: sum(v["psnr"] for v in vs) / len(vs) for n, vs in views.items()}
    sam = {n: sum(v["sam"] for v in vs) / len(vs) for n, vs in views.items()}
    joint = rows["joint"]
    assert joint["dpsnr_observed"] == pytest.approx(psnr["joint"] - psnr["full"], abs=1e-9)
    assert joint["sam_ratio_observed"] == pytest.approx(sam["joint"] / sam["full"], rel=1e-9)
    assert len(views["full"]) < 3 and "dpsnr_observed_ci95_lo" not in joint  # too few views for an interval
    assert "| full |" in md and "ΔPSNR [95 %]" in md


def test_ablate_tables_take_a_run_another_call_finished_meanwhile(scene, tmp_path, monkeypatch):
    """Two `brfgs ablate --only` calls side by side: the call that ends last writes the tables with the
    other call's run, also when that run finished while this call trained (the tables once lacked one)."""
    import brfgs.workflows.ablate as ablate_mod

    out = tmp_path / "abl"
    opts = ["--study", "training", "--preset", "tiny", "--quiet", "--threads", "1", "--stage1-steps", "4",
            "--stage2-steps", "4"]
    real_train = ablate_mod.train

    def other_call_finishes_joint_first(scene_path, rdir, cfg, **kw):
        if rdir.name == "full":  # "joint" comes first in the study: this call had passed it unfinished
            assert main(["ablate", str(scene), str(out), *opts, "--only", "joint"]) == 0
            assert "BRF-GS (Full)" not in (out / "table_training.md").read_text()
        return real_train(scene_path, rdir, cfg, **kw)

    monkeypatch.setattr(ablate_mod, "train", other_call_finishes_joint_first)
    assert main(["ablate", str(scene), str(out), *opts, "--only", "full"]) == 0
    md = (out / "table_training.md").read_text()
    assert "Joint optimization" in md and "BRF-GS (Full)" in md


def test_every_training_option_is_on_the_command_line():
    """The options of brfgs train are generated from TrainConfig: every field (the strategies' nested
    fields too) is an option, none is listed by hand; --help lists at most 40 (the method's), and
    --help-all also the experimental and expert ones."""
    import dataclasses

    import typer.main

    from brfgs.cli import app
    from brfgs.cli._config import config_options
    from brfgs.model import ADCConfig, MCMCConfig
    from brfgs.train.config import TrainConfig

    cmd = typer.main.get_command(app).commands["train"]
    flags = {f for p in cmd.params for f in p.opts + p.secondary_opts}
    expected = config_options(TrainConfig)
    nested = {"densify": ADCConfig, "mcmc": MCMCConfig}
    n_fields = sum(len(dataclasses.fields(nested[f.name])) if f.name in nested else 1 for f in dataclasses.fields(TrainConfig))
    assert len(expected) == n_fields
    for opt in expected:
        assert opt.flag.split("/")[0] in flags, opt.flag
    assert "--densify-refine-every" in flags and "--mcmc-growth" in flags and "--ae-steps" in flags
    shown = [p for p in cmd.params if getattr(p, "param_type_name", "") == "option" and not p.hidden]
    assert len(shown) <= 40, len(shown)
    assert {"--preset", "--stage1-steps", "--strategy", "--help-all"} <= {o for p in shown for o in p.opts}


def test_help_lists_the_method_and_help_all_the_experimental_options(capsys):
    import re

    assert main(["train", "--help"]) == 0
    short = capsys.readouterr().out
    assert main(["train", "--help-all"]) == 0
    full = capsys.readouterr().out
    assert "--stage1-steps" in short and "--lr-means" not in short and "--adc" not in short
    assert "--lr-means" in full and "--densify-absgrad" in full and "Experimental and expert options" in full
    assert not re.search(r"Session \d|issue \d|#\d\d", short + full)


def test_config_file_reruns_a_run_exactly(scene, tmp_path, capsys):
    """brfgs train --config RUN/config.json trains with exactly RUN's options (bit-identical model);
    options given next to it override the file; a bad file is a one-line error naming it."""
    from brfgs.model.io import load

    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    opts = [*TINY, "--no-evaluate", "--densify-refine-every", "5", "--lr-spec", "0.1", "--components", "iso,vol,spec"]
    assert main(["train", str(scene), str(a), *opts]) == 0
    assert main(["train", str(scene), str(b), "--config", str(a / "config.json"), "--quiet", "--no-evaluate"]) == 0
    assert (a / "config.json").read_text() == (b / "config.json").read_text()
    ta, tb = load(a / "model.safetensors")[0], load(b / "model.safetensors")[0]
    assert ta.keys() == tb.keys() and all(torch.equal(ta[k], tb[k]) for k in ta)
    assert main(["train", str(scene), str(c), "--config", str(a / "config.json"), "--stage2-steps", "2", "--quiet",
                 "--no-evaluate"]) == 0
    cfg_c = json.loads((c / "config.json").read_text())
    assert cfg_c["stage2_steps"] == 2 and cfg_c["densify"]["refine_every"] == 5 and cfg_c["lr_spec"] == 0.1
    assert cfg_c["components"] == ["iso", "vol", "spec"]
    bad = tmp_path / "bad.json"
    for text, field in (('{"stage1_steps": "many"}', "stage1_steps"), ('{"nope": 1}', "config"), ("[1, 2]", None),
                        ("{not json", None), ('{"densify": {"refine_every": 1.5}}', "densify.refine_every"),
                        ('{"supersample": 0}', "supersample"), ('{"latent_dim": 99}', "latent_dim")):
        bad.write_text(text)
        capsys.readouterr()
        assert main(["train", str(scene), str(tmp_path / "d"), "--config", str(bad), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert str(bad) in err and len(err.strip().splitlines()) == 1, err
        if field:
            assert field in err
    capsys.readouterr()  # a bad value from the command line is not blamed on the file
    assert main(["train", str(scene), str(tmp_path / "d"), "--config", str(a / "config.json"), "--supersample", "0",
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "field 'supersample'" in err and "config.json" not in err, err
    assert main(["train", str(scene), str(tmp_path / "d"), "--config", str(a / "config.json"), "--preset", "fast"]) == 2
    assert not (tmp_path / "d").exists()


def test_train_and_ablate_never_write_into_the_scene(scene, tmp_path, capsys):
    from scenes import snapshot

    before = snapshot(scene)
    for args in (["train", str(scene), str(scene / "run"), *TINY],
                 ["ablate", str(scene), str(scene / "abl"), "--study", "training", "--preset", "tiny", "--quiet"],
                 ["train", str(scene), str(scene), *TINY]):
        capsys.readouterr()
        assert main(args) == 2
        err = capsys.readouterr().err
        assert "inside the scene folder" in err and len(err.strip().splitlines()) == 1
    assert snapshot(scene) == before


def test_bench_train_times_both_decoders_with_the_same_result(scene, tmp_path, capsys):
    """`brfgs bench train` (what it reports, not speed): both decoders train the same model to the same
    scores (float rounding apart), per-phase timings and ratios present."""
    out = tmp_path / "bench.json"
    opts = [o for o in TINY if o != "--quiet"]
    assert main(["bench", "train", str(scene), str(tmp_path / "runs"), *opts, "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert set(res["summary"]) == {"fused", "reference"} and res["repeats"] == 1
    assert abs(res["psnr_difference_db"]) < 0.01 and abs(res["sam_ratio"] - 1) < 0.01
    assert res["summary"]["fused"]["ms_per_step"]["stage2"] > 0 and res["speedup_vs_reference"]["stage2"] > 0
    assert (tmp_path / "runs" / "fused_0" / "model.safetensors").is_file()
    assert "speed-up vs reference" in capsys.readouterr().out


def ablate_rows(out, study):
    """The rows of OUT/table_<study>.csv as dicts of floats (strings where not a number)."""
    import csv

    def val(x):
        try:
            return float(x)
        except ValueError:
            return x
    with open(out / f"table_{study}.csv", newline="") as fh:
        return [{k: val(v) for k, v in r.items() if v != ""} for r in csv.DictReader(fh)]


def test_ablation_rows_are_compared_with_their_reference_run():
    from brfgs.workflows.ablate import reference_run

    names = {"default", "no_flatness", "paper", "paper_flatness"}
    assert reference_run("additions", "default", names) is None
    assert reference_run("additions", "no_flatness", names) == "default"
    assert reference_run("additions", "paper", names) == "default"
    assert reference_run("additions", "paper_flatness", names) == "paper"
    assert reference_run("additions", "paper_flatness", names - {"paper"}) is None
    assert reference_run("kernels", "wo_iso", {"full", "wo_iso", "sh"}) == "full"
    assert reference_run("bands", "bands_rgb", {"bands_rgb", "bands_efc-top3"}) == "bands_efc-top3"
    assert reference_run("bands", "bands_rgb", {"bands_rgb"}) is None


def test_ablation_row_intervals_are_brfgs_compare_intervals(tmp_path):
    """versus() gives a row the margin, SAM ratio and 95 % intervals that brfgs compare gives the same pair."""
    from brfgs.evaluation.compare import compare, read_scores
    from brfgs.workflows.ablate import versus

    rng = torch.Generator().manual_seed(3)
    for name, shift in (("full", 0.0), ("wo_iso", -0.8)):
        views = [{"name": f"v{i:02d}", "psnr": 30 + shift + float(torch.randn(1, generator=rng)),
                  "sam": 0.03 * (1 - shift / 4) + 0.002 * float(torch.rand(1, generator=rng))} for i in range(7)]
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.json").write_text(json.dumps({"against": {"truth": {"views": views}}}))
    row = versus(tmp_path, "wo_iso", "full", "test", ["truth"])
    ref = compare([read_scores(tmp_path / "wo_iso")], [read_scores(tmp_path / "full")])["all"]
    assert row["vs"] == "full"
    assert row["dpsnr_truth"] == pytest.approx(ref["margin_db"]) and row["sam_ratio_truth"] == pytest.approx(ref["sam_ratio"])
    assert (row["dpsnr_truth_ci95_lo"], row["dpsnr_truth_ci95_hi"]) == pytest.approx(ref["margin_db_ci95"])
    assert (row["sam_ratio_truth_ci95_lo"], row["sam_ratio_truth_ci95_hi"]) == pytest.approx(ref["sam_ratio_ci95"])
    assert row["dpsnr_truth_ci95_lo"] < row["dpsnr_truth"] < row["dpsnr_truth_ci95_hi"] < 0
    assert versus(tmp_path, "full", None, "test", ["truth"]) == {}
