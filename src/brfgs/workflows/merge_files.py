"""The file side of ``brfgs merge``: which files of a flight may be merged, and writing them only inside
the new scene folder, all at once.

A merged scene is built in a fresh folder beside OUT (same file system) and renamed onto OUT at the end
(:func:`staged_folder`); on any failure, an interrupt included, that folder is removed and OUT is left as
it was (absent, or an empty folder). Every file is created with exclusive creation: a hard link to a
path that must not exist, or (where a hard link cannot be made: another file system, a file system
without them, a file the user may not link) a copy opened with ``O_CREAT | O_EXCL``; nothing is ever
written through an existing path or link, and two files meant for one path are an error, not an
overwrite. Only regular files that, after following links, lie inside their own flight folder are
merged (:func:`regular_inside`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
import stat
from pathlib import Path
from typing import Iterator

from brfgs.errors import STORAGE_ERRNOS, UserError

__all__ = ["NAME_MAX_BYTES", "STAGE_PREFIX", "Placement", "real_path", "regular_inside", "folder_inside", "check_name",
           "check_output", "staged_folder", "place_file", "user_error"]

NAME_MAX_BYTES = 255               # the longest file name POSIX file systems take (bytes)
STAGE_PREFIX = ".brfgs-merge-"     # the folder beside OUT the merged scene is built in
# where a hard link cannot be made and a copy is made instead (never on EEXIST: a clash is an error)
NO_LINK_ERRNOS = {errno.EXDEV, errno.EPERM, errno.EMLINK, errno.ENOTSUP, errno.EOPNOTSUPP}
COPY_CHUNK_BYTES = 4 * 2**20


def user_error(exc: OSError, what: str, file) -> UserError:
    """A one-line UserError for an OSError met on a user's path (``what`` says what was done)."""
    reason = exc.strerror or os.strerror(exc.errno or 0)
    if exc.errno == errno.ELOOP:
        reason = "a loop of symbolic links"
    elif exc.errno == errno.ENAMETOOLONG:
        reason = f"a name longer than the {NAME_MAX_BYTES} bytes a file system takes"
    return UserError(f"cannot {what}: {reason}", file=file)


def real_path(path: Path, what: str) -> tuple[Path, os.stat_result]:
    """(the path with every link followed, its stat); UserError for a missing path, a loop, a long name."""
    try:
        real = path.resolve(strict=True)
        return real, os.lstat(real)
    except FileNotFoundError:
        raise UserError(f"{what} not found", file=path) from None
    except RuntimeError:              # Path.resolve's own symlink-loop error
        raise UserError(f"cannot read the {what}: a loop of symbolic links", file=path) from None
    except OSError as exc:
        if exc.errno in STORAGE_ERRNOS:
            raise
        raise user_error(exc, f"read the {what}", path) from None


def _check_inside(path: Path, real: Path, root_real: Path, what: str) -> None:
    if real != root_real and root_real not in real.parents:
        raise UserError(f"the {what} leads outside its flight folder {root_real} (to {real}); only files inside a "
                        "flight are merged", file=path)


def folder_inside(path: Path, root_real: Path, what: str) -> Path:
    """``path`` (a folder of the flight whose real path is ``root_real``) with links followed; UserError
    unless it is a folder inside the flight."""
    real, st = real_path(path, what)
    _check_inside(path, real, root_real, what)
    if not stat.S_ISDIR(st.st_mode):
        raise UserError(f"the {what} is not a folder", file=path)
    return real


def regular_inside(path: Path, root_real: Path, what: str) -> tuple[Path, os.stat_result]:
    """(real path, stat) of ``path``: a regular file (not a folder, device or pipe) that, with every link
    followed, lies inside the flight folder whose real path is ``root_real``; UserError naming it else."""
    real, st = real_path(path, what)
    _check_inside(path, real, root_real, what)
    if not stat.S_ISREG(st.st_mode):
        raise UserError(f"the {what} is not a regular file (a folder, device or pipe); only regular files are "
                        "merged", file=path)
    return real, st


def check_name(name: str, source: Path, field: str | None = None) -> str:
    """A merged file name: one path component of at most NAME_MAX_BYTES bytes; UserError naming the source."""
    if "/" in name or name in ("", ".", ".."):
        raise UserError(f"the merged name {name!r} is not a file name", file=source, field=field)
    n = len(os.fsencode(name))
    if n > NAME_MAX_BYTES:
        raise UserError(f"the merged name of this file would be {n} bytes long, more than the {NAME_MAX_BYTES} "
                        "a file name may have: shorten the file's name (or the flight folder's)", file=source,
                        field=field)
    return name


