"""Pixels of one frame read a row block at a time: its valid mask, then the spectra of chosen pixels,
without the frame's cube in memory (what samplers of pixels take instead of a whole cube)."""

from __future__ import annotations

import numpy as np


class FramePixels:
    """Frame ``i`` of ``scene`` (bands ``bands`` of the scene's, default all), read by row blocks
    (:meth:`brfgs.data.scene.Scene.scan_image`): the values :meth:`~brfgs.data.scene.Scene.load_image`
    gives, one pass per call."""

    def __init__(self, scene, i: int, bands=None):
        self.scene, self.i, self.bands = scene, int(i), bands

    @property
    def shape(self) -> tuple[int, int, int]:
        """[H, W, b] of the frame."""
        nb = self.scene.n_bands if self.bands is None else len(self.bands)
        return self.scene.height, self.scene.width, nb

    def valid(self) -> np.ndarray:  # [H, W] bool
        """Pixels whose every band is finite."""
        h, w, _ = self.shape
        mask = np.zeros((h, w), bool)

        def put(r0: int, r1: int, block: np.ndarray) -> None:
            mask[r0:r1] = np.isfinite(block).all(-1)

        self.scene.scan_image(self.i, self.bands, put)
        return mask

    def take(self, flat: np.ndarray) -> np.ndarray:  # [n, b] float32
        """Spectra of the pixels with row-major indices ``flat`` [n] (any order)."""
        h, w, nb = self.shape
        flat = np.asarray(flat, np.int64)
        rows = flat // w
        out = np.empty((len(flat), nb), np.float32)

        def pick(r0: int, r1: int, block: np.ndarray) -> None:
            sel = (rows >= r0) & (rows < r1)
            if sel.any():
                out[sel] = block.reshape(-1, nb)[flat[sel] - r0 * w]

        self.scene.scan_image(self.i, self.bands, pick)
        return out
