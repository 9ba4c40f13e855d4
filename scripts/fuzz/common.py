"""What every fuzz case shares: the mutation's expected outcome, running the command line in-process,
and the checks of the outcome (docs/reliability.md, "Fuzzing")."""

from __future__ import annotations

import contextlib
import io
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Mutation:
    """One mutation: what it did and its outcome, known by construction."""

    what: str
    expected: str            # "valid" | "invalid" | "either"
    names: str = "/"         # what a one-line error must contain (a file path, an option's flag, a file name)
    step: str | None = None  # the command that must refuse it, where several run in turn


def snapshot(root: Path, skip: tuple[str, ...] = ()) -> dict[str, tuple[int, int]]:
    """{relative path: (size, mtime_ns)} of everything under ``root`` except the names in ``skip``."""
    return {str(p.relative_to(root)): (p.lstat().st_size, p.lstat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.name not in skip}


@dataclass
class Outcome:
    mutation: Mutation
    rc: int
    stderr: str
    traceback: str | None
    input_changed: bool

    def problems(self) -> list[str]:
        out = []
        if self.traceback is not None:
            out.append("traceback")
        elif self.rc not in (0, 2):
            out.append(f"exit {self.rc}")
        lines = self.stderr.strip().splitlines()
        if self.rc == 2:
            if len(lines) != 1 or not lines[0].startswith("brfgs: error: ") or self.mutation.names not in lines[0]:
                out.append(f"error not one line naming {self.mutation.names!r}")
        elif self.rc == 0 and lines:
            out.append("warnings printed")
        if "Traceback" in self.stderr:
            out.append("traceback printed")
        if self.mutation.expected == "invalid" and self.rc == 0:
            out.append("invalid input accepted")
        if self.mutation.expected == "valid" and self.rc != 0:
            out.append("valid input refused")
        if self.input_changed:
            out.append("input folder changed")
        return out

    @property
    def last_line(self) -> str:
        text = (self.traceback or self.stderr).strip().splitlines()
        return text[-1] if text else ""


def run_cli(argv: list[str]) -> tuple[int, str, str | None]:
    """(exit status, stderr, traceback or None) of ``brfgs ARGV`` run in-process; Python warnings that
    brfgs does not silence are printed to stderr, every time (not once per place, as in a fresh process)."""
    from brfgs.cli import main

    err, tb = io.StringIO(), None
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()), \
            warnings.catch_warnings(record=True) as caught:
        warnings.filterwarnings("always", append=True)   # what brfgs does not silence, every time
        try:
            rc = main(argv)
        except BaseException:  # a traceback is a failure of its own kind
            rc, tb = -1, traceback.format_exc()
    for w in caught:                                      # as Python prints them
        err.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno, w.line))
    return rc, err.getvalue(), tb
