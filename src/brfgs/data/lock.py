"""One writer per output folder: an OS lock (``fcntl.flock`` on ``FOLDER/.brfgs.lock``) held by the
command that writes into the folder (train, render, brf, products, export, simulate, batch) from its
"is a finished result already here?" check until it ends.

A second writer is refused in one line naming the holder's process ID. The lock belongs to the
holder's open file: when that process ends, however it ends (kill -9 included), the operating system
releases it and the next writer takes the folder over (the file of a killed holder stays until then).
A holder that ends normally removes the file.
Within one process the lock is re-entrant (a command that locks a folder may call one that locks it
again).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import functools
import os
from pathlib import Path

from brfgs.errors import UserError

LOCK_NAME = ".brfgs.lock"
_held: dict[str, tuple[int, int]] = {}  # resolved folder -> (file descriptor, nesting depth)


def acquire(folder: Path, what: str) -> None:
    """Lock ``folder`` (created if needed) for this process; UserError naming the holder otherwise."""
    folder = Path(folder)
    key = str(folder.resolve())
    if key in _held:
        fd, depth = _held[key]
        _held[key] = (fd, depth + 1)
        return
    folder.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            raise UserError(f"another brfgs process is writing here (PID and command: {holder}); wait for it to "
                            "end or choose another folder", file=folder) from None
        if _same_file(fd, folder / LOCK_NAME):
            break
        os.close(fd)  # the holder removed the file between our open and our lock: lock the new one
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()} {what}\n".encode(), 0)
    _held[key] = (fd, 1)


def release(folder: Path) -> None:
    """Undo one :func:`acquire` of ``folder`` by this process (the lock ends with the last)."""
    key = str(Path(folder).resolve())
    fd, depth = _held[key]
    if depth > 1:
        _held[key] = (fd, depth - 1)
        return
    del _held[key]
    _remove(fd, Path(key) / LOCK_NAME)


def _same_file(fd: int, path: Path) -> bool:
    """Whether the open file ``fd`` is still the file at ``path``."""
    try:
        return os.fstat(fd).st_ino == os.stat(path).st_ino
    except FileNotFoundError:
        return False


def _remove(fd: int, path: Path) -> None:
    """Remove the lock file and release the lock (in this order, under the lock: a process that opened
    the file meanwhile sees it gone once it holds the lock, and locks the next one)."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
    os.close(fd)  # closing the only descriptor releases the flock


@contextlib.contextmanager
def folder_lock(folder: Path, what: str):
    """Hold the lock of ``folder`` (:func:`acquire`) while the block runs."""
    acquire(folder, what)
    try:
        yield
    finally:
        release(folder)


def releases_locks(fn):
    """Decorator: every folder lock that ``fn`` acquires (e.g. through
    :func:`brfgs.analysis.output.prepare_output_dir`) is released when it returns or raises."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        before = set(_held)
        try:
            return fn(*args, **kwargs)
        finally:
            for key in [k for k in _held if k not in before]:
                fd, _ = _held.pop(key)
                _remove(fd, Path(key) / LOCK_NAME)

    return wrapper
