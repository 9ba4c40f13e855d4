"""Parsing of the analysis commands' text options (comma-separated numbers, image sizes)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from brfgs.errors import UserError

__all__ = ["parse_floats", "parse_size", "MAX_IMAGE_PX"]

MAX_IMAGE_PX = 8192


def parse_floats(text: str, field: str, n: int | None = None) -> list[float]:
    """Finite numbers of the comma-separated ``text`` (empty items skipped), ``n`` of them when
    given; UserError naming ``field`` otherwise."""
    try:
        vals = [float(t) for t in str(text).split(",") if t.strip()]
    except ValueError:
        raise UserError(f"expected comma-separated numbers, got {text!r}", field=field) from None
    if not vals or not all(math.isfinite(v) for v in vals):
        raise UserError(f"expected finite numbers, got {text!r}", field=field)
    if n is not None and len(vals) != n:
        raise UserError(f"expected {n} numbers, got {len(vals)}", field=field)
    return vals


def parse_size(text: str, field: str = "--size") -> tuple[int, int]:
    """(W, H) pixels of 'W' (square) or 'W,H', each 1..8192; UserError otherwise."""
    wh = parse_floats(text, field)
    check_size(wh, field)
    return int(wh[0]), int(wh[-1])


def check_size(wh: Sequence[float], field: str = "--size") -> None:
    """UserError unless ``wh`` is [W] or [W, H] of whole pixels in 1..8192."""
    if len(wh) not in (1, 2) or any(v != int(v) or v < 1 or v > MAX_IMAGE_PX for v in wh):
        raise UserError(f"expected W or W,H in pixels (1..{MAX_IMAGE_PX})", field=field)
