"""A real full disk: train, render and products write into a small tmpfs, filled to 10 levels of free
space below what the command writes. Each ends in exit 3 with one line naming a path on that disk,
never a signal (SIGABRT) or a traceback, and leaves no temporary file; after space
is freed, a rerun finishes (training resumes to the model an unlimited disk gives, bit for bit).

Needs root (mount); skipped elsewhere. The injected-error tests in test_io_errors.py run everywhere."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
import torch

from brfgs.cli import main
from brfgs.data import atomic
from brfgs.model.io import load
from test_train_scene import make_plane_scene

TRAIN = ["--preset", "tiny", "--threads", "1", "--stage1-steps", "6", "--stage2-steps", "3",
         "--checkpoint-every", "2", "--quiet"]
LEVELS = [0.02, 0.08, 0.15, 0.25, 0.35, 0.45, 0.55, 0.7, 0.85, 0.97]  # of the bytes the command writes


class Tmpfs:
    """A tmpfs of a given size; ``resize`` remounts it (its files stay)."""

    def __init__(self, root: Path):
        self.path = root / f"disk-{uuid.uuid4().hex[:8]}"
        self.path.mkdir()

    def mount(self, size_bytes: int) -> "Tmpfs":
        size = max(4096, size_bytes // 4096 * 4096)
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(self.path)], check=True,
                       capture_output=True)
        return self

    def resize(self, size_bytes: int) -> None:
        subprocess.run(["mount", "-o", f"remount,size={size_bytes}", str(self.path)], check=True,
                       capture_output=True)

    def umount(self) -> None:
        """Unmount; lazily if a file on it is still open (a memory-mapped model), so no mount outlives the test."""
        if subprocess.run(["umount", str(self.path)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(self.path)], capture_output=True)


def _can_mount(tmp: Path) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    t = Tmpfs(tmp)
    try:
        t.mount(1 << 20)
    except (subprocess.CalledProcessError, OSError):
        return False
    t.umount()
    return True


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("tmpfs")
    if not _can_mount(root):
        pytest.skip("mounting a tmpfs needs root")
    torch.set_num_threads(1)
    scene = make_plane_scene(root / "scene", w=48, h=32, n_bands=12)
    return root, scene


def _brfgs(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "BRFGS_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "brfgs", *args], capture_output=True, text=True, env=env,
                          timeout=600)


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def _check_failure(code: int, err: str, disk: Path) -> None:
    """Exit 3 with one line naming a path on the full disk (the disk is smaller than the results);
    never a signal or a traceback; no temporary file left."""
    assert code == 3, (code, err[-2000:])
    err = err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and err.startswith("brfgs: error: "), err
    assert str(disk) in err and ("No space left" in err or "free" in err), err
    assert not [p for p in disk.rglob("*") if atomic.TMP_SUFFIX in p.name]


def _same_model(a_run: Path, b_run: Path) -> bool:
    a, b = load(a_run / "model.safetensors")[0], load(b_run / "model.safetensors")[0]
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.fixture(scope="module")
def reference(base):
    root, scene = base
    run = root / "reference"
    assert _brfgs("train", str(scene), str(run), *TRAIN).returncode == 0
    return run


@pytest.mark.parametrize("level", LEVELS)
def test_train_on_a_full_disk(base, reference, level):
    root, scene = base
    disk = Tmpfs(root).mount(int(level * _size(reference)))
    try:
        run = disk.path / "run"
        res = _brfgs("train", str(scene), str(run), *TRAIN)
        _check_failure(res.returncode, res.stderr, disk.path)
        disk.resize(4 * _size(reference) + (8 << 20))
        res = _brfgs("train", str(scene), str(run), *TRAIN)
        assert res.returncode == 0, res.stderr[-2000:]
        assert _same_model(run, reference)
    finally:
        disk.umount()


@pytest.mark.parametrize("command", ["render", "products"])
def test_render_and_products_on_a_full_disk(base, reference, command, capsys):
    """In this process (neither command runs COLMAP, the one library that could abort it)."""
    root, _ = base
    args = {"render": ["render", str(reference), "--view-zenith", "10", "--view-azimuth", "0", "-q"],
            "products": ["products", str(reference), "--size", "32", "-q"]}[command]
    probe = root / f"probe-{command}"
    assert main([*args, "-o", str(probe)]) == 0
    need = _size(probe)
    for level in LEVELS:
        disk = Tmpfs(root).mount(int(level * need))
        try:
            out = disk.path / "out"
            capsys.readouterr()
            code = main([*args, "-o", str(out)])
            _check_failure(code, capsys.readouterr().err, disk.path)
            disk.resize(4 * need + (8 << 20))
            assert main([*args, "-o", str(out), "--overwrite"]) == 0, level
            assert sorted(p.name for p in out.rglob("*")) == sorted(p.name for p in probe.rglob("*"))
        finally:
            disk.umount()
