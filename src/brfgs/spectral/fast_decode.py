"""The spectral decoder (eq. 13) as one fused numba kernel per pixel, forward and latent gradient.

:meth:`SpectralAutoencoder.decode` (PyTorch: Linear, GELU, two ConvTranspose1d) stays the reference;
:func:`fast_decode` computes the same map with every intermediate of a pixel (two 16 × 41 and 8 × 82
feature maps) kept in the core's cache instead of streaming [N, 656] tensors through memory five times,
and the two transposed convolutions (kernel 4, stride 2, padding 1) in polyphase form: output 2j reads
inputs j − 1 (tap 3) and j (tap 1), output 2j + 1 reads j (tap 2) and j + 1 (tap 0) — half the taps of
a dense transposed convolution and no zero-stuffing. Feature maps are channels-first, so the inner
loops run along the 41–82 positions of a channel and vectorise.

GELU is exact-form, 0.5 x (1 + erf(x / √2)), with erf as a rational function of x² on [−4, 4] (the
form XLA and Eigen vectorise; 6.5e-8 from math.erf in float64, ≈4e-7 evaluated in float32) instead of a
library call, so it vectorises too. Results equal the reference within float rounding
(tests/test_fast_decode.py: 1e-5). The backward gives the gradient with respect to the latent only:
:func:`fast_decode` is used when the decoder is frozen (training's default) or without gradients,
:func:`brfgs.model.rendering.decode_image` falls back to the reference otherwise.
"""

from __future__ import annotations

import contextlib
import math
import weakref

import numba as nb
import numpy as np
import torch
from numba import njit, prange

from brfgs.spectral.autoencoder import SpectralAutoencoder

__all__ = ["DecoderPlan", "fast_decode", "can_fast_decode", "reference_decoding"]

_FUSED = [True]  # switched off by reference_decoding()

_FM = {"nsz", "arcp", "contract", "reassoc"}
_BLOCK = 64  # pixels per parallel work item (scratch stays in L1/L2)


# Coefficients as float32 scalars (numba types them float32, so float32 pixels stay in float32 SIMD lanes;
# float64 pixels promote them exactly).
_P = tuple(np.float32(c) for c in (-2.72614225801306e-10, 2.77068142495902e-08, -2.10102402082508e-06,
                                   -5.69250639462346e-05, -7.34990630326855e-04, -2.95459980854025e-03,
                                   -1.60960333262415e-02))
_Q = tuple(np.float32(c) for c in (-1.45660718464996e-05, -2.13374055278905e-04, -1.68282697438203e-03,
                                   -7.37332916720468e-03, -1.42647390514189e-02))
_P0, _P1, _P2, _P3, _P4, _P5, _P6 = _P
_Q0, _Q1, _Q2, _Q3, _Q4 = _Q
_FOUR, _HALF, _ONE, _SQRT1_2, _INV_SQRT_2PI = (np.float32(v) for v in (4.0, 0.5, 1.0, 0.7071067811865476,
                                                                     0.3989422804014327))


@njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _erf(x):
    """erf(x) as P(x²)·x / Q(x²) on x clamped to [−4, 4] (module docstring)."""
    x = min(max(x, -_FOUR), _FOUR)
    x2 = x * x
    p = ((((((_P0 * x2 + _P1) * x2 + _P2) * x2 + _P3) * x2 + _P4) * x2 + _P5) * x2 + _P6)
    q = ((((_Q0 * x2 + _Q1) * x2 + _Q2) * x2 + _Q3) * x2 + _Q4)
    return x * p / q


@njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _gelu(x):
    return _HALF * x * (_ONE + _erf(x * _SQRT1_2))


_E = tuple(np.float32(1.0 / math.factorial(k)) for k in range(10))
_E0, _E1, _E2, _E3, _E4, _E5, _E6, _E7, _E8, _E9 = _E
_EXP_MIN, _SIXTEENTH = np.float32(-24.0), np.float32(0.0625)


@njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _exp_neg(y):
    """exp(y) for y ≤ 0 as (Taylor₉(y/16))¹⁶, y clamped to [−24, 0]: a vectorisable exp for φ(x) =
    exp(−x²/2)/√(2π) in the GELU derivative (tests/test_fast_decode.py bounds the error of x·φ(x))."""
    u = max(y, _EXP_MIN) * _SIXTEENTH
    p = _E0 + u * (_E1 + u * (_E2 + u * (_E3 + u * (_E4 + u * (_E5 + u * (_E6 + u * (_E7 + u * (_E8 + u * _E9))))))))
    p = p * p
    p = p * p
    p = p * p
    return p * p


@njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _gelu_grad(x):
    """d gelu / dx = Φ(x) + x φ(x)."""
    return _HALF * (_ONE + _erf(x * _SQRT1_2)) + x * _INV_SQRT_2PI * _exp_neg(-_HALF * x * x)


@njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _affine(z, n, w, b, out):
    """out [M] = b + wᵀ z[n] for w [d, M] (a fully connected layer on pixel n's latent)."""
    for i in range(out.shape[0]):
        out[i] = b[i]
    for k in range(w.shape[0]):
        zk = z[n, k]
        for i in range(out.shape[0]):
            out[i] += w[k, i] * zk


@njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _forward_pixel(z, n, wfc, bfc, w1, b1, a1, h1, a2e, a2o, h2):
    """Pre-activations and activations of pixel n, channels first: a1, h1 [c2·L2] (the fully connected
    layer, c·L2 + l as the reference reshapes it), a2e/a2o [c1, L2] (the first transposed convolution's
    even/odd outputs 2j, 2j+1), h2 [c1, 2·L2] (their GELU, interleaved)."""
    m1 = wfc.shape[1]
    c2, c1 = w1.shape[2], w1.shape[3]
    l2 = m1 // c2
    _affine(z, n, wfc, bfc, a1)
    for i in range(m1):
        h1[i] = _gelu(a1[i])
    for co in range(c1):
        for j in range(l2):
            a2e[co, j] = b1[co]
            a2o[co, j] = b1[co]
        for ci in range(c2):
            b = ci * l2
            we0, we1, wo0, wo1 = w1[0, 0, ci, co], w1[0, 1, ci, co], w1[1, 0, ci, co], w1[1, 1, ci, co]
            for j in range(l2):
                a2e[co, j] += we1 * h1[b + j]
                a2o[co, j] += wo0 * h1[b + j]
            for j in range(1, l2):
                a2e[co, j] += we0 * h1[b + j - 1]
            for j in range(l2 - 1):
                a2o[co, j] += wo1 * h1[b + j + 1]
        for j in range(l2):
            h2[co, 2 * j] = _gelu(a2e[co, j])
            h2[co, 2 * j + 1] = _gelu(a2o[co, j])


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True, error_model="numpy")
def _decode_fwd(z, wfc, bfc, w1, b1, w2, b2, wlin, blin, std, mean, out, sa1, sa2):
    """out [N, B] = decode(z [N, d]) (module docstring); when sa1 has rows, the pre-activations are
    kept for the backward: sa1 [N, c2·L2], sa2 [N, 2, c1, L2] (even, odd)."""
    n_pix, n_bands = out.shape
    c2, c1 = w1.shape[2], w1.shape[3]
    l2 = wfc.shape[1] // c2
    l3 = 2 * l2
    for blk in prange((n_pix + _BLOCK - 1) // _BLOCK):
        a1 = np.empty(wfc.shape[1], z.dtype)
        h1 = np.empty(wfc.shape[1], z.dtype)
        a2e = np.empty((c1, l2), z.dtype)
        a2o = np.empty((c1, l2), z.dtype)
        h2 = np.empty((c1, l3), z.dtype)
        oe = np.empty(l3, z.dtype)
        oo = np.empty(l3, z.dtype)
        lin = np.empty(n_bands, z.dtype)
        for n in range(blk * _BLOCK, min(n_pix, (blk + 1) * _BLOCK)):
            _forward_pixel(z, n, wfc, bfc, w1, b1, a1, h1, a2e, a2o, h2)
            if sa1.shape[0] > 0:
                sa1[n, :] = a1
                sa2[n, 0] = a2e
                sa2[n, 1] = a2o
            for j in range(l3):
                oe[j] = b2
                oo[j] = b2
            for ci in range(c1):
                we0, we1, wo0, wo1 = w2[0, 0, ci], w2[0, 1, ci], w2[1, 0, ci], w2[1, 1, ci]
                for j in range(l3):
                    oe[j] += we1 * h2[ci, j]
                    oo[j] += wo0 * h2[ci, j]
                for j in range(1, l3):
                    oe[j] += we0 * h2[ci, j - 1]
                for j in range(l3 - 1):
                    oo[j] += wo1 * h2[ci, j + 1]
            _affine(z, n, wlin, blin, lin)
            for y in range(n_bands):
                h = oe[y // 2] if y % 2 == 0 else oo[y // 2]
                out[n, y] = (lin[y] + h) * std[y] + mean[y]


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True, error_model="numpy")
def _decode_bwd(z, g_out, wfc, bfc, w1, b1, w2, wlin, std, g_z, sa1, sa2):
    """g_z [N, d] = (∂ decode / ∂ z)ᵀ g_out [N, B] (the decoder's weights are constants); the forward's
    pre-activations are read from sa1/sa2 when it kept them, else recomputed."""
    n_pix, n_bands = g_out.shape
    c2, c1 = w1.shape[2], w1.shape[3]
    m1 = wfc.shape[1]
    l2 = m1 // c2
    l3 = 2 * l2
    d = z.shape[1]
    for blk in prange((n_pix + _BLOCK - 1) // _BLOCK):
        a1 = np.empty(m1, z.dtype)
        h1 = np.empty(m1, z.dtype)
        a2e = np.empty((c1, l2), z.dtype)
        a2o = np.empty((c1, l2), z.dtype)
        h2 = np.empty((c1, l3), z.dtype)
        g = np.empty(n_bands, z.dtype)
        ge = np.zeros(l3 + 1, z.dtype)
        go = np.zeros(l3 + 1, z.dtype)
        for n in range(blk * _BLOCK, min(n_pix, (blk + 1) * _BLOCK)):
            if sa1.shape[0] > 0:
                a1[:] = sa1[n]
                a2e[:, :] = sa2[n, 0]
                a2o[:, :] = sa2[n, 1]
            else:
                _forward_pixel(z, n, wfc, bfc, w1, b1, a1, h1, a2e, a2o, h2)
            for y in range(n_bands):
                g[y] = g_out[n, y] * std[y]
                if y % 2 == 0:
                    ge[y // 2] = g[y]
                else:
                    go[y // 2] = g[y]
            for k in range(d):
                s = g[0] * 0
                for y in range(n_bands):
                    s += wlin[k, y] * g[y]
                g_z[n, k] = s
            _backward_pixel(ge, go, w1, w2, a1, h1, a2e, a2o, h2)
            for k in range(d):
                s = g[0] * 0
                for i in range(m1):
                    s += wfc[k, i] * h1[i]
                g_z[n, k] += s


@njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _backward_pixel(ge, go, w1, w2, a1, h1, a2e, a2o, h2):
    """∂L/∂(even, odd outputs) ge, go [L3 (+1 zero)] → ∂L/∂a1 left in h1; a2e/a2o become ∂L/∂a2 and
    h2 ∂L/∂h2 (the forward's values there are overwritten)."""
    c2, c1 = w1.shape[2], w1.shape[3]
    l2 = a2e.shape[1]
    l3 = 2 * l2
    for ci in range(c1):
        we0, we1, wo0, wo1 = w2[0, 0, ci], w2[0, 1, ci], w2[1, 0, ci], w2[1, 1, ci]
        for j in range(l3):
            h2[ci, j] = we1 * ge[j] + wo0 * go[j] + we0 * ge[j + 1]   # output 2(j+1) reads input j (tap 3)
        for j in range(1, l3):
            h2[ci, j] += wo1 * go[j - 1]                              # output 2(j-1)+1 reads input j (tap 0)
        for j in range(l2):
            a2e[ci, j] = h2[ci, 2 * j] * _gelu_grad(a2e[ci, j])
            a2o[ci, j] = h2[ci, 2 * j + 1] * _gelu_grad(a2o[ci, j])
    for ci in range(c2):
        b = ci * l2
        for j in range(l2):
            h1[b + j] = 0.0
        for co in range(c1):
            we0, we1, wo0, wo1 = w1[0, 0, ci, co], w1[0, 1, ci, co], w1[1, 0, ci, co], w1[1, 1, ci, co]
            for j in range(l2):
                h1[b + j] += we1 * a2e[co, j] + wo0 * a2o[co, j]
            for j in range(l2 - 1):
                h1[b + j] += we0 * a2e[co, j + 1]
            for j in range(1, l2):
                h1[b + j] += wo1 * a2o[co, j - 1]
        for j in range(l2):
            h1[b + j] *= _gelu_grad(a1[b + j])


class DecoderPlan:
    """A decoder's weights in the fused kernels' layouts (numpy, the latent's dtype).

    wfc [d, c2·L2] (the fully connected layer, transposed), bfc [c2·L2],
    w1 [2 phases, 2 taps, c2, c1] and w2 [2, 2, c1] (polyphase transposed-convolution weights), b1 [c1],
    b2 (scalar), wlin [d, B], blin [B], std/mean [B] (the decoder's band standardisation)."""

    def __init__(self, decoder, dtype=np.float32):
        def a(t):
            return np.ascontiguousarray(t.detach().cpu().numpy().astype(dtype))

        self.wfc = a(decoder.dec_fc.weight.t())
        self.bfc = a(decoder.dec_fc.bias)
        self.w1 = a(_polyphase(decoder.dec_up1.weight.detach()))
        self.b1 = a(decoder.dec_up1.bias)
        self.w2 = a(_polyphase(decoder.dec_up2.weight.detach())[..., 0])
        self.b2 = float(decoder.dec_up2.bias.detach()[0])
        self.wlin = a(decoder.dec_lin.weight.t())
        self.blin = a(decoder.dec_lin.bias)
        self.std, self.mean = a(decoder.band_std), a(decoder.band_mean)
        self.n_bands = decoder.n_bands

    def args(self):
        return self.wfc, self.bfc, self.w1, self.b1, self.w2


def _polyphase(w: torch.Tensor) -> torch.Tensor:
    """ConvTranspose1d(k=4, s=2, p=1) weight [c_in, c_out, 4] → [phase, tap, c_in, c_out]: phase 0
    (output 2j) taps (input j−1: k=3, input j: k=1), phase 1 (output 2j+1) taps (input j: k=2, j+1: k=0)."""
    return torch.stack([torch.stack([w[..., 3], w[..., 1]]), torch.stack([w[..., 2], w[..., 0]])])


def can_fast_decode(decoder, z: torch.Tensor) -> bool:
    """True when :func:`fast_decode` computes ``decoder.decode(z)``: a SpectralAutoencoder with the
    standard architecture, on CPU, float32/float64, and no gradient wanted for its weights."""
    if not _FUSED[0] or type(decoder) is not SpectralAutoencoder or z.device.type != "cpu" or z.dtype not in (torch.float32,
                                                                                            torch.float64):
        return False
    weights_need_grad = torch.is_grad_enabled() and any(p.requires_grad for p in decoder.parameters())
    return 4 * decoder._L2 >= decoder.n_bands and not weights_need_grad


@contextlib.contextmanager
def reference_decoding():
    """Within the block, decoding uses the reference ``SpectralAutoencoder.decode`` (``brfgs bench view``
    times both in one run)."""
    prev, _FUSED[0] = _FUSED[0], False
    try:
        yield
    finally:
        _FUSED[0] = prev


_SAVE_MAX_PIXELS = 65536  # keep the pre-activations (5 kB a pixel) for the backward up to this many pixels


class _FastDecode(torch.autograd.Function):
    @staticmethod
    def forward(ctx, z, plan):
        zc = z.detach().contiguous()
        n, dt = zc.shape[0], zc.dtype
        out = torch.empty(n, plan.n_bands, dtype=dt)
        keep = n if z.requires_grad and n <= _SAVE_MAX_PIXELS else 0
        m1, (c1, l2) = plan.wfc.shape[1], (plan.w1.shape[3], plan.wfc.shape[1] // plan.w1.shape[2])
        sa1, sa2 = torch.empty(keep, m1, dtype=dt), torch.empty(keep, 2, c1, l2, dtype=dt)
        _sync_threads()
        _decode_fwd(zc.numpy(), *plan.args(), plan.b2, plan.wlin, plan.blin, plan.std, plan.mean, out.numpy(),
                    sa1.numpy(), sa2.numpy())
        ctx.save_for_backward(zc, sa1, sa2)
        ctx.plan = plan
        return out

    @staticmethod
    def backward(ctx, g_out):
        zc, sa1, sa2 = ctx.saved_tensors
        plan = ctx.plan
        g_z = torch.empty_like(zc)
        _sync_threads()
        _decode_bwd(zc.numpy(), g_out.contiguous().numpy(), *plan.args(), plan.wlin, plan.std, g_z.numpy(),
                    sa1.numpy(), sa2.numpy())
        return g_z, None


_PLANS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _plan_of(decoder, dtype: torch.dtype) -> DecoderPlan:
    """The plan of ``decoder`` for ``dtype``, rebuilt when its weights change (the parameters' and
    buffers' in-place versions are part of the key)."""
    versions = (dtype, tuple(p._version for p in decoder.parameters()), tuple(b._version for b in decoder.buffers()))
    cached = _PLANS.get(decoder)
    if cached is None or cached[0] != versions:
        cached = _PLANS[decoder] = (versions, DecoderPlan(decoder, np.float32 if dtype == torch.float32
                                                          else np.float64))
    return cached[1]


def fast_decode(decoder, z: torch.Tensor) -> torch.Tensor:
    """``decoder.decode(z)`` for z [N, d] through the fused kernels (check :func:`can_fast_decode` first);
    differentiable with respect to ``z``."""
    return _FastDecode.apply(z, _plan_of(decoder, z.dtype))


def _sync_threads() -> None:
    nb.set_num_threads(max(1, min(torch.get_num_threads(), nb.config.NUMBA_NUM_THREADS)))
