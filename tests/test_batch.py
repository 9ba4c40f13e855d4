"""brfgs batch: the manifest (schema, paths, errors naming the field) and a batch of tiny scenes run
as Ray tasks on a local Ray: finished scenes, a corrupt cube reported without retry, skips on a
rerun, the fixed scene finished by the next one, unexpected errors retried and reported."""

from __future__ import annotations

import csv
import json
import logging

import pytest

from brfgs.cli import main
from brfgs.errors import UserError
from brfgs.workflows import batch as batch_mod
from brfgs.workflows.batch import check_reachable, run_batch, run_scene
from brfgs.workflows.manifest import BATCH_KEYS, SCENE_KEYS, TRAIN_KEYS, read_manifest
from brfgs.workflows.options import BatchConfig
from scenes import make_scene
from test_train_scene import make_plane_scene

# A tiny run: known poses, a few steps, a 16-px product map without the MCD43 fit (~10 s per scene on 1 core).
TINY = """
[defaults]
preset = "tiny"
poses = "known"
stage1_steps = 6
stage2_steps = 4
ae_steps = 20
num_cpus = 1
[defaults.products]
size = 16
mcd43 = false
check_decoder = false
"""


def _write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _summary(out):
    js = json.loads((out / "summary.json").read_text())
    with open(out / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {r["name"]: r for r in js["scenes"]}, {r["name"]: r for r in rows}


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray for the module (run_batch uses a Ray this process started and leaves it running)."""
    ray = pytest.importorskip("ray")
    logging.getLogger(batch_mod._TOKEN_LOGGER).setLevel(logging.ERROR)
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    yield ray
    ray.shutdown()


# ------------------------------------------------------------------------------------------ the manifest
def test_manifest_schema_paths_and_defaults(tmp_path):
    make_scene(tmp_path / "data" / "a")
    m = _write(tmp_path / "jobs" / "flights.toml", TINY + """
[[scene]]
scene = "../data/a"
seed = 3
[[scene]]
name = "a-again"
scene = "../data/a"
out = "elsewhere/a2"
num_cpus = 2
threads = 1
products = false
max_gaussians = 999
[scene.densify]
refine_every = 11
""")
    man = read_manifest(m)
    a, b = man.scenes
    assert man.out == tmp_path / "jobs" / "flights_batch"            # default: beside the manifest
    assert a.name == "a" and a.scene == tmp_path / "data" / "a" and a.out == man.out / "a"
    assert a.run == a.out / "run"
    assert a.config["seed"] == 3 and a.config["stage1_steps"] == 6 and a.config["preset"] == "tiny"
    assert a.config["threads"] == 0 and a.num_cpus == 1 and a.num_gpus == 0.0   # the task sets num_cpus threads
    assert a.products == {"size": (16,), "mcd43": False, "check_decoder": False}
    assert b.out == tmp_path / "jobs" / "elsewhere" / "a2" and b.products is None
    assert b.num_cpus == 2 and b.config["threads"] == 1                            # given threads win
    assert b.config["max_gaussians"] == 999 and b.config["densify"]["refine_every"] == 11
    assert b.config["densify"]["reset_every"] == 1000                                # the rest from the preset
    assert read_manifest(m, out=tmp_path / "o").out == tmp_path / "o"             # --out overrides
    # JSON (a plain list of scenes) and YAML give the same scenes
    j = _write(tmp_path / "jobs" / "list.json", json.dumps([{"scene": "../data/a", "preset": "tiny", "seed": 3}]))
    (sj,) = read_manifest(j).scenes
    assert sj.scene == a.scene and sj.out == tmp_path / "jobs" / "list_batch" / "a" and sj.config["seed"] == 3
    y = _write(tmp_path / "jobs" / "f.yaml", "out: runs\nscenes:\n  - scene: ../data/a\n    preset: tiny\n")
    assert read_manifest(y).scenes[0].out == tmp_path / "jobs" / "runs" / "a"
    assert not set(SCENE_KEYS + BATCH_KEYS) & set(TRAIN_KEYS)                      # no name clashes


@pytest.mark.parametrize("text, field", [
    ("[[scene]]\nscene = 'a'\n[[scene]]\nscene = 'a'\nname = 'b'\nstage1_step = 5\n", "scene[2].stage1_step"),
    ("[defaults]\nae_step = 5\n[[scene]]\nscene = 'a'\n", "defaults.ae_step"),
    ("[[scene]]\nscene = 'a'\nseed = 'x'\n", "scene[1].seed"),
    ("[[scene]]\nscene = 'a'\nlatent_dim = 99\n", "scene[1].latent_dim"),
    ("[[scene]]\nscene = 'a'\nnum_cpus = 0\n", "scene[1].num_cpus"),
    ("[[scene]]\nscene = 'a'\nvariant = 'sh'\nproducts = true\n", "scene[1].products"),
    ("[[scene]]\nscene = 'a'\n[scene.products]\nmcd_43 = false\n", "scene[1].products.mcd_43"),
    ("[[scene]]\nscene = 'a'\nout = 'a/out'\n", "scene[1].out"),                 # inside the scene folder
    ("[[scene]]\nscene = 'a'\n[[scene]]\nscene = 'a'\n", "scene[2].name"),         # two scenes named a
    ("[[scene]]\nscene = 'a'\npreset = 'quick'\n", "scene[1].preset"),
    ("[[scene]]\nscene = 'a'\nname = 'x/y'\n", "scene[1].name"),
    ("[defaults]\nname = 'a'\n[[scene]]\nscene = 'a'\n", "defaults.name"),
    ("scene = []\n", "scene"),
    ("outt = 'x'\n[[scene]]\nscene = 'a'\n", "outt"),
])
def test_manifest_errors_name_the_file_and_the_field(tmp_path, text, field):
    m = _write(tmp_path / "m.toml", text)
    with pytest.raises(UserError) as err:
        read_manifest(m)
    assert err.value.file == str(m) and err.value.field == field, str(err.value)


def test_manifest_typo_on_the_command_line(tmp_path, capsys):
    m = _write(tmp_path / "m.toml", "[[scene]]\nscene = 'a'\nstage1_step = 5\n")
    assert main(["batch", str(m), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert str(m) in err and "scene[1].stage1_step" in err and "did you mean 'stage1_steps'" in err
    assert main(["batch", str(_write(tmp_path / "m.ini", "x"))]) == 2
    assert main(["batch", str(_write(tmp_path / "bad.toml", "[[scene]\n"))]) == 2
    assert "not a valid TOML file" in capsys.readouterr().err


def test_dry_run_and_the_install_hint_without_ray(tmp_path, capsys, monkeypatch):
    make_scene(tmp_path / "a")
    m = _write(tmp_path / "m.toml", TINY + "[[scene]]\nscene = 'a'\n[[scene]]\nscene = 'missing'\n")
    assert main(["batch", str(m), "--dry-run"]) == 2                              # a scene would fail
    cap = capsys.readouterr()
    out = cap.out
    assert "a: run train -> evaluate -> products" in out and "missing: FAIL" in out and "no transforms.json" in out
    err = cap.err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("brfgs: error: scene 'missing' would fail: ") and "transforms" in err[0]
    assert err[1] == "brfgs: error: 1 of 2 scenes would fail"
    assert not (tmp_path / "m_batch").exists()                                     # a dry run writes nothing
    monkeypatch.setattr(batch_mod, "ray", None)
    assert main(["batch", str(m)]) == 2
    assert "pip install 'brfgs[scale]'" in capsys.readouterr().err


def test_an_unreachable_cluster_is_a_user_error():
    with pytest.raises(UserError, match="cannot reach the Ray cluster at 127.0.0.1:1") as err:
        check_reachable("127.0.0.1:1", timeout_s=2.0)
    assert err.value.field == "--address"
    check_reachable("auto")                                                        # Ray finds it; not checked


# ------------------------------------------------------------------------------------------ batches on Ray
def test_batch_survives_a_corrupt_cube_and_skips_finished_scenes(local_ray, tmp_path, capsys):
    for name in ("a", "b", "bad"):
        make_plane_scene(tmp_path / "scenes" / name, w=40, h=32, n_bands=8)
    cube = tmp_path / "scenes" / "bad" / "images" / "view_03.img"
    good = cube.read_bytes()
    cube.write_bytes(good[: len(good) // 2])
    m = _write(tmp_path / "flights.toml", 'out = "runs"\n' + TINY + """
[[scene]]
scene = "scenes/a"
[[scene]]
scene = "scenes/b"
seed = 1
[[scene]]
scene = "scenes/bad"
""")
    out = tmp_path / "runs"
    assert main(["batch", str(m)]) == 2
    err = capsys.readouterr().err
    assert err.count("brfgs: error:") == 1 and "scene 'bad' failed" in err and "view_03.img" in err
    js, rows = _summary(out)
    for name in ("a", "b"):
        assert js[name]["status"] == rows[name]["status"] == "finished" and js[name]["attempts"] == 1
        assert 0 < js[name]["psnr_observed"] < 60 and 0 < js[name]["sam_truth"] < 1.6 and js[name]["n_gaussians"] > 0
        assert float(rows[name]["psnr_truth"]) == pytest.approx(js[name]["psnr_truth"])
        run = out / name / "run"
        assert (run / "model.safetensors").is_file() and (run / "metrics.json").is_file()
        assert (run / "analysis" / "products" / "products.json").is_file()
        assert js[name]["model"] == f"{name}/run/model.safetensors"
    bad = js["bad"]
    assert bad["status"] == "failed" and bad["attempts"] == 1 and "view_03.img" in bad["error"]   # not retried
    assert (out / bad["error_log"]).is_file() and "view_03.img" in (out / bad["error_log"]).read_text()
    assert "| bad | failed |" in (out / "summary.md").read_text()
    # rerun: the finished scenes are skipped (no task, files untouched), the corrupt one fails again
    mtimes = {n: (out / n / "run" / "model.safetensors").stat().st_mtime_ns for n in ("a", "b")}
    assert main(["batch", str(m)]) == 2
    js2, _ = _summary(out)
    for name in ("a", "b"):
        assert js2[name]["status"] == "skipped" and js2[name]["attempts"] == 0
        assert js2[name]["psnr_observed"] == js[name]["psnr_observed"]            # read from the run folder
        assert (out / name / "run" / "model.safetensors").stat().st_mtime_ns == mtimes[name]
    assert js2["bad"]["status"] == "failed" and js2["bad"]["attempts"] == 1
    assert "skipped (finished)" in (out / "summary.md").read_text()
    # the cube fixed: the next batch finishes it; same data and seed as scene a -> the same model
    cube.write_bytes(good)
    capsys.readouterr()
    assert main(["batch", str(m)]) == 0
    js3, _ = _summary(out)
    assert [js3[n]["status"] for n in ("a", "b", "bad")] == ["skipped", "skipped", "finished"]
    assert js3["bad"]["psnr_observed"] == pytest.approx(js["a"]["psnr_observed"], abs=1e-9)
    assert json.loads((out / "summary.json").read_text())["counts"] == {"finished": 1, "skipped": 2, "failed": 0}


def test_unexpected_errors_are_retried_then_reported(local_ray, tmp_path):
    for name in ("flaky", "broken", "greedy"):
        make_scene(tmp_path / name)
    m = read_manifest(_write(tmp_path / "m.toml", TINY + "[[scene]]\nscene = 'flaky'\n[[scene]]\nscene = 'broken'\n"
                             "[[scene]]\nscene = 'greedy'\nnum_gpus = 64\n"))
    root = tmp_path

    def pipeline(s, log):
        marker = root / f"{s.name}_failed_once"
        if s.name == "broken" or not marker.exists():
            marker.touch()
            raise RuntimeError(f"simulated crash of {s.name}")

    def task(s, batch_id):  # a local function: Ray ships it to the workers by value
        return run_scene(s, batch_id, pipeline=pipeline)

    res = run_batch(m, BatchConfig(retries=1), say=lambda *a: None, task=task)
    rows = {r["name"]: r for r in res.rows}
    assert rows["flaky"]["status"] == "finished" and rows["flaky"]["attempts"] == 2
    broken = rows["broken"]
    assert broken["status"] == "failed" and broken["attempts"] == 2
    assert broken["error"] == "RuntimeError: simulated crash of broken"
    assert rows["greedy"]["status"] == "failed" and "asks for 64 GPUs" in rows["greedy"]["error"]   # never queued
    assert rows["greedy"]["attempts"] == 0
    log = (m.out / broken["error_log"]).read_text()
    assert log.count("=== ") == 2 and "Traceback" in log and "simulated crash" in log
    assert res.failures[0] == ("scene 'broken' failed after 2 attempts: RuntimeError: simulated crash of broken "
                               "(log: broken/error.log)")
