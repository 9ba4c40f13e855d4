"""One writer per output folder: a second brfgs process writing into a folder another one holds is
refused in one line naming the holder; a dead holder's lock is taken over; two renders started
together into one folder give one result and one refusal."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from brfgs.cli import main
from brfgs.data.lock import LOCK_NAME, acquire, folder_lock, release
from test_format1_runs import DATA, OPTIONS, scene  # noqa: F401  (the fixture)

HOLD = ("import sys, time; from pathlib import Path; from brfgs.data.lock import acquire; "
        "acquire(Path(sys.argv[1]), 'test holder'); print('held', flush=True); time.sleep(120)")


def _holder(folder: Path) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


def test_a_second_writer_is_refused_and_a_dead_holders_lock_taken_over(scene, tmp_path, capsys):  # noqa: F811
    run = tmp_path / "run"
    holder = _holder(run)
    try:
        assert main(["train", str(scene), str(run), *OPTIONS]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(holder.pid) in err and "test holder" in err
        assert {p.name for p in run.iterdir()} == {LOCK_NAME}  # nothing written (the holder's lock file)
    finally:
        holder.kill()
        holder.wait()
    assert main(["train", str(scene), str(run), *OPTIONS, "--no-evaluate"]) == 0  # the OS released it
    assert not (run / LOCK_NAME).exists()  # an orderly end removes the file


def test_the_lock_is_reentrant_within_a_process_and_released(tmp_path):
    with folder_lock(tmp_path / "f", "outer"):
        acquire(tmp_path / "f", "inner")
        release(tmp_path / "f")
        holder = subprocess.run([sys.executable, "-c", HOLD.replace("time.sleep(120)", "pass"), str(tmp_path / "f")],
                                capture_output=True, text=True)
        assert holder.returncode != 0 and "another brfgs process" in holder.stderr
    holder = subprocess.run([sys.executable, "-c", HOLD.replace("time.sleep(120)", "pass"), str(tmp_path / "f")],
                            capture_output=True, text=True)
    assert holder.returncode == 0


@pytest.mark.parametrize("command", ["render", "products"])
def test_two_writers_started_together_give_one_result(tmp_path, command):
    run = tmp_path / "model"
    run.mkdir()
    (run / "model.safetensors").write_bytes((DATA / "finished" / "model.safetensors").read_bytes())
    out = tmp_path / "out"
    args = {"render": ["--view-zenith", "20", "--view-azimuth", "45"], "products": ["--size", "8", "--no-mcd43",
                                                                                  "--no-check-decoder"]}[command]
    cmd = [sys.executable, "-m", "brfgs", command, str(run), *args, "--out", str(out), "--quiet", "--backend", "torch"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    codes = sorted(rc for rc, _ in results)
    assert codes == [0, 2], results
    err = next(e for rc, e in results if rc == 2).strip()
    assert len(err.splitlines()) == 1 and ("another brfgs process" in err or "--overwrite" in err)
    time.sleep(0)
