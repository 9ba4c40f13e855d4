"""Tiny training runs shared by the test modules of one pytest process: each run is trained once, on
first use, by ``brfgs train`` (the tiny preset of tests/test_format1_runs.py on a 48 x 32 plane scene)."""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

import torch

from brfgs.cli import main
from test_train_scene import make_plane_scene

# the tiny preset with the short schedule of tests/test_format1_runs.py
OPTIONS = ["--preset", "tiny", "--threads", "1", "--stage1-steps", "12", "--stage2-steps", "6", "--ae-steps", "40",
           "--init-fill-points", "150", "--checkpoint-every", "5", "--backend", "torch", "--quiet", "--no-evaluate"]
STAGE1 = Path("checkpoints") / "stage1.safetensors"

_ROOT: list[Path] = []
_DONE: dict[str, Path] = {}


def root() -> Path:
    """This process's folder of scenes and runs (made once)."""
    if not _ROOT:
        _ROOT.append(Path(tempfile.mkdtemp(prefix="brfgs-tiny-runs-")))
        atexit.register(shutil.rmtree, _ROOT[0], True)
    return _ROOT[0]


def scene() -> Path:
    """The plane scene (8 bands, 13 views) every run here trains on unless told otherwise."""
    path = root() / "scene"
    if not path.is_dir():
        torch.set_num_threads(1)
        make_plane_scene(path, w=48, h=32, n_bands=8, n_views=13)
    return path


# name: (the options beyond OPTIONS, the run whose stage 1 it starts from or None)
RUNS = {
    "brf": ([], None),                                        # the autoencoder, both stages
    "linear": (["--spectral-basis", "linear"], None),         # the linear basis, both stages
    "brf_linear": (["--spectral-basis", "linear"], "brf"),    # linear stage 2 on the autoencoder's stage 1
    "linear_ae": (["--spectral-basis", "autoencoder"], "linear"),
    "sh": (["--variant", "sh"], "brf"),
    "shadows": (["--shadows"], "brf"),
    "neural": (["--variant", "neural"], "brf"),
    "cir": (["--variant", "cir"], None),
    "joint": (["--joint", "--learn-irradiance"], None),
}


def run(name: str) -> Path:
    """The run folder of ``name`` (:data:`RUNS`), trained on first use."""
    if name not in _DONE:
        extra, src = RUNS[name]
        if src is not None:
            extra = [*extra, "--from-stage1", str(run(src) / STAGE1)]
        out = root() / name
        assert main(["train", str(scene()), str(out), *OPTIONS, *extra]) == 0
        _DONE[name] = out
    return _DONE[name]
