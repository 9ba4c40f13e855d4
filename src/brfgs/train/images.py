"""Training targets: the frames' cubes as tensors, whole frames kept in a least-recently-used cache
bounded in bytes, windows (training patches) read from the files for the frames it does not hold."""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from brfgs.data.cir import cir_composite
from brfgs.data.pixels import FramePixels


TILE_PX = 512   # side of the windows a frame that the cache cannot hold is processed in (set-up)


class ByteLRU:
    """Values with a size in bytes, at most ``budget_bytes`` together; the least recently used leave first.

    Shared by the image stores of a run, so that a phase's targets (e.g. all bands in stage 2) take
    the room of the previous phase's (the stage-1 bands) as they are used.
    """

    def __init__(self, budget_bytes: float):
        self.budget = float(budget_bytes)
        self.used = 0
        self._entries: OrderedDict = OrderedDict()   # key -> (value, nbytes)

    def __contains__(self, key) -> bool:
        return key in self._entries

    def get(self, key):
        """The value of ``key`` (now the most recently used) or None."""
        if key not in self._entries:
            return None
        self._entries.move_to_end(key)
        return self._entries[key][0]

    def keys(self) -> list:
        """The keys held, least recently used first."""
        return list(self._entries)

    def items(self) -> list:
        """(key, value) of the entries held, least recently used first."""
        return [(k, v) for k, (v, _) in self._entries.items()]

    def room(self, nbytes: int, keep: Callable[[object], bool] | None = None) -> bool:
        """Whether ``nbytes`` fit after evicting the entries whose key ``keep`` does not keep (all: None)."""
        evictable = sum(n for k, (_, n) in self._entries.items() if keep is None or not keep(k))
        return nbytes <= self.budget - self.used + evictable

    def put(self, key, value, nbytes: int, keep: Callable[[object], bool] | None = None) -> bool:
        """Hold ``value`` under ``key``, evicting least recently used entries (never those ``keep`` keeps)
        until it fits; False (nothing evicted, nothing held) when it cannot fit."""
        if key in self._entries or not self.room(nbytes, keep):
            return key in self._entries
        for k in list(self._entries):
            if self.used + nbytes <= self.budget:
                break
            if keep is None or not keep(k):
                self.used -= self._entries.pop(k)[1]
        self._entries[key] = (value, nbytes)
        self.used += nbytes
        return True


