"""Checkpoints and model files: safetensors (tensors only) + JSON metadata.

Loading never executes code: :func:`load` uses ``safetensors`` (no pickle). Files are
self-describing: the metadata string ``brfgs`` holds the training config, the scene
description (wavelengths, sun angles, intrinsics, frames with poses and split), the band
selection, CIR scale, the appearance head and the autoencoder architecture, so ``render``,
``brf`` and ``evaluate`` can use a model without the training scene.

Tensor name prefixes: ``param.`` Gaussian tensors, ``extra.`` non-per-Gaussian parameters
(backgrounds), ``decoder.`` spectral autoencoder, ``neural.`` neural head, ``optim.`` Adam
moments, ``densify.`` densification statistics, ``rng.`` generator state.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from brfgs.errors import UserError

FORMAT = "brfgs-gaussians/1"


def save(path: str | Path, tensors: dict[str, torch.Tensor], meta: dict) -> Path:
    """Atomically write ``tensors`` + JSON ``meta`` to ``path`` (safetensors)."""
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    clean = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    save_file(clean, str(tmp), metadata={"format": FORMAT, "brfgs": json.dumps(meta)})
    os.replace(tmp, path)
    return path


def load(path: str | Path) -> tuple[dict[str, torch.Tensor], dict]:
    """(tensors, meta) of a file written by :func:`save`; UserError if it is not one."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise UserError("model/checkpoint file not found", file=path)
    try:
        tensors = {}
        with safe_open(str(path), framework="pt") as f:
            md = f.metadata() or {}
            for k in f.keys():
                tensors[k] = f.get_tensor(k)
    except Exception as exc:
        raise UserError(f"not a readable safetensors file ({exc})", file=path) from None
    if md.get("format") != FORMAT or "brfgs" not in md:
        raise UserError(f"not a brfgs model file (format {md.get('format')!r}, expected {FORMAT!r})", file=path)
    return tensors, json.loads(md["brfgs"])


def with_prefix(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    """Sub-dict of names starting with ``prefix``, prefix removed."""
    return {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}


def prefixed(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    return {prefix + k: v for k, v in tensors.items()}
