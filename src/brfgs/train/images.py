"""Training targets: the frames' cubes as tensors, cached in memory up to a byte budget."""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from brfgs.data.cir import cir_composite


class ImageStore:
    """Training targets of some frames: cached in memory up to ``cache_gib``, else read per use.

    ``get(i)`` -> (image [H, W, C] float32 tensor with invalid pixels zeroed, valid [H, W] bool).
    ``transform`` maps a loaded cube [H, W, b] (numpy) to the stored target (e.g. CIR composite).
    """

    def __init__(self, scene, indices, bands=None, cache_gib: float = 4.0,
                 transform: Callable[[np.ndarray], np.ndarray] | None = None):
        self.scene = scene
        self.bands = None if bands is None else [int(b) for b in bands]
        self.transform = transform
        self.cache: dict[int, tuple[Tensor, Tensor]] = {}
        nb = scene.n_bands if bands is None else len(bands)
        total = len(indices) * scene.width * scene.height * nb * 4
        self.cached = total <= cache_gib * 2**30
        self.indices = list(indices)

    def _load(self, i: int) -> tuple[Tensor, Tensor]:
        cube = self.scene.load_image(i, bands=self.bands)
        if self.transform is not None:
            cube = self.transform(cube)
        cube = np.array(cube, np.float32, copy=None)     # the reader's fresh array: zeroed in place, no copies
        valid = np.isfinite(cube).all(-1)
        cube[~valid] = 0.0
        return torch.from_numpy(cube), torch.from_numpy(valid)

    def get_with_nan(self, i: int) -> np.ndarray:  # [H, W, C] float32
        """Frame ``i``'s target with its invalid pixels NaN (one load; a copy only when it is cached)."""
        img, valid = self.get(i)
        cube = img.numpy().copy() if i in self.cache else img.numpy()
        cube[~valid.numpy()] = np.nan
        return cube

    def get(self, i: int) -> tuple[Tensor, Tensor]:
        if i in self.cache:
            return self.cache[i]
        out = self._load(i)
        if self.cached:
            self.cache[i] = out
        return out

    def preload(self, progress: bool = False) -> None:
        if not self.cached:
            return
        for i in tqdm(self.indices, desc="loading images", leave=False, disable=not progress):
            self.get(i)


class TrainImages:
    """The image stores of a run's training frames, made on first use: ``"colors"`` (the
    stage-1 bands), ``"full"`` (all bands), ``"cir"`` (CIR composites)."""

    def __init__(self, scene, stage1_bands: list[int], cir_indices: list[int], cir_scale, cache_gib: float):
        self.scene = scene
        self.stage1_bands = list(stage1_bands)
        self.cir_indices = list(cir_indices)
        self.cir_scale = np.asarray(cir_scale)
        self.cache_gib = cache_gib
        self._stores: dict[str, ImageStore] = {}

    def __call__(self, kind: str) -> ImageStore:
        if kind not in self._stores:
            sc, idx = self.scene, self.scene.train_indices
            if kind == "colors":
                s = ImageStore(sc, idx, bands=self.stage1_bands, cache_gib=self.cache_gib)
            elif kind == "full":
                s = ImageStore(sc, idx, bands=None, cache_gib=self.cache_gib)
            elif kind == "cir":
                scale = self.cir_scale
                s = ImageStore(sc, idx, bands=self.cir_indices, cache_gib=self.cache_gib,
                               transform=lambda cube: cir_composite(cube, (0, 1, 2), scale))
            else:
                raise ValueError(f"unknown image kind {kind!r}")
            self._stores[kind] = s
        return self._stores[kind]
