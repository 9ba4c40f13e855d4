"""Writing result files so that a crash, a full disk or a read-only folder never leaves a half
file that looks finished: write to a temporary name beside the target, then rename it into place
(atomic on POSIX); on any failure the temporary file is removed and the error propagates."""

from __future__ import annotations

import contextlib
import json
import math
import os
from pathlib import Path
from typing import Iterator

import numpy as np

TMP_SUFFIX = ".partial"


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same extension, so writers that look at it keep
    working); rename it onto ``path`` when the block succeeds, remove it when it fails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}{TMP_SUFFIX}{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and exc.filename is None:
            exc.filename = str(path)  # name the file (a writer such as PIL or numpy may not)
        raise


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def finite_json(obj):
    """``obj`` with every non-finite float (NaN, ±inf, which JSON cannot hold) as None (null), and
    numpy scalars as Python numbers: what :func:`json_text` writes."""
    if isinstance(obj, float) or (hasattr(obj, "dtype") and getattr(obj, "shape", None) == ()):
        v = obj.item() if hasattr(obj, "item") else obj
        return v if not isinstance(v, float) or math.isfinite(v) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    return obj


def json_text(obj, indent: int | None = None, sort_keys: bool = False) -> str:
    """Strict JSON of ``obj`` (non-finite numbers as null, never a bare NaN token)."""
    return json.dumps(finite_json(obj), indent=indent, sort_keys=sort_keys, allow_nan=False)


def write_json(path: str | Path, obj, indent: int | None = 1, sort_keys: bool = False) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically."""
    return write_text(path, json_text(obj, indent=indent, sort_keys=sort_keys))


@contextlib.contextmanager
def open_text(path: str | Path, newline: str | None = None) -> Iterator:
    """A text file handle for writing ``path`` atomically (renamed into place when the block ends)."""
    with atomic_path(path) as tmp, open(tmp, "w", newline=newline) as fh:
        yield fh


class _PythonWrites:
    """A file seen by numpy through ``write`` only: numpy then writes with Python's file writes, whose
    errors carry their errno (to a real file it writes with C ``fwrite``, and a full disk surfaces as
    ``OSError: [Errno None]``)."""

    def __init__(self, fh):
        self.write = fh.write


def save_npy(path: str | Path, array) -> Path:
    """``numpy.save`` to ``path`` (ending in .npy) atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.lib.format.write_array(_PythonWrites(fh), np.asanyarray(array), allow_pickle=False)
    return Path(path)


def save_figure(fig, path: str | Path, **savefig) -> Path:
    """``fig.savefig`` to ``path`` atomically (format from the suffix)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".") or None, **savefig)
    return Path(path)