def check_output(out: Path) -> None:
    """UserError unless ``out`` is a new path or an empty folder (never a link, a file or a full folder)."""
    try:
        st = os.lstat(out)
    except FileNotFoundError:
        return
    except OSError as exc:
        if exc.errno in STORAGE_ERRNOS:
            raise
        raise user_error(exc, "use the output folder", out) from None
    if stat.S_ISLNK(st.st_mode):
        raise UserError("the output folder is a symbolic link: give a new folder (or an empty one)", file=out)
    if not stat.S_ISDIR(st.st_mode):
        raise UserError("the output path exists and is not a folder: choose a new one", file=out)
    with os.scandir(out) as it:
        if next(it, None) is not None:
            raise UserError("the output folder exists and is not empty: choose a new one", file=out)


class Placement:
    """Files to place in the new scene: {path relative to OUT: (real source path, its stat)}. Adding a
    second file for one path is an error (:meth:`add`)."""

    def __init__(self):
        self.files: dict[str, tuple[Path, os.stat_result, Path]] = {}

    def add(self, rel: str, source: Path, real: Path, st: os.stat_result) -> None:
        """Plan ``source`` (real path ``real``, stat ``st``) for ``OUT/rel``."""
        if rel in self.files:
            raise UserError(f"two files would be merged as {rel} (this one and {self.files[rel][2]})", file=source)
        self.files[rel] = (real, st, source)

    def write(self, stage: Path) -> None:
        """Create every planned file inside ``stage`` (exclusively)."""
        for rel, (real, st, source) in self.files.items():
            dst = stage / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            place_file(real, st, dst, rel)


def place_file(src: Path, st: os.stat_result, dst: Path, shown: str) -> None:
    """``dst`` (which must not exist) as a hard link to the regular file ``src`` whose stat was ``st``, else
    an exclusive copy of it; UserError when ``dst`` exists or ``src`` changed since it was checked."""
    try:
        os.link(src, dst, follow_symlinks=False)
    except FileExistsError:
        raise UserError("two files would be merged under this name", file=shown) from None
    except OSError as exc:
        if exc.errno not in NO_LINK_ERRNOS:
            raise
        _copy_exclusive(src, st, dst, shown)
        return
    now = os.lstat(dst)
    if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino) or not stat.S_ISREG(now.st_mode):
        raise UserError("the file changed while it was merged", file=src)


def _copy_exclusive(src: Path, st: os.stat_result, dst: Path, shown: str) -> None:
    """Copy the regular file ``src`` into the new path ``dst`` (O_CREAT | O_EXCL, links not followed)."""
    fd_in = os.open(src, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        now = os.fstat(fd_in)
        if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino) or not stat.S_ISREG(now.st_mode):
            raise UserError("the file changed while it was merged", file=src)
        try:
            fd_out = os.open(dst, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
        except FileExistsError:
            raise UserError("two files would be merged under this name", file=shown) from None
        with open(fd_in, "rb", closefd=False) as fin, open(fd_out, "wb") as fout:
            shutil.copyfileobj(fin, fout, COPY_CHUNK_BYTES)
        os.utime(dst, ns=(now.st_atime_ns, now.st_mtime_ns), follow_symlinks=False)
    finally:
        os.close(fd_in)


def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; returns those created, deepest last."""
    missing = []
    p = folder
    while not os.path.lexists(p):
        missing.append(p)
        p = p.parent
    made: list[Path] = []
    try:
        for q in reversed(missing):
            os.mkdir(q)
            made.append(q)
    except BaseException:
        for q in reversed(made):
            with contextlib.suppress(OSError):
                os.rmdir(q)
        raise
    return made


@contextlib.contextmanager
def staged_folder(out: Path) -> Iterator[Path]:
    """A new folder beside ``out`` to build the scene in, renamed onto ``out`` (new, or an empty folder)
    when the block succeeds; on any failure it is removed (with any parents of ``out`` made for it)."""
    out = Path(os.path.abspath(out))
    made = _make_parents(out.parent)
    stage = None
    try:
        while stage is None:
            cand = out.parent / f"{STAGE_PREFIX}{secrets.token_hex(4)}"
            try:
                os.mkdir(cand)
                stage = cand
            except FileExistsError:
                continue
        yield stage
        check_output(out)
        os.rename(stage, out)
    except BaseException:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
        for q in reversed(made):
            with contextlib.suppress(OSError):
                os.rmdir(q)
        raise