class ImageStore:
    """Training targets of some frames: whole frames held in ``cache`` (a :class:`ByteLRU`, its own
    of ``cache_gib`` when not given) as far as they fit, else read per use (a window by
    :meth:`get_window`, reading only the window's rows from the file).

    ``get(i)`` -> (image [H, W, C] float32 tensor with invalid pixels zeroed, valid [H, W] bool).
    ``transform`` maps a loaded cube [H, W, b] (numpy) to the stored target (e.g. CIR composite); it
    must work pixel by pixel (a window's target is the whole frame's, cropped).
    """

    def __init__(self, scene, indices, bands=None, cache_gib: float = 4.0,
                 transform: Callable[[np.ndarray], np.ndarray] | None = None, cache: ByteLRU | None = None,
                 name: str = "images"):
        self.scene = scene
        self.bands = None if bands is None else [int(b) for b in bands]
        self.transform = transform
        self.lru = cache if cache is not None else ByteLRU(cache_gib * 2**30)
        self.name = name
        self.indices = list(indices)
        nb = scene.n_bands if bands is None else len(bands)
        self.frame_bytes = scene.width * scene.height * (nb * 4 + 1)   # the target and its mask
        self._checked: set[int] = set()     # frames whose whole-frame checks were made

    @property
    def cached(self) -> bool:
        """Whether every frame of the store fits in the cache's budget."""
        return len(self.indices) * self.frame_bytes <= self.lru.budget

    @property
    def cache(self) -> dict[int, tuple[Tensor, Tensor]]:
        """The frames of this store that the cache holds now {index: (image, valid)}."""
        return {k[1]: v for k, v in self.lru.items() if k[0] == self.name}

    def _mine(self, key) -> bool:
        return key[0] == self.name

    def _target(self, cube: np.ndarray) -> tuple[Tensor, Tensor]:
        if self.transform is not None:
            cube = self.transform(cube)
        cube = np.array(cube, np.float32, copy=None)     # the reader's fresh array: zeroed in place, no copies
        valid = np.isfinite(cube).all(-1)
        cube[~valid] = 0.0
        return torch.from_numpy(cube), torch.from_numpy(valid)

    def _load(self, i: int) -> tuple[Tensor, Tensor]:
        out = self._target(self.scene.load_image(i, bands=self.bands))
        self._checked.add(i)
        return out

    def get_with_nan(self, i: int) -> np.ndarray:  # [H, W, C] float32
        """Frame ``i``'s target with its invalid pixels NaN (one load; a copy only when it is cached)."""
        img, valid = self.get(i)
        cube = img.numpy().copy() if (self.name, i) in self.lru else img.numpy()
        cube[~valid.numpy()] = np.nan
        return cube

    def for_sampling(self, i: int):
        """Frame ``i`` for a sampler of pixels (brfgs.spectral.autoencoder.sample_pixels): its target with
        NaN where invalid when the cache holds it or has room for it, else the frame read by row blocks
        (:class:`brfgs.data.pixels.FramePixels`; a store without a transform)."""
        if self.transform is None and (self.name, i) not in self.lru and not self.lru.room(self.frame_bytes):
            return FramePixels(self.scene, i, self.bands)
        return self.get_with_nan(i)

    def get(self, i: int) -> tuple[Tensor, Tensor]:
        """The whole frame ``i``'s target (held in the cache when it fits, evicting the least recently used)."""
        hit = self.lru.get((self.name, i))
        if hit is not None:
            return hit
        out = self._load(i)
        self.lru.put((self.name, i), out, self.frame_bytes)
        return out

    def get_window(self, i: int, window: tuple[int, int, int, int]) -> tuple[Tensor, Tensor]:
        """``get(i)`` cropped to ``window`` = (x0, y0, w, h), the same values: from the cache when it holds
        the frame or has room for it (evicting only other stores' frames), else the window read from the
        file (the frame's whole-frame checks made once first, a row block at a time)."""
        x0, y0, w, h = window
        hit = self.lru.get((self.name, i))
        if hit is None and self.lru.room(self.frame_bytes, self._mine):
            hit = self._load(i)
            self.lru.put((self.name, i), hit, self.frame_bytes, self._mine)
        if hit is not None:
            return hit[0][y0:y0 + h, x0:x0 + w], hit[1][y0:y0 + h, x0:x0 + w]
        if i not in self._checked:
            self.scene.check_image(i, self.bands)
            self._checked.add(i)
        return self._target(self.scene.load_window(i, window, bands=self.bands))

    def tiles(self, i: int, cam, tile_px: int | None = None):
        """(camera, target [h, w, C], valid [h, w]) pieces that cover frame ``i`` seen by ``cam`` (a
        brfgs.model.camera.Camera of the whole frame): the whole frame when the cache holds it or has
        room for it, else windows of at most ``tile_px`` (default TILE_PX) square read from the file, each
        with its camera (``cam.crop``), so that no whole cube of a large frame is in memory."""
        tile_px = tile_px or TILE_PX
        if (self.name, i) in self.lru or self.lru.room(self.frame_bytes):
            yield (cam, *self.get(i))
            return
        w, h = self.scene.width, self.scene.height
        for y0 in range(0, h, tile_px):
            for x0 in range(0, w, tile_px):
                win = (x0, y0, min(tile_px, w - x0), min(tile_px, h - y0))
                yield (cam.crop(*win), *self.get_window(i, win))

    def preload(self, progress: bool = False) -> None:
        """Load the frames into the cache while they fit without evicting any."""
        for i in tqdm(self.indices, desc="loading images", leave=False, disable=not progress):
            if (self.name, i) not in self.lru and not self.lru.room(self.frame_bytes, lambda k: True):
                break
            self.get(i)


class TrainImages:
    """The image stores of a run's training frames, made on first use: ``"colors"`` (the
    stage-1 bands), ``"full"`` (all bands), ``"cir"`` (CIR composites); they share one cache of
    ``cache_gib`` GiB."""

    def __init__(self, scene, stage1_bands: list[int], cir_indices: list[int], cir_scale, cache_gib: float):
        self.scene = scene
        self.stage1_bands = list(stage1_bands)
        self.cir_indices = list(cir_indices)
        self.cir_scale = np.asarray(cir_scale)
        self.cache_gib = cache_gib
        self.cache = ByteLRU(cache_gib * 2**30)
        self._stores: dict[str, ImageStore] = {}

    def __call__(self, kind: str) -> ImageStore:
        if kind not in self._stores:
            sc, idx = self.scene, self.scene.train_indices
            if kind == "colors":
                s = ImageStore(sc, idx, bands=self.stage1_bands, cache=self.cache, name=kind)
            elif kind == "full":
                s = ImageStore(sc, idx, bands=None, cache=self.cache, name=kind)
            elif kind == "cir":
                scale = self.cir_scale
                s = ImageStore(sc, idx, bands=self.cir_indices, cache=self.cache, name=kind,
                               transform=lambda cube: cir_composite(cube, (0, 1, 2), scale))
            else:
                raise ValueError(f"unknown image kind {kind!r}")
            self._stores[kind] = s
        return self._stores[kind]
