"""The spectral encoder (eq. 9) as one fused numba kernel per pixel, forward only.

:meth:`SpectralAutoencoder.encode` (PyTorch: two strided Conv1d with GELU, a Linear) stays the reference;
:func:`encode_spectra` computes the same map with a pixel's feature maps (8 × L1 and 16 × L2) kept in
cache, for the places that encode whole images without gradients (the back-projected appearance
targets at the start of stage 2 encode every pixel of every training view). GELU and its vectorised erf
are :mod:`brfgs.spectral.fast_math`'s. Results equal the reference within float rounding
(tests/test_fast_decode.py).
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from brfgs.spectral.autoencoder import SpectralAutoencoder
from brfgs.spectral.fast_decode import _FUSED, _sync_threads
from brfgs.spectral.fast_math import FASTMATH_FLAGS as _FM
from brfgs.spectral.fast_math import gelu as _gelu

__all__ = ["encode_spectra"]

_BLOCK = 64


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True, error_model="numpy")
def _encode_fwd(r, mean, std, w1, b1, w2, b2, wfc, bfc, z):
    """z [N, d] = encode(r [N, B]): conv1 w1 [c1, 7] (stride 2, padding 3), conv2 w2 [c2, c1, 5] (stride 2,
    padding 2), fully connected wfc [d, c2·L2] over the channels-first flattening. Each strided
    convolution reads its zero-padded input as even and odd planes (input 2j + t = plane t % 2 at j + t // 2),
    so every inner loop runs over contiguous positions."""
    n_pix, n_bands = r.shape
    c1, c2 = w1.shape[0], w2.shape[0]
    l1 = (n_bands - 1) // 2 + 1
    l2 = (l1 - 1) // 2 + 1
    d = wfc.shape[0]
    for blk in prange((n_pix + _BLOCK - 1) // _BLOCK):
        xp = np.zeros((2, l1 + 4), r.dtype)                # padded spectrum (3 zeros first), even/odd planes
        hp = np.zeros((c1, 2, l2 + 3), r.dtype)           # padded conv1 activations (2 zeros first), planes
        acc = np.empty(l1, r.dtype)
        h2 = np.empty(c2 * l2, r.dtype)
        for n in range(blk * _BLOCK, min(n_pix, (blk + 1) * _BLOCK)):
            for b in range(n_bands):
                q = b + 3
                xp[q % 2, q // 2] = (r[n, b] - mean[b]) / std[b]
            for o in range(c1):
                for j in range(l1):
                    acc[j] = b1[o]
                for t in range(7):
                    w, pl, off = w1[o, t], t % 2, t // 2
                    for j in range(l1):
                        acc[j] += w * xp[pl, j + off]
                for j in range(l1):
                    q = j + 2
                    hp[o, q % 2, q // 2] = _gelu(acc[j])
            for o in range(c2):
                for j in range(l2):
                    acc[j] = b2[o]
                for ci in range(c1):
                    for t in range(5):
                        w, pl, off = w2[o, ci, t], t % 2, t // 2
                        for j in range(l2):
                            acc[j] += w * hp[ci, pl, j + off]
                for j in range(l2):
                    h2[o * l2 + j] = _gelu(acc[j])
            for k in range(d):
                s = bfc[k]
                for i in range(c2 * l2):
                    s += wfc[k, i] * h2[i]
                z[n, k] = s


def encode_spectra(encoder: SpectralAutoencoder, r: torch.Tensor) -> torch.Tensor:
    """Reflectance [..., B] → latent [..., d] (eq. 9): the fused kernel for CPU float32/float64 input when
    no gradient is wanted, else ``encoder.encode`` (the reference)."""
    wants_grad = torch.is_grad_enabled() and (r.requires_grad or any(p.requires_grad for p in encoder.parameters()))
    if (not _FUSED[0] or wants_grad or type(encoder) is not SpectralAutoencoder or r.device.type != "cpu"
            or r.dtype not in (torch.float32, torch.float64)):
        return encoder.encode(r)
    flat = r.detach().reshape(-1, encoder.n_bands).contiguous()

    def a(t: torch.Tensor) -> np.ndarray:
        return np.ascontiguousarray(t.detach().to(r.dtype).numpy())

    z = torch.empty(flat.shape[0], encoder.latent_dim, dtype=r.dtype)
    _sync_threads()
    _encode_fwd(flat.numpy(), a(encoder.band_mean), a(encoder.band_std), a(encoder.enc_conv1.weight[:, 0]),
                a(encoder.enc_conv1.bias), a(encoder.enc_conv2.weight), a(encoder.enc_conv2.bias),
                a(encoder.enc_fc.weight), a(encoder.enc_fc.bias), z.numpy())
    return z.reshape(*r.shape[:-1], encoder.latent_dim)
