"""Decoding a few bands of the spectral decoder D_φ (eq. 13) without decoding all of them.

A display frame needs 1–3 bands (CIR, true colour, a band, an index), but
:meth:`brfgs.spectral.SpectralAutoencoder.decode` computes all B. Its convolutional branch is
local: band o of ``dec_up2`` (a transposed convolution, kernel 4, stride 2, padding 1) reads two
positions of ``dec_up1``'s output, each of which reads two positions of ``gelu(dec_fc(z))``. So
the bands ``bands`` need only those rows of ``dec_fc`` and those taps of the two transposed
convolutions; the linear branch ``dec_lin`` needs its rows ``bands``. The result equals
``decode(z)[..., bands]`` (tested); decoders whose convolution output is shorter than B
(interpolated) fall back to the full decode.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["decode_bands"]


def _taps(out_pos: int, conv: torch.nn.ConvTranspose1d, length_in: int) -> list[tuple[int, int]]:
    """(input position, kernel tap) pairs that a 1D transposed convolution sums into ``out_pos``."""
    (k_size,), (stride,), (pad,) = conv.kernel_size, conv.stride, conv.padding
    out = []
    for k in range(k_size):
        num = out_pos + pad - k
        if num % stride == 0 and 0 <= num // stride < length_in:
            out.append((num // stride, k))
    return out


@torch.no_grad()
def decode_bands(ae, z: Tensor, bands: Sequence[int]) -> Tensor:  # [..., nb]
    """Reflectance in bands ``bands`` [nb] of latents ``z`` [..., d]: ``ae.decode(z)[..., bands]``."""
    bands = [int(b) for b in bands]
    L2, c2 = ae._L2, ae.channels2
    if 4 * L2 < ae.n_bands:  # the conv branch is interpolated to B: no shortcut
        return ae.decode(z)[..., bands]
    shp = z.shape[:-1]
    z2 = z.reshape(-1, ae.latent_dim).to(ae.dec_fc.weight.dtype)  # [N, d]
    L1 = 2 * L2
    taps2 = {o: _taps(o, ae.dec_up2, L1) for o in bands}
    pos1 = sorted({q for t in taps2.values() for q, _ in t})
    taps1 = {q: _taps(q, ae.dec_up1, L2) for q in pos1}
    pos0 = sorted({i for t in taps1.values() for i, _ in t})
    col0 = {i: j for j, i in enumerate(pos0)}
    rows = torch.tensor([c * L2 + i for c in range(c2) for i in pos0], dtype=torch.long)
    h0 = F.gelu(F.linear(z2, ae.dec_fc.weight[rows], ae.dec_fc.bias[rows])).reshape(-1, c2, len(pos0))  # [N, c2, P0]
    # both transposed convolutions restricted to the positions needed, as dense matrices
    w1, w2 = ae.dec_up1.weight, ae.dec_up2.weight[:, 0]  # [c2, c1, K], [c1, K]
    c1 = w1.shape[1]
    m1 = torch.zeros(c2, len(pos0), c1, len(pos1), dtype=w1.dtype)
    for jq, q in enumerate(pos1):
        for i, k in taps1[q]:
            m1[:, col0[i], :, jq] += w1[:, :, k]
    h1 = F.gelu(h0.reshape(-1, c2 * len(pos0)) @ m1.reshape(c2 * len(pos0), c1 * len(pos1))
                + ae.dec_up1.bias.repeat_interleave(len(pos1)))  # [N, c1·P1]
    col1 = {q: j for j, q in enumerate(pos1)}
    m2 = torch.zeros(c1, len(pos1), len(bands), dtype=w2.dtype)
    for jb, o in enumerate(bands):
        for q, k in taps2[o]:
            m2[:, col1[q], jb] += w2[:, k]
    conv = h1 @ m2.reshape(c1 * len(pos1), len(bands)) + ae.dec_up2.bias[0]  # [N, nb]
    idx = torch.tensor(bands, dtype=torch.long)
    lin = F.linear(z2, ae.dec_lin.weight[idx], ae.dec_lin.bias[idx])  # [N, nb]
    x = lin + conv
    r = x * ae.band_std[idx] + ae.band_mean[idx]
    return r.reshape(*shp, len(bands))
