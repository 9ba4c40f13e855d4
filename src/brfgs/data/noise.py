"""The scene's per-band noise σ_b: from its dark frames (streamed by row blocks), its ``dark_sigma``
field, or estimated from the images."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from brfgs.data import validation as V
from brfgs.data.cube_io import CubeSource, for_each_block, open_cube, read_block_averaged
from brfgs.data.validation import RangeTally
from brfgs.errors import UserError

SUM_PIXELS = 2**16   # pixels of a dark frame converted to float64 at once


def dark_sigma(root: Path, meta: dict, tf: Path, wl: np.ndarray, sources: list[CubeSource],
               reading: tuple) -> tuple[np.ndarray, str]:
    """σ_b [B]: std over dark frames and pixels; else ``dark_sigma``; else estimated from the images.
    ``reading``: (plausible value range, allow_outside_links); dark-frame values must lie in the range."""
    value_range, allow = reading
    n_bands = len(wl)
    listed = meta.get("dark_frames")
    if listed is not None:
        if not isinstance(listed, list):
            raise UserError("expected a list of paths", file=tf, field="dark_frames")
        paths = [V.path_inside(root, p, tf, f"dark_frames[{i}]", allow) for i, p in enumerate(listed)]
    else:
        paths = sorted((root / "calibration").glob("dark_*.hdr")) if (root / "calibration").is_dir() else []
    if paths:
        sources = [open_cube(p, wl, tf, f"dark frame {p.name}", allow) for p in paths]
        return dark_frame_sigma(sources, value_range, paths[0]), "dark_frames"
    if meta.get("dark_sigma") is not None:
        sig = V.number_list(meta["dark_sigma"], tf, "dark_sigma", length=n_bands)
        if np.any(sig < 0):
            raise UserError("dark_sigma values must be >= 0", file=tf, field="dark_sigma")
        return sig, "transforms.json"
    return _estimate_sigma(sources[: min(3, len(sources))], n_bands, value_range), "estimated"


def dark_frame_sigma(sources: list[CubeSource], value_range, first: Path) -> np.ndarray:  # [B]
    """Sample standard deviation σ_b [B] over the dark frames ``sources`` and their pixels whose every
    band is finite, accumulated in float64 a row block at a time (no whole frame in memory): per frame
    its rows' sums Σx and Σx² in row order, continued from block to block, then added over the frames.
    UserError (naming ``first``) when fewer than two pixels are finite."""
    n_bands = sources[0].bands if sources else 0
    s1, s2 = np.zeros(n_bands), np.zeros(n_bands)
    n = 0
    for src in sources:
        frame = {"s1": None, "s2": None, "n": 0}

        def add(r0: int, r1: int, block: np.ndarray) -> None:
            pixels = block.reshape(-1, n_bands)
            for k in range(0, len(pixels), SUM_PIXELS):     # float64 copies of SUM_PIXELS pixels at a time
                with np.errstate(invalid="ignore"):  # signalling NaNs of a damaged frame: dropped below
                    x = pixels[k:k + SUM_PIXELS].astype(np.float64)
                x = x[np.isfinite(x).all(1)]
                frame["s1"] = _continued_sum(frame["s1"], x)
                frame["s2"] = _continued_sum(frame["s2"], x * x)
                frame["n"] += len(x)

        for_each_block(src, np.arange(n_bands), None, 1, RangeTally(value_range), src.path.name, add)
        if frame["n"]:
            s1 += frame["s1"]
            s2 += frame["s2"]
            n += frame["n"]
    if n < 2:
        raise UserError("dark frames contain no finite pixels", file=first)
    var = np.maximum(s2 / n - (s1 / n) ** 2, 0.0) * n / (n - 1)
    return np.sqrt(var)


def _continued_sum(acc: np.ndarray | None, rows: np.ndarray) -> np.ndarray:  # [B]
    """Column sums of ``rows`` [n, B] added row after row to ``acc`` [B] (None: start at the first row):
    the order a single sum over the whole frame's rows takes, so the result does not depend on blocks."""
    if acc is None:
        return rows.sum(0) if len(rows) else None
    return np.concatenate([acc[None], rows]).sum(0)


def _estimate_sigma(sources: list[CubeSource], n_bands: int, value_range) -> np.ndarray:
    """Per-band noise σ from images (no dark frames): robust MAD of a 3×3 Laplacian residual (Immerkær 1996)."""
    ests = []
    for src in sources:
        cube = read_block_averaged(src, np.arange(n_bands), None, 1, RangeTally(value_range), src.path.stem)
        lap = (4 * cube[1:-1, 1:-1] - cube[:-2, 1:-1] - cube[2:, 1:-1] - cube[1:-1, :-2] - cube[1:-1, 2:])
        lap = lap.reshape(-1, n_bands)
        lap = lap[np.isfinite(lap).all(1)]
        # std of 4x - 4 neighbours for i.i.d. noise σ is sqrt(20) σ; MAD → σ via 1.4826
        ests.append(1.4826 * np.median(np.abs(lap - np.median(lap, 0)), 0) / np.sqrt(20.0))
    return np.median(np.stack(ests), 0)
