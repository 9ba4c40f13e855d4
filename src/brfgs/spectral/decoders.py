"""The two spectral bases a model may hold, and how each goes into a model file.

``"autoencoder"``: :class:`brfgs.spectral.autoencoder.SpectralAutoencoder` (paper eq. 9, nonlinear);
``"linear"``: :class:`brfgs.spectral.linear_basis.LinearBasis` (D(z) = W z + b). A model file records
which in its metadata key ``spectral_basis``; files without the key hold the autoencoder.
"""

from __future__ import annotations

import json

from brfgs.spectral.autoencoder import SpectralAutoencoder, autoencoder_from_state, autoencoder_state
from brfgs.spectral.linear_basis import LinearBasis, linear_basis_from_state, linear_basis_state

__all__ = ["SPECTRAL_BASES", "DESCRIPTION_KEYS", "SpectralDecoder", "basis_kind", "is_linear", "decoder_metadata",
           "decoder_state", "decoder_from_state", "decoder_from_description"]

SPECTRAL_BASES = ("autoencoder", "linear")
DESCRIPTION_KEYS = {"autoencoder": "autoencoder", "linear": "linear_basis"}  # metadata key of each description
SpectralDecoder = SpectralAutoencoder | LinearBasis


def basis_kind(decoder) -> str:
    """"linear" for a :class:`LinearBasis`, else "autoencoder"."""
    return "linear" if isinstance(decoder, LinearBasis) else "autoencoder"


def is_linear(decoder) -> bool:
    """Whether ``decoder`` is affine (a :class:`LinearBasis`)."""
    return isinstance(decoder, LinearBasis)


def decoder_metadata(decoder) -> dict:
    """The model-file metadata of ``decoder``: ``spectral_basis`` and its JSON description."""
    kind = basis_kind(decoder)
    return {"spectral_basis": kind, DESCRIPTION_KEYS[kind]: json.dumps(decoder.describe())}


def decoder_state(decoder, prefix: str = "decoder.") -> tuple[dict, dict]:
    """(tensors under ``prefix``, :func:`decoder_metadata`)."""
    tensors = (linear_basis_state if is_linear(decoder) else autoencoder_state)(decoder, prefix)[0]
    return tensors, decoder_metadata(decoder)


def decoder_from_state(tensors: dict, meta: dict, prefix: str = "decoder.") -> SpectralDecoder:
    """The decoder of a model file's (tensors, metadata) (:func:`decoder_state`'s inverse); a file
    without ``spectral_basis`` holds the autoencoder."""
    kind = meta.get("spectral_basis", "autoencoder")
    if kind == "linear":
        return linear_basis_from_state(tensors, meta, prefix)
    if kind == "autoencoder":
        return autoencoder_from_state(tensors, meta, prefix)
    raise ValueError(f"unknown spectral basis {kind!r} (expected one of {', '.join(SPECTRAL_BASES)})")


def decoder_from_description(meta: dict) -> SpectralDecoder:
    """A decoder of the architecture a model file's metadata describes (its weights as made, not loaded):
    what :func:`decoder_from_state` fills, e.g. to list the tensors a file must hold."""
    kind = meta.get("spectral_basis", "autoencoder")
    if kind not in SPECTRAL_BASES:
        raise ValueError(f"unknown spectral basis {kind!r} (expected one of {', '.join(SPECTRAL_BASES)})")
    cls = LinearBasis if kind == "linear" else SpectralAutoencoder
    return cls.from_description(json.loads(meta[DESCRIPTION_KEYS[kind]]))
