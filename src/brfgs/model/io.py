"""Model files and checkpoints: safetensors (tensors only) + JSON metadata.

Loading never executes code: :func:`load` uses ``safetensors`` (no pickle). Files are
self-describing: the metadata string ``brfgs`` holds the schema version, the training
config, the scene description (wavelengths, sun angles, intrinsics, frames with poses and
split), the band selection, CIR scale, the appearance head and the spectral decoder
(``spectral_basis``: "autoencoder" or "linear" — files without it hold the autoencoder — and its
description under ``autoencoder`` or ``linear_basis``), so a model renders without the training
scene (:class:`brfgs.model.trained.TrainedModel`).

Tensor name prefixes: ``param.`` Gaussian tensors, ``extra.`` non-per-Gaussian parameters
(backgrounds), ``decoder.`` spectral decoder, ``neural.`` neural head; checkpoints add
``optim.`` Adam moments, ``densify.`` densification statistics, ``rng.`` generator state.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file

from brfgs.data.atomic import atomic_path, json_text
from brfgs.errors import UserError

FORMAT = "brfgs-gaussians/1"
# Version of the metadata layout. 1: files written before the version was recorded (same layout);
# 2: ``schema_version`` recorded and validated on load, a SHA-256 of the metadata and the tensors.
SCHEMA_VERSION = 2


def content_digest(tensors: dict[str, torch.Tensor], meta_json: str) -> str:
    """SHA-256 (hex) of the metadata string and every tensor's name, dtype, shape and bytes."""
    h = hashlib.sha256(meta_json.encode())
    for name in sorted(tensors):
        t = tensors[name].detach().contiguous().cpu()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy())
    return h.hexdigest()


def save(path: str | Path, tensors: dict[str, torch.Tensor], meta: dict) -> Path:
    """Write ``tensors`` + JSON ``meta`` (with the schema version and a checksum) to ``path``
    atomically (:func:`brfgs.data.atomic.atomic_path`)."""
    clean = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    text = json_text({"schema_version": SCHEMA_VERSION, **meta})
    with atomic_path(path) as tmp:
        save_file(clean, str(tmp), metadata={"format": FORMAT, "brfgs": text, "sha256": content_digest(clean, text)})
    return Path(path)


def load(path: str | Path) -> tuple[dict[str, torch.Tensor], dict]:
    """(tensors, meta) of a file written by :func:`save`; UserError naming the file if it is not one."""
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
    if "sha256" in md and md["sha256"] != content_digest(tensors, md["brfgs"]):
        raise UserError("the tensors or metadata do not match the file's checksum (a damaged file)", file=path,
                        field="sha256")
    try:
        meta = json.loads(md["brfgs"])
    except (ValueError, RecursionError):
        raise UserError("metadata is not valid JSON", file=path, field="brfgs") from None
    if not isinstance(meta, dict):
        raise UserError(f"metadata must be a JSON object, got {type(meta).__name__}", file=path, field="brfgs")
    version = meta.get("schema_version", 1)
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= SCHEMA_VERSION:
        raise UserError(f"schema version {version!r} is not supported (this brfgs reads 1..{SCHEMA_VERSION}; "
                        "a newer brfgs wrote it?)", file=path, field="schema_version")
    return tensors, meta


def with_prefix(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    """Sub-dict of names starting with ``prefix``, prefix removed."""
    return {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}


def prefixed(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    """``tensors`` with every name prefixed by ``prefix``."""
    return {prefix + k: v for k, v in tensors.items()}
