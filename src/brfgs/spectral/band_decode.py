"""Decoding a few bands of the spectral decoder D_φ (eq. 13) without decoding all of them.

A display frame needs 1–3 bands (CIR, true colour, a band, an index), but
:meth:`brfgs.spectral.SpectralAutoencoder.decode` computes all B. Its convolutional branch is
local: band o of ``dec_up2`` (a transposed convolution, kernel 4, stride 2, padding 1) reads two
positions of ``dec_up1``'s output, each of which reads two positions of ``gelu(dec_fc(z))``. So
the bands ``bands`` need only those rows of ``dec_fc`` and those taps of the two transposed
convolutions; the linear branch ``dec_lin`` needs its rows ``bands``. The result equals
``decode(z)[..., bands]`` (tested); decoders whose convolution output is shorter than B
(interpolated) fall back to the full decode. Each band is decoded through its own small dense
matrices (a band's two up1 positions read at most three dec_fc positions), pixels in blocks that
stay in the cache: 3x the previous single set of dense products over all the bands' positions
for a CIR frame at 256² (`brfgs bench viewer`, BENCHMARKS.md). A linear basis decodes band o as one
dot product, W[o] · z + b[o].
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from brfgs.spectral.linear_basis import LinearBasis

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


# pixels per block: a band's intermediates ([block, c2·P0] and [block, c1·P1]) stay in the cache
# (8192 measured fastest on two cores: 3.0x the one-block dense products at 256², 1.6x with 65536)
BLOCK_PX = 8192


def _band_plan(ae, o: int) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """The part of the convolutional branch that band ``o`` reads, as dense matrices:
    (dec_fc rows [c2·P0, d] and bias [c2·P0], up1 [c2·P0, c1·P1] and bias [c1·P1], up2 [c1·P1, 1])
    with P1 ≤ 2 positions of up1's output and P0 ≤ 3 positions of dec_fc's output."""
    L2, c2 = ae._L2, ae.channels2
    w1, w2 = ae.dec_up1.weight, ae.dec_up2.weight[:, 0]  # [c2, c1, K], [c1, K]
    c1 = w1.shape[1]
    taps2 = _taps(o, ae.dec_up2, 2 * L2)
    taps1 = [_taps(q, ae.dec_up1, L2) for q, _ in taps2]
    pos0 = sorted({i for t in taps1 for i, _ in t})
    col0 = {i: j for j, i in enumerate(pos0)}
    rows = torch.tensor([c * L2 + i for c in range(c2) for i in pos0], dtype=torch.long)
    m1 = torch.zeros(c2, len(pos0), c1, len(taps2), dtype=w1.dtype)
    m2 = torch.zeros(c1, len(taps2), dtype=w2.dtype)
    for jq, (_, k2) in enumerate(taps2):
        m2[:, jq] = w2[:, k2]
        for i, k in taps1[jq]:
            m1[:, col0[i], :, jq] += w1[:, :, k]
    return (ae.dec_fc.weight[rows], ae.dec_fc.bias[rows], m1.reshape(c2 * len(pos0), c1 * len(taps2)),
            ae.dec_up1.bias.repeat_interleave(len(taps2)), m2.reshape(-1, 1))


@torch.no_grad()
def decode_bands(ae, z: Tensor, bands: Sequence[int]) -> Tensor:  # [..., nb]
    """Reflectance in bands ``bands`` [nb] of latents ``z`` [..., d]: ``ae.decode(z)[..., bands]`` (``ae``
    the autoencoder or a :class:`LinearBasis`).

    Each band is decoded on its own (its ≤ 3 dec_fc positions, ≤ 2 up1 positions), in blocks of
    :data:`BLOCK_PX` pixels."""
    bands = [int(b) for b in bands]
    if isinstance(ae, LinearBasis):  # one dot product per band
        idx = torch.tensor(bands, dtype=torch.long)
        w, b = ae.weight[idx], ae.bias[idx]
        return F.linear(z, w.to(z.dtype), b.to(z.dtype))
    if 4 * ae._L2 < ae.n_bands:  # the conv branch is interpolated to B: no shortcut
        return ae.decode(z)[..., bands]
    shp = z.shape[:-1]
    z2 = z.reshape(-1, ae.latent_dim).to(ae.dec_fc.weight.dtype)  # [N, d]
    idx = torch.tensor(bands, dtype=torch.long)
    x = F.linear(z2, ae.dec_lin.weight[idx], ae.dec_lin.bias[idx]) + ae.dec_up2.bias[0]  # [N, nb] linear branch
    plans = [_band_plan(ae, o) for o in bands]
    for s in range(0, z2.shape[0], BLOCK_PX):
        zb = z2[s : s + BLOCK_PX]
        for j, (w0, b0, m1, b1, m2) in enumerate(plans):
            h0 = F.gelu(F.linear(zb, w0, b0))  # [n, c2·P0]
            h1 = F.gelu(torch.addmm(b1, h0, m1))  # [n, c1·P1]
            x[s : s + BLOCK_PX, j : j + 1] += h1 @ m2
    r = x * ae.band_std[idx] + ae.band_mean[idx]
    return r.reshape(*shp, len(bands))
