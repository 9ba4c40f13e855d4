"""The product speaks of itself as it is: README, BENCHMARKS, docs/ and the source narrate no
development history (numbered work periods, issue numbers), and nothing refers to a file outside the
repository."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HISTORY = re.compile(
    r"\b[Ss]essions? \d|\b(?:last|previous|this|next) session\b|\b[Ii]ssues? #?\d|#\d\d\b|\bS\d\d\b"
)
OUTSIDE = re.compile(r"\.\./shared")


def _texts() -> list[Path]:
    files = [ROOT / "README.md", ROOT / "BENCHMARKS.md", *sorted((ROOT / "docs").glob("*.md"))]
    files += sorted((ROOT / "src" / "brfgs").rglob("*.py"))
    return files


@pytest.mark.parametrize("path", _texts(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_development_history(path):
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        m = HISTORY.search(line) or OUTSIDE.search(line)
        assert m is None, f"{path.relative_to(ROOT)}:{n}: {m.group(0)!r} in {line.strip()[:120]}"


def test_the_pattern_catches_history():
    """The check can fail: each form of history it is meant to find is found."""
    for text in ("as before Session 26", "since sessions 3", "the pipeline of last session",
                 "issue 15 asks", "Issue #70", "see #68", "S41 measured", "../shared/conventions.md"):
        assert HISTORY.search(text) or OUTSIDE.search(text), text
    for text in ("a Ray session", "the 15 issues of a flight", "band #3", "session-free"):
        assert not (HISTORY.search(text) or OUTSIDE.search(text)), text
