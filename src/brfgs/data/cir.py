"""Colour-infrared (CIR) composites (conventions: "Splits and metrics").

Bands nearest 850, 650 and 550 nm become R, G, B; each is divided by that band's 99th
percentile over the training images and clipped to [0, 1]. PSNR/SSIM/LPIPS are computed
on this composite, so the scale is a property of the data set, computed once.
"""

from __future__ import annotations

import sys

import numpy as np

CIR_WAVELENGTHS_NM = (850.0, 650.0, 550.0)
CIR_PERCENTILE = 99.0


def cir_band_indices(wavelengths_nm) -> tuple[int, int, int]:
    """Indices of the bands nearest 850, 650 and 550 nm (R, G, B of the composite)."""
    wl = np.asarray(wavelengths_nm, float)
    return tuple(int(np.argmin(np.abs(wl - w))) for w in CIR_WAVELENGTHS_NM)  # type: ignore[return-value]


def cir_scale_from_images(images, indices) -> np.ndarray:
    """Per-channel scale [3]: 99th percentile of each CIR band over ``images`` ([H, W, B] each), NaN ignored."""
    vals = [np.concatenate([np.asarray(img)[..., b].ravel() for img in images]) for b in indices]
    scale = np.array([np.nanpercentile(v, CIR_PERCENTILE) for v in vals])
    return np.where(scale > 0, scale, 1.0)


def cir_scale(scene) -> np.ndarray:
    """Per-channel scale [3] of a scene: 99th percentile over its training images (reads 3 bands only)."""
    idx = cir_band_indices(scene.wavelengths_nm)
    images = [scene.load_image(i, bands=list(idx)) for i in scene.train_indices]
    return cir_scale_from_images(images, (0, 1, 2))


def cir_composite(cube, indices, scale):
    """CIR composite [H, W, 3] in [0, 1] of a cube [H, W, B] (numpy or torch); NaN stays NaN."""
    if type(cube).__module__.startswith("torch"):
        torch = sys.modules["torch"]  # loaded, since cube is a tensor; brfgs.data never imports it
        rgb = cube[..., list(indices)] / torch.as_tensor(scale, dtype=cube.dtype, device=cube.device)
        return rgb.clamp(0.0, 1.0)
    rgb = np.asarray(cube)[..., list(indices)] / np.asarray(scale, dtype=np.float64)
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)
