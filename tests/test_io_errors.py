"""A full disk (ENOSPC, injected) while a command writes its results: one line naming the path,
exit status 3, and no half-written result file left behind, for inspect, select-bands, init,
train, evaluate and render."""

from __future__ import annotations

import errno
import os

import pytest
import torch

from brfgs.cli import main
from brfgs.data import atomic
from test_train_scene import make_plane_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.set_num_threads(1)
    return make_plane_scene(tmp_path_factory.mktemp("io") / "scene", w=48, h=32, n_bands=12)


@pytest.fixture(scope="module")
def run(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("io_run") / "run"
    assert main(["train", str(scene), str(out), "--preset", "tiny", "--threads", "1", "--stage1-steps", "4",
                 "--stage2-steps", "2", "--quiet", "--no-evaluate"]) == 0
    return out


def _full_disk_for(monkeypatch, name_part: str):
    """Fail the rename that would put a file whose name contains ``name_part`` into place, after its
    temporary file was written (as when the disk fills during the write)."""
    real = os.replace

    def replace(src, dst):
        if name_part in os.path.basename(str(dst)):
            raise OSError(errno.ENOSPC, "No space left on device", str(dst))
        return real(src, dst)

    monkeypatch.setattr(atomic.os, "replace", replace)


def _partials(folder):
    return [p for p in folder.rglob("*") if atomic.TMP_SUFFIX in p.name]


@pytest.mark.parametrize("command, target", [
    (lambda s, r, o: ["inspect", str(s), "--out", str(o), "-q"], "summary.json"),
    (lambda s, r, o: ["inspect", str(s), "--out", str(o), "-q"], "views_polar.png"),
    (lambda s, r, o: ["select-bands", str(s), "--out", str(o), "-q"], "bands.json"),
    (lambda s, r, o: ["init", str(s), str(o), "--poses", "known", "-q"], "points.ply"),
    (lambda s, r, o: ["evaluate", str(r), "--quiet"], "metrics.json"),
    (lambda s, r, o: ["evaluate", str(r), "--quiet"], ".img"),
    (lambda s, r, o: ["render", str(r), "--view-zenith", "10", "--view-azimuth", "0", "-o", str(o), "-q"], "depth.npy"),
    (lambda s, r, o: ["render", str(r), "--view-zenith", "10", "--view-azimuth", "0", "-o", str(o), "-q"], "cube.hdr"),
])
def test_full_disk_is_one_line_exit_3(scene, run, tmp_path, monkeypatch, capsys, command, target):
    out = tmp_path / "out"
    before = {p: p.stat().st_mtime_ns for p in run.rglob("*") if p.is_file()}
    _full_disk_for(monkeypatch, target)
    assert main(command(scene, run, out)) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("brfgs: error: ") and "No space left on device" in err
    assert target in err
    for folder in (out, run):
        if folder.exists():
            assert _partials(folder) == []
            assert not [p for p in folder.rglob("*") if p.name.endswith(target) and p not in before]


def test_json_files_never_hold_a_nan_token(tmp_path):
    """Every JSON brfgs writes goes through brfgs.data.atomic: non-finite numbers become null, so the
    files are strict JSON (Python's NaN token is not JSON)."""
    import json
    import math

    import numpy as np

    from brfgs.data import atomic

    obj = {"a": float("nan"), "b": [1.0, float("inf"), -float("inf")], "c": np.float32(np.nan), "d": np.float64(2.5),
           "e": (1, 2), "f": {"g": float("nan")}, "h": "NaN"}
    path = atomic.write_json(tmp_path / "x.json", obj)
    text = path.read_text()
    assert "NaN" not in text.replace('"NaN"', "") and "Infinity" not in text
    back = json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert back == {"a": None, "b": [1.0, None, None], "c": None, "d": 2.5, "e": [1, 2], "f": {"g": None}, "h": "NaN"}
    assert math.isfinite(back["d"])


def _disk_full_while_writing(monkeypatch, module, name: str):
    """A writer that fails with ENOSPC and no file name (as PIL and numpy do) while writing."""
    def fail(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(module, name, fail)


def test_a_writer_without_a_file_name_is_named_by_the_path(run, tmp_path, monkeypatch, capsys):
    import numpy as np

    _disk_full_while_writing(monkeypatch, np.lib.format, "write_array")
    out = tmp_path / "r"
    assert main(["render", str(run), "--view-zenith", "10", "--view-azimuth", "0", "-o", str(out), "-q"]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "(unknown path)" not in err and str(out) in err and ".npy" in err
    assert _partials(out) == []


@pytest.mark.parametrize("free_mib", [0.3, 1.5, 2.5])
def test_a_disk_too_full_for_the_colmap_database_is_exit_3_before_colmap_starts(scene, tmp_path, monkeypatch,
                                                                                 capsys, free_mib):
    """COLMAP aborts the process when SQLite runs out of space mid-write: brfgs measures the free space
    first, says which file does not fit, leaves no database behind, and a rerun with space finishes."""
    import shutil

    from brfgs.init import api

    real = shutil.disk_usage
    monkeypatch.setattr(api.shutil, "disk_usage", lambda p: real(p)._replace(free=int(free_mib * 2**20)))
    out = tmp_path / "run"
    assert main(["train", str(scene), str(out), "--preset", "tiny", "--threads", "1", "--stage1-steps", "4",
                 "--stage2-steps", "2", "--quiet", "--no-evaluate"]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "database.db" in err and "free" in err
    assert not list(out.rglob("database.db*")) and _partials(out) == []
    monkeypatch.undo()
    assert main(["train", str(scene), str(out), "--preset", "tiny", "--threads", "1", "--stage1-steps", "4",
                 "--stage2-steps", "2", "--quiet", "--no-evaluate"]) == 0
