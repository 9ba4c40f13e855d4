"""User-facing errors.

Anything the user can fix (bad input file, bad option, impossible angle) raises
:class:`UserError`. The command line prints its message without a traceback and
exits with status 2. Messages name the file and the field and say what was expected.
"""

from __future__ import annotations

import errno
from pathlib import Path

# OSErrors that are the machine's or the user's to fix, not bugs: exit status 3, one line (brfgs.cli.main).
STORAGE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG, errno.EIO})


class UserError(Exception):
    """An error caused by the user's input; printed without traceback, exit status 2."""

    def __init__(self, message: str, *, file: str | Path | None = None, field: str | None = None):
        self.file = str(file) if file is not None else None
        self.field = field
        message = " ".join(str(message).split())  # one line, whatever a library's message held
        self.detail = message
        parts = []
        if file is not None:
            parts.append(str(file))
        if field is not None:
            parts.append(f"field '{field}'")
        prefix = ": ".join(parts)
        super().__init__(f"{prefix}: {message}" if prefix else message)


def require(condition: bool, message: str, *, file: str | Path | None = None, field: str | None = None) -> None:
    """Raise :class:`UserError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise UserError(message, file=file, field=field)
