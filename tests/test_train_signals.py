"""Ctrl-C during training: the first asks for a stop at the end of the step, a second stops at once
without saving the half-done step, a press while a checkpoint is written waits for the write; every
rerun resumes to the uninterrupted model bit for bit. A training log whose header a kill lost is
written again."""

from __future__ import annotations

import os
import signal

import pytest
import torch

from brfgs.model.io import load
from brfgs.train.presets import preset
from brfgs.train.run_folder import LOG_HEADER, RunFolder, run_status
from brfgs.train.trainer import train
from test_train_scene import make_plane_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("sig") / "scene", w=48, h=32, n_bands=8)


def _cfg():
    return preset("tiny", threads=1, stage1_steps=16, stage2_steps=6, checkpoint_every=4, backend="torch")


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    return load(train(scene, tmp_path_factory.mktemp("ref") / "run", _cfg(), progress=False, log=None))[0]


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("presses", [1, 2])
@pytest.mark.parametrize("at", [("stage1", 3), ("stage1", 4), ("stage1", 11), ("stage2", 2)])
def test_ctrl_c_once_or_twice_resumes_to_the_same_model(scene, reference, tmp_path, presses, at):
    """SIGINT sent to this process at a step's callback (after the step, around a checkpoint at steps
    4 and 8): once, or twice in a row (the second while the first is pending)."""
    run = tmp_path / "run"

    def cb(phase, step):
        if (phase, step) == at:
            for _ in range(presses):
                os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(KeyboardInterrupt):
        train(scene, run, _cfg(), progress=False, log=None, callback=cb)
    assert _same(load(train(scene, run, _cfg(), progress=False, log=None))[0], reference)


def test_ctrl_c_while_a_checkpoint_is_written_waits_for_it(scene, reference, tmp_path, monkeypatch):
    from brfgs.train.state import TrainState

    run, calls = tmp_path / "run", []
    original = TrainState.save_checkpoint

    def save_and_press(self, path):
        calls.append(path)
        if len(calls) == 3:                                      # a periodic checkpoint of stage 1
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, path)

    monkeypatch.setattr(TrainState, "save_checkpoint", save_and_press)
    with pytest.raises(KeyboardInterrupt):
        train(scene, run, _cfg(), progress=False, log=None)
    monkeypatch.undo()
    assert (run / "checkpoints" / "last.safetensors").is_file()
    assert _same(load(train(scene, run, _cfg(), progress=False, log=None))[0], reference)


def test_training_learns_even_when_autograd_was_left_off(scene, reference, tmp_path):
    """A Ctrl-C that lands inside a no_grad block's entry leaves this thread's grad mode off; the next
    train() in the process must still learn (the same model) and give the caller's mode back."""
    torch.set_grad_enabled(False)
    try:
        model = train(scene, tmp_path / "run", _cfg(), progress=False, log=None)
        assert not torch.is_grad_enabled()
    finally:
        torch.set_grad_enabled(True)
    assert _same(load(model)[0], reference)


def test_a_log_without_its_header_is_written_again(tmp_path):
    folder = RunFolder(tmp_path)
    folder.log.write_text("stage1,1,0.5,20.0,100\r\nstage1,2,0.4,21.0,100\r\nstage1,3,0.3")  # torn last line
    fh, writer = folder.open_log()
    writer.writerow(["stage1", 3, 0.3, 22.0, 100])
    fh.close()
    lines = folder.log.read_text().splitlines()
    assert lines[0] == ",".join(LOG_HEADER) and lines[1:] == ["stage1,1,0.5,20.0,100", "stage1,2,0.4,21.0,100",
                                                             "stage1,3,0.3,22.0,100"]


@pytest.mark.parametrize("at_call", [3, 6, 19])
def test_a_second_ctrl_c_inside_a_step_does_not_save_the_half_done_step(scene, reference, tmp_path, monkeypatch,
                                                                        at_call):
    """Both presses while the optimiser updates the parameters (the step counter not yet advanced):
    the run stops at once, and the rerun resumes from the last whole checkpoint to the same model."""
    from brfgs.model.optim import NamedAdam

    run, calls = tmp_path / "run", []
    original = NamedAdam.step

    def step_and_press(self, params):
        original(self, params)
        calls.append(1)
        if len(calls) == at_call:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(NamedAdam, "step", step_and_press)
    with pytest.raises(KeyboardInterrupt):
        train(scene, run, _cfg(), progress=False, log=None)
    monkeypatch.undo()
    assert _same(load(train(scene, run, _cfg(), progress=False, log=None))[0], reference)


MOMENTS = [("stage1", s) for s in (1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 15, 16)] + [("stage2", s) for s in range(1, 7)]


@pytest.mark.parametrize("at", MOMENTS, ids=[f"{p}-{s}" for p, s in MOMENTS])
def test_two_presses_10_ms_apart_at_20_moments(scene, reference, tmp_path, at):
    """A person pressing Ctrl-C twice: the first press after a step (at each of 20 steps of the two
    stages, checkpoints every 4 steps and the model write at the end among them), the second 10 ms
    later from another thread, wherever the main thread then is. The rerun (or the run itself, when
    the first press came after its last step) gives the uninterrupted training's model bit for bit."""
    import threading
    import time

    assert len(MOMENTS) == 20
    run, timers = tmp_path / "run", []

    def cb(phase, step):
        if (phase, step) == at:
            os.kill(os.getpid(), signal.SIGINT)
            timers.append(threading.Timer(0.010, os.kill, (os.getpid(), signal.SIGINT)))
            timers[-1].start()

    finished = False
    try:
        train(scene, run, _cfg(), progress=False, log=None, callback=cb)
        finished = True
    except KeyboardInterrupt:
        pass
    try:  # the second press lands after train returned: Python's own KeyboardInterrupt
        for t in timers:
            t.join()
        time.sleep(0.05)
    except KeyboardInterrupt:
        pass
    assert len(timers) == 1
    assert torch.is_grad_enabled()  # a press inside a no_grad entry must not leave autograd off
    # a press that lands after the model was written still ends train() with KeyboardInterrupt: the run
    # is finished on disk (a rerun is refused as finished) and its model is the one to compare
    done = finished or run_status(run) == "finished"
    model = run / "model.safetensors" if done else train(scene, run, _cfg(), progress=False, log=None)
    assert _same(load(model)[0], reference)
