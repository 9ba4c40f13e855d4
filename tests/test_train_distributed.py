"""Data-parallel training (brfgs.train.distributed): two gloo processes give the model of one
process with the same seed and global batch (bit for bit when every process runs the same number
of threads), a run resumes across process counts, torchrun's path works, and user errors reach
the command line once with exit status 2."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from brfgs.errors import UserError
from brfgs.model.io import load
from brfgs.train.presets import preset
from brfgs.train.distributed import Comm, check_identical, fingerprint, reduce_gradients, shard
from brfgs.train.trainer import Trainer, train, train_parallel
from test_train_scene import make_plane_scene

# densification inside stage 1 (clone/split/prune decisions must agree), stage-2 ray sampling
# (per-view generators), the numba rasterizer; one thread per process so the digits can match
OPTS = dict(threads=1, backend="cpu", stage1_steps=24, stage2_steps=8, stage2_rays=256, views_per_step=2,
            checkpoint_every=10, densify=dict(refine_start=4, refine_stop=20, refine_every=6, reset_every=1000),
            max_gaussians=5000)
ARGS = ["--preset", "tiny", "--threads", "1", "--backend", "cpu", "--stage1-steps", "24", "--stage2-steps", "8",
        "--stage2-rays", "256", "--views-per-step", "2", "--checkpoint-every", "10", "--densify-refine-start", "4",
        "--densify-refine-stop", "20", "--densify-refine-every", "6", "--quiet", "--no-evaluate"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("dist") / "scene", w=48, h=32, n_bands=12)


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    """One process, two views per step."""
    out = tmp_path_factory.mktemp("dist_ref") / "run"
    return load(train(scene, out, preset("tiny", **OPTS), progress=False, log=None))[0], out


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    diff = {k: float((a[k].double() - b[k].double()).abs().max()) for k in a
            if a[k].shape != b[k].shape or not torch.equal(a[k], b[k])}
    assert not diff, diff


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([os.path.dirname(__file__), env.get("PYTHONPATH", "")])
    return env


def test_two_processes_train_the_model_of_one(scene, reference, tmp_path):
    ref, ref_out = reference
    out = tmp_path / "two"
    path = train_parallel(2, scene, out, preset("tiny", **OPTS), quiet=True)
    model = load(path)[0]
    assert model["param.means"].shape != (0, 3)
    _assert_same(ref, model)
    # densification happened (the decisions were taken on summed statistics) and the log is rank 0's
    log = (out / "train_log.csv").read_text().splitlines()
    assert log == (ref_out / "train_log.csv").read_text().splitlines()
    assert len({row.split(",")[-1] for row in log[1:]}) > 1  # the number of Gaussians changed


def test_resume_with_another_number_of_processes(scene, reference, tmp_path):
    """A one-process run interrupted in stage 1 is finished by two processes: same model."""
    run = tmp_path / "run"

    def stop(phase, step):
        if (phase, step) == ("stage1", 13):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(scene, run, preset("tiny", **OPTS), progress=False, callback=stop, log=None)
    _assert_same(reference[0], load(train_parallel(2, scene, run, preset("tiny", **OPTS), quiet=True))[0])


def test_torchrun_distributed(scene, reference, tmp_path):
    out = tmp_path / "tr"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
           "-m", "brfgs", "train", str(scene), str(out), "--distributed", *ARGS]
    res = subprocess.run(cmd, capture_output=True, text=True, env=_env(), timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    _assert_same(reference[0], load(out / "model.safetensors")[0])


def test_ctrl_c_keeps_a_checkpoint_and_the_rerun_finishes(scene, tmp_path):
    """Ctrl-C on `brfgs train --nproc 2` (SIGINT to the process group, as a terminal sends it): rank 0
    saves its checkpoint, exit status 130, run.json says interrupted; the same command finishes the
    run, and the model is that of an uninterrupted run."""
    long = [*ARGS]
    long[long.index("--stage1-steps") + 1] = "400"
    out = tmp_path / "int"
    cmd = [sys.executable, "-m", "brfgs", "train", str(scene), str(out), "--nproc", "2", *long]
    proc = subprocess.Popen(cmd, env=_env(), start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline, step = time.time() + 300, 0
    while time.time() < deadline and proc.poll() is None:
        try:
            st = json.loads((out / "run.json").read_text())
            step = st["step"] if st["phase"] == "stage1" else step
        except (OSError, ValueError, KeyError):
            pass
        if step >= 20:
            break
        time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()[1][-3000:]
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err[-3000:]
    st = json.loads((out / "run.json").read_text())
    assert st["status"] == "interrupted" and st["phase"] == "stage1" and 20 <= st["step"] < 400
    res = subprocess.run(cmd, capture_output=True, text=True, env=_env(), timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    ref = train(scene, tmp_path / "ref", preset("tiny", **{**OPTS, "stage1_steps": 400}), progress=False, log=None)
    _assert_same(load(ref)[0], load(out / "model.safetensors")[0])


def test_user_errors_are_one_line_exit_2(scene, reference, tmp_path):
    brfgs = [sys.executable, "-m", "brfgs", "train", str(scene)]
    # a finished run is refused by rank 0; every rank stops, the error is printed once
    res = subprocess.run([*brfgs, str(reference[1]), "--nproc", "2", *ARGS], capture_output=True, text=True,
                         env=_env(), timeout=300)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2, res.stderr[-3000:]
    assert lines == [f"brfgs: error: {reference[1]}: a finished training run exists here; pass --overwrite to "
                     "replace it (or choose another output folder)"], lines
    # a global batch that the processes cannot share out equally: refused before any process starts
    res = subprocess.run([*brfgs, str(tmp_path / "x"), "--nproc", "2", "--views-per-step", "3"],
                         capture_output=True, text=True, env=_env(), timeout=300)
    assert res.returncode == 2 and "views_per_step" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "x").exists()
    # --distributed outside torchrun names the missing variables
    env = {k: v for k, v in _env().items() if k not in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT")}
    res = subprocess.run([*brfgs, str(tmp_path / "y"), "--distributed"], capture_output=True, text=True, env=env,
                         timeout=300)
    assert res.returncode == 2 and "torchrun" in res.stderr and "RANK" in res.stderr


def test_views_per_step_must_be_shared_out_equally(scene, tmp_path):
    class Four(Comm):
        world = 4
    with pytest.raises(UserError, match="multiple of the number of processes"):
        Trainer(scene, tmp_path / "run", preset("tiny", views_per_step=6), comm=Four())
    with pytest.raises(UserError, match="views_per_step"):
        preset("tiny", views_per_step=0).validate()


def test_helpers_in_one_process():
    items = list(range(7))
    assert shard(items, Comm()) == items

    class Rank(Comm):
        def __init__(self, r, n):
            self.rank, self.world = r, n
    assert [shard(items, Rank(r, 3)) for r in range(3)] == [[0, 3, 6], [1, 4], [2, 5]]
    p = {"a": torch.ones(3, requires_grad=True)}
    p["a"].grad = torch.full((3,), 2.0)
    assert reduce_gradients(Comm(), p) == 0 and torch.equal(p["a"].grad, torch.full((3,), 2.0))
    a = {"x": torch.arange(4.0), "y": torch.ones(2)}
    b = {"x": torch.arange(4.0), "y": torch.tensor([1.0, 1.5])}
    assert torch.equal(fingerprint(a), fingerprint(dict(a)))
    assert not torch.equal(fingerprint(a), fingerprint(b))
    check_identical(Comm(), a, "one process")  # nothing to compare with: never raises


def test_bench_parallel(scene, tmp_path):
    """brfgs bench parallel: both process counts timed and scored; with one thread per process
    the models are identical; only the 2-process run all-reduces, and its volume is the size of
    the gradients (4 bytes per trained value) plus the densification statistics in stage 1."""
    from brfgs.workflows.bench_parallel import bench_parallel

    cfg = preset("tiny", **{**OPTS, "stage1_steps": 8, "stage2_steps": 4})
    res = bench_parallel(scene, tmp_path / "bp", cfg, nprocs=(1, 2))
    one, two = res["summary"]["1"], res["summary"]["2"]
    assert res["max_abs_model_difference"]["2"] == 0.0
    assert one["psnr"] == two["psnr"] and all(p > 10 for p in one["psnr"])
    assert set(one["ms_per_step"]) == {"stage1", "stage2"} and all(v > 0 for v in two["ms_per_step"].values())
    assert all(v == 0 for v in one["allreduce_bytes_per_step"].values())
    model = load(tmp_path / "bp" / "n2_0" / "model.safetensors")[0]
    n = model["param.means"].shape[0]
    assert two["allreduce_bytes_per_step"]["stage2"] >= 4 * n * 3  # at least the latents' gradients
    assert two["allreduce_bytes_per_step"]["stage1"] > 4 * n * (3 + 4 + 3 + 1)  # means, quats, scales, opacities
