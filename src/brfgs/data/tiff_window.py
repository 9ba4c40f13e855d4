"""A window of a TIFF cube read strip by strip or tile by tile: only the segments (strips or tiles,
compressed or not) that the window touches are read and decoded, so a patch of a compressed GeoTIFF
costs its own rows, not the file."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import tifffile


def read_tiff_window(path: Path, rows: slice, cols: slice) -> tuple[np.ndarray, int] | None:
    """(stored values [h, w, S] of rows ``rows`` and columns ``cols`` of the first page, S its samples
    (bands) in file order; bytes of segments read) or None when the file is not one single-page,
    single-depth image (read it whole then). ``rows``/``cols``: slices with start and stop in pixels."""
    with tifffile.TiffFile(path) as t:
        series = t.series[0]
        page = t.pages[0]
        if len(series.pages) != 1 or page.imagedepth != 1 or len(page.dataoffsets) == 0:
            return None
        h, w, n_s = page.imagelength, page.imagewidth, page.samplesperpixel
        ch_h, ch_w = int(page.chunks[0]), int(page.chunks[1])
        n_sr, n_sc = math.ceil(h / ch_h), math.ceil(w / ch_w)
        planes = n_s if page.planarconfig == 2 else 1
        if len(page.dataoffsets) != planes * n_sr * n_sc:
            return None
        r0, r1, c0, c1 = rows.start, rows.stop, cols.start, cols.stop
        out = np.empty((r1 - r0, c1 - c0, n_s), dtype=page.dtype)
        fh, n_bytes = t.filehandle, 0
        for p in range(planes):
            for sr in range(r0 // ch_h, (r1 - 1) // ch_h + 1):
                for sc in range(c0 // ch_w, (c1 - 1) // ch_w + 1):
                    index = (p * n_sr + sr) * n_sc + sc
                    fh.seek(page.dataoffsets[index])
                    data = fh.read(page.databytecounts[index])
                    n_bytes += len(data)
                    seg, (s, _, y, x, _), _ = page.decode(data, index)
                    _place(out, seg[0], s, y - r0, x - c0)
        return out, n_bytes


def _place(out: np.ndarray, seg: np.ndarray, s: int, dy: int, dx: int) -> None:
    """Copy the part of segment ``seg`` [L, W, S_seg] (its top-left at row ``dy``, column ``dx`` of the
    window, samples from ``s``) that lies inside the window ``out`` [h, w, S]."""
    h, w = out.shape[:2]
    y0, x0 = max(0, -dy), max(0, -dx)
    y1, x1 = min(seg.shape[0], h - dy), min(seg.shape[1], w - dx)
    if y1 > y0 and x1 > x0:
        out[dy + y0:dy + y1, dx + x0:dx + x1, s:s + seg.shape[2]] = seg[y0:y1, x0:x1]
