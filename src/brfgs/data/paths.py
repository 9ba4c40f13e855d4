"""Where outputs may go: never inside an input folder (input data is never written to)."""

from __future__ import annotations

from pathlib import Path

from brfgs.errors import UserError


def resolved(path: str | Path) -> Path:
    """``path`` with every link followed (need not exist); UserError naming it for a loop of links."""
    try:
        return Path(path).resolve()
    except RuntimeError:      # pathlib's "Symlink loop from ..."
        raise UserError("a loop of symbolic links", file=path) from None


def inside(path: str | Path, folder: str | Path) -> bool:
    """``path`` is ``folder`` or lies below it, after following links (UserError for a loop of links)."""
    try:
        resolved(path).relative_to(resolved(folder))
        return True
    except ValueError:
        return False


def check_outside(out: str | Path, scene_root: str | Path) -> None:
    """UserError when the output folder ``out`` is, or lies inside, the scene folder."""
    if inside(out, scene_root):
        raise UserError("output folder lies inside the scene folder; input data is never written to", file=out)
