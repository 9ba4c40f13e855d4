"""Output folders of the commands: never inside the scene, never over a finished result."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from brfgs.data.lock import LOCK_NAME, acquire
from brfgs.errors import UserError

__all__ = ["check_output_dir", "prepare_output_dir", "run_folder", "safe_name", "Report", "SPLITS", "metrics_file"]

SPLITS = ("test", "validation", "train")  # the views a run is scored on: held out, or its own (the fit)


def metrics_file(split: str = "test") -> str:
    """Name of the metrics file of ``split`` in a run folder (brfgs evaluate writes it)."""
    return "metrics.json" if split == "test" else f"metrics_{split}.json"


def check_output_dir(out: Path, scene_root: Path | None = None, overwrite: bool = False,
                     marker: str | None = None) -> None:
    """Refuse an output folder inside the scene folder, or a non-empty one unless ``overwrite``.

    ``marker``: a file whose presence means "a finished result is here" — only it blocks
    (other outputs may be regenerated) when given.
    """
    if scene_root is not None:
        try:
            out.resolve().relative_to(scene_root.resolve())
            raise UserError("output folder lies inside the scene folder; input data is never written to",
                            file=out)
        except ValueError:
            pass
    if out.exists() and not out.is_dir():
        raise UserError("output path exists and is not a folder", file=out)
    if overwrite or not out.exists():
        return
    if marker is not None:
        if (out / marker).exists():
            raise UserError(f"a finished result ({marker}) is already here; pass --overwrite to replace it",
                            file=out)
    elif any(p.name != LOCK_NAME for p in out.iterdir()):
        raise UserError("output folder exists and is not empty; pass --overwrite to replace it", file=out)


def prepare_output_dir(out: Path, marker: str, overwrite: bool, scene_root: str | None) -> Path:
    """``out`` created and locked for this process (:mod:`brfgs.data.lock`; the caller releases it, e.g.
    with :func:`brfgs.data.lock.releases_locks`), after :func:`check_output_dir` against the model's
    scene folder (when it still exists): the finished-result check happens under the lock."""
    root = Path(scene_root) if scene_root and Path(scene_root).exists() else None
    check_output_dir(out, root, overwrite=True)  # never inside the scene, before anything is created
    if out.exists() and not out.is_dir():
        raise UserError("output path exists and is not a folder", file=out)
    acquire(out, f"{marker.split('.')[0]} output")
    check_output_dir(out, root, overwrite=overwrite, marker=marker)
    return out


def run_folder(run: Path) -> Path:
    """The run folder of ``run`` (a run folder or the model file in it)."""
    run = Path(run)
    return run if run.is_dir() else run.parent


SAFE_NAME_BYTES = 100   # a file name holds at most 255 bytes; a folder named brf_<name> keeps well below


def safe_name(name: str) -> str:
    """``name`` with every character other than letters, digits, '-', '_' and '.' replaced by '_'; a
    name of more than SAFE_NAME_BYTES bytes (UTF-8) is cut and ends in '-' and 10 hex digits of the
    SHA-256 of the whole name, so that long names stay distinct and fit a file name."""
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in str(name))
    if len(safe.encode("utf-8", "replace")) <= SAFE_NAME_BYTES:
        return safe
    digest = hashlib.sha256(str(name).encode("utf-8", "surrogatepass")).hexdigest()[:10]
    cut = safe.encode("utf-8", "replace")[:SAFE_NAME_BYTES - 11].decode("utf-8", "ignore")
    return f"{cut}-{digest}"


@dataclass
class Report:
    """What a report function wrote: the folder, the JSON summary it holds and a one-line message."""

    out: Path
    info: dict
    message: str
