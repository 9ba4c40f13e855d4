"""The spectral decoder's fused numba kernels (eq. 13), 16 pixels at a time as the lanes of one vector.

Layout: a group of 16 pixels is decoded together; every feature value is a 16-tuple (one value per pixel)
held in registers, and every stored feature map is [channel, position, 16 pixels]. Each multiply-add of
the decoder then reads one contiguous 16-float row and one scalar weight, so LLVM's SLP vectoriser turns
the tuple arithmetic into 512-bit (or 2 × 256-bit) FMAs with the weight broadcast, and GELU's rational
erf runs on 16 pixels per instruction. The kernels must be compiled with the SLP vectoriser on, which
numba leaves off by default: call them through :func:`run_vectorised`.

Forward (:func:`decode_fwd`): Linear d → c2·L2, GELU, ConvTranspose1d(c2 → c1, k4, s2, p1), GELU,
ConvTranspose1d(c1 → 1, k4, s2, p1), plus the linear path Linear d → B, then the band de-standardisation.
The transposed convolutions are in polyphase form (output 2j reads inputs j − 1 and j, output 2j + 1
reads j and j + 1; fast_decode's docstring); feature maps carry a zero position on each side so no
boundary branch is needed. Backward (:func:`decode_bwd`): the gradient with respect to the latent only
(the decoder's weights are constants), recomputing the forward's pre-activations per group.

Weights come in :class:`brfgs.spectral.fast_decode.DecoderPlan`'s layouts: wfc [d, c2·L2], bfc [c2·L2],
w1 [phase, tap, c2, c1], b1 [c1], w2 [phase, tap, c1], b2 (scalar), wlin [d, B], blin [B], std/mean [B].
"""

from __future__ import annotations

import contextlib
import threading

import numba.core.config as numba_config
import numpy as np
from numba import njit, prange

from brfgs.spectral.fast_math import FASTMATH_FLAGS, gelu, gelu_grad

__all__ = ["LANES", "decode_fwd", "decode_bwd", "slp_vectorised", "run_vectorised"]

LANES = 16  # pixels per group: one 512-bit vector of float32
_FM = FASTMATH_FLAGS - {"reassoc"}  # no reassociation: SLP packs the lanes, never a reduction's terms
_LANE = dict(cache=True, inline="always", fastmath=_FM, error_model="numpy", boundscheck=False)
_KERNEL = dict(cache=True, parallel=True, fastmath=_FM, nogil=True, error_model="numpy", boundscheck=False)
_SLP_LOCK = threading.Lock()


@contextlib.contextmanager
def slp_vectorised():
    """Within the block, numba compiles with LLVM's SLP vectoriser on (a cached kernel loads compiled)."""
    with _SLP_LOCK:
        prev, numba_config.SLP_VECTORIZE = numba_config.SLP_VECTORIZE, 1
        try:
            yield
        finally:
            numba_config.SLP_VECTORIZE = prev


_READY: set = set()  # (kernel, latent dtype) already compiled or loaded with SLP on in this process


def run_vectorised(kernel, *args) -> None:
    """``kernel(*args)``; its first call for a latent dtype (args[0]) runs inside :func:`slp_vectorised`,
    where numba compiles it or loads it from its cache; later calls run without the lock."""
    key = (kernel, args[0].dtype)
    if key in _READY:
        kernel(*args)
        return
    with slp_vectorised():
        kernel(*args)
    _READY.add(key)


# ---- 16-lane values: tuples of one value per pixel of the group ----------------------------------------
@njit(**_LANE)
def _fill(b):
    return (b, b, b, b, b, b, b, b, b, b, b, b, b, b, b, b)


@njit(**_LANE)
def _fma(a, w, x, i, j):
    """a + w · x[i, j, :16] for a feature map x [channel, position, 16]."""
    return (a[0] + w * x[i, j, 0], a[1] + w * x[i, j, 1], a[2] + w * x[i, j, 2], a[3] + w * x[i, j, 3],
            a[4] + w * x[i, j, 4], a[5] + w * x[i, j, 5], a[6] + w * x[i, j, 6], a[7] + w * x[i, j, 7],
            a[8] + w * x[i, j, 8], a[9] + w * x[i, j, 9], a[10] + w * x[i, j, 10], a[11] + w * x[i, j, 11],
            a[12] + w * x[i, j, 12], a[13] + w * x[i, j, 13], a[14] + w * x[i, j, 14], a[15] + w * x[i, j, 15])


@njit(**_LANE)
def _gelu16(a):
    return (gelu(a[0]), gelu(a[1]), gelu(a[2]), gelu(a[3]), gelu(a[4]), gelu(a[5]), gelu(a[6]), gelu(a[7]),
            gelu(a[8]), gelu(a[9]), gelu(a[10]), gelu(a[11]), gelu(a[12]), gelu(a[13]), gelu(a[14]), gelu(a[15]))


@njit(**_LANE)
def _mul_gelu_grad(a, x, i, j):
    """a · gelu'(x[i, j, :16]) (a backward through a GELU whose pre-activation is stored in x)."""
    return (a[0] * gelu_grad(x[i, j, 0]), a[1] * gelu_grad(x[i, j, 1]), a[2] * gelu_grad(x[i, j, 2]),
            a[3] * gelu_grad(x[i, j, 3]), a[4] * gelu_grad(x[i, j, 4]), a[5] * gelu_grad(x[i, j, 5]),
            a[6] * gelu_grad(x[i, j, 6]), a[7] * gelu_grad(x[i, j, 7]), a[8] * gelu_grad(x[i, j, 8]),
            a[9] * gelu_grad(x[i, j, 9]), a[10] * gelu_grad(x[i, j, 10]), a[11] * gelu_grad(x[i, j, 11]),
            a[12] * gelu_grad(x[i, j, 12]), a[13] * gelu_grad(x[i, j, 13]), a[14] * gelu_grad(x[i, j, 14]),
            a[15] * gelu_grad(x[i, j, 15]))


@njit(**_LANE)
def _load(x, i, j):
    """x[i, j, :16] as a 16-lane value."""
    return (x[i, j, 0], x[i, j, 1], x[i, j, 2], x[i, j, 3], x[i, j, 4], x[i, j, 5], x[i, j, 6], x[i, j, 7],
            x[i, j, 8], x[i, j, 9], x[i, j, 10], x[i, j, 11], x[i, j, 12], x[i, j, 13], x[i, j, 14], x[i, j, 15])


@njit(**_LANE)
def _store(x, i, j, a):
    x[i, j, 0], x[i, j, 1], x[i, j, 2], x[i, j, 3] = a[0], a[1], a[2], a[3]
    x[i, j, 4], x[i, j, 5], x[i, j, 6], x[i, j, 7] = a[4], a[5], a[6], a[7]
    x[i, j, 8], x[i, j, 9], x[i, j, 10], x[i, j, 11] = a[8], a[9], a[10], a[11]
    x[i, j, 12], x[i, j, 13], x[i, j, 14], x[i, j, 15] = a[12], a[13], a[14], a[15]


# ---- group helpers ---------------------------------------------------------------------------------------
@njit(**_LANE)
def _load_group(x, n0, cnt, xt):
    """xt [1, C, 16] = x[n0 : n0 + cnt, :C]ᵀ (lanes past cnt zero)."""
    xt[:] = 0
    for p in range(cnt):
        for k in range(x.shape[1]):
            xt[0, k, p] = x[n0 + p, k]


@njit(**_LANE)
def _hidden(zt, wfc, bfc, w1, b1, a1, h1, a2e, a2o, h2):
    """The group's two hidden layers: a1 [c2, L2 + 2, 16] (the fully connected layer's pre-activations,
    position + 1, as the reference reshapes it), h1 = GELU(a1) (zero at both ends), a2e/a2o [c1, L2, 16] (the
    first transposed convolution's outputs 2j, 2j + 1), h2 [c1, 2·L2 + 2, 16] their GELU at 2j + 1, 2j + 2."""
    c2, c1 = w1.shape[2], w1.shape[3]
    l2 = wfc.shape[1] // c2
    for ci in range(c2):
        for j in range(l2):
            i = ci * l2 + j
            a = _fill(bfc[i])
            for k in range(zt.shape[1]):
                a = _fma(a, wfc[k, i], zt, 0, k)
            _store(a1, ci, j + 1, a)
            _store(h1, ci, j + 1, _gelu16(a))
    for co in range(c1):
        for j in range(l2):
            e = _fill(b1[co])
            q = _fill(b1[co])
            for ci in range(c2):
                e = _fma(_fma(e, w1[0, 0, ci, co], h1, ci, j), w1[0, 1, ci, co], h1, ci, j + 1)
                q = _fma(_fma(q, w1[1, 0, ci, co], h1, ci, j + 1), w1[1, 1, ci, co], h1, ci, j + 2)
            _store(a2e, co, j, e)
            _store(a2o, co, j, q)
            _store(h2, co, 2 * j + 1, _gelu16(e))
            _store(h2, co, 2 * j + 2, _gelu16(q))


@njit(**_LANE)
def _group_hidden(z, n0, cnt, wfc, bfc, w1, b1):
    """The latents zt [1, d, 16] of pixels n0 … n0 + cnt − 1 and their hidden layers (see _hidden)."""
    d, m1 = wfc.shape
    c2, c1 = w1.shape[2], w1.shape[3]
    l2 = m1 // c2
    zt = np.empty((1, d, LANES), z.dtype)
    a1 = np.zeros((c2, l2 + 2, LANES), z.dtype)
    h1 = np.zeros((c2, l2 + 2, LANES), z.dtype)
    a2e = np.empty((c1, l2, LANES), z.dtype)
    a2o = np.empty((c1, l2, LANES), z.dtype)
    h2 = np.zeros((c1, 2 * l2 + 2, LANES), z.dtype)
    _load_group(z, n0, cnt, zt)
    _hidden(zt, wfc, bfc, w1, b1, a1, h1, a2e, a2o, h2)
    return zt, a1, h1, a2e, a2o, h2


@njit(**_KERNEL)
def decode_fwd(z, wfc, bfc, w1, b1, w2, b2, wlin, blin, std, mean, out):
    """out [N, B] = decode(z [N, d]) (module docstring); out's rows past B in 4·L2 are never written."""
    n_pix, n_bands = out.shape
    d, c1 = wfc.shape[0], w1.shape[3]
    for g in prange((n_pix + LANES - 1) // LANES):
        n0 = g * LANES
        cnt = min(LANES, n_pix - n0)
        zt, _, _, _, _, h2 = _group_hidden(z, n0, cnt, wfc, bfc, w1, b1)
        o = np.empty((1, n_bands + 1, LANES), z.dtype)
        for j in range((n_bands + 1) // 2):                   # outputs 2j (e) and 2j + 1 (q)
            y0, y1 = 2 * j, min(2 * j + 1, n_bands - 1)      # an odd B's last q lands in the spare row
            e = _fill(b2 + blin[y0])
            q = _fill(b2 + blin[y1])
            for ci in range(c1):
                e = _fma(_fma(e, w2[0, 0, ci], h2, ci, j), w2[0, 1, ci], h2, ci, j + 1)
                q = _fma(_fma(q, w2[1, 0, ci], h2, ci, j + 1), w2[1, 1, ci], h2, ci, j + 2)
            for k in range(d):
                e = _fma(e, wlin[k, y0], zt, 0, k)
                q = _fma(q, wlin[k, y1], zt, 0, k)
            _store(o, 0, 2 * j, e)
            _store(o, 0, 2 * j + 1, q)
        for p in range(cnt):
            for y in range(n_bands):
                out[n0 + p, y] = o[0, y, p] * std[y] + mean[y]


@njit(**_KERNEL)
def decode_bwd(z, g_out, wfc, bfc, w1, b1, w2, wlin, std, g_z):
    """g_z [N, d] = (∂ decode / ∂ z)ᵀ g_out [N, B]: through the linear path, the second transposed
    convolution (its transpose), GELU', the first one's transpose, GELU' and the fully connected layer."""
    n_pix, n_bands = g_out.shape
    d, m1 = wfc.shape
    c2, c1 = w1.shape[2], w1.shape[3]
    l2 = m1 // c2
    for g in prange((n_pix + LANES - 1) // LANES):
        n0 = g * LANES
        cnt = min(LANES, n_pix - n0)
        zt, a1, h1, a2e, a2o, h2 = _group_hidden(z, n0, cnt, wfc, bfc, w1, b1)
        gt = np.zeros((1, 4 * l2 + 4, LANES), z.dtype)      # ∂L/∂(standardised output y) at y + 2
        de = np.zeros((c1, l2 + 2, LANES), z.dtype)          # ∂L/∂a2e at j + 1 (zero at both ends)
        do = np.zeros((c1, l2 + 2, LANES), z.dtype)
        gz = np.empty((1, d, LANES), z.dtype)
        for p in range(cnt):
            for y in range(n_bands):
                gt[0, y + 2, p] = g_out[n0 + p, y] * std[y]
        for k in range(d):                                    # the linear path
            a = _fill(zt[0, 0, 0] * 0)
            for y in range(n_bands):
                a = _fma(a, wlin[k, y], gt, 0, y + 2)
            _store(gz, 0, k, a)
        _up2_transposed(w2, gt, a2e, a2o, de, do)
        _up1_transposed(w1, de, do, a1, h1)                   # h1 becomes ∂L/∂a1 (position + 1)
        for k in range(d):                                    # the fully connected layer
            a = _load(gz, 0, k)
            for ci in range(c2):
                for j in range(l2):
                    a = _fma(a, wfc[k, ci * l2 + j], h1, ci, j + 1)
            _store(gz, 0, k, a)
        for p in range(cnt):
            for k in range(d):
                g_z[n0 + p, k] = gz[0, k, p]


@njit(**_LANE)
def _up2_transposed(w2, gt, a2e, a2o, de, do):
    """de/do [c1, L2 + 2, 16] = ∂L/∂a2 (even/odd, at j + 1) from gt (∂L/∂ output y at y + 2). The forward
    reads output 2j ← h2[j − 1]·w_e0 + h2[j]·w_e1 and output 2j + 1 ← h2[j]·w_o0 + h2[j + 1]·w_o1, so h2
    position s feeds outputs 2s + 2 (w_e0), 2s (w_e1), 2s + 1 (w_o0) and 2s − 1 (w_o1)."""
    c1, l2 = a2e.shape[0], a2e.shape[1]
    for ci in range(c1):
        we0, we1, wo0, wo1 = w2[0, 0, ci], w2[0, 1, ci], w2[1, 0, ci], w2[1, 1, ci]
        for j in range(l2):
            for par in range(2):
                s = 2 * j + par
                a = _fill(gt[0, 0, 0] * 0)
                a = _fma(a, we0, gt, 0, 2 * s + 4)            # output 2(s + 1) reads h2[s] with w_e0
                a = _fma(a, we1, gt, 0, 2 * s + 2)            # output 2s reads h2[s] with w_e1
                a = _fma(a, wo0, gt, 0, 2 * s + 3)            # output 2s + 1 reads h2[s] with w_o0
                a = _fma(a, wo1, gt, 0, 2 * s + 1)            # output 2(s − 1) + 1 reads h2[s] with w_o1
                if par == 0:    # an if, not `x, y = (a2e, de) if par == 0 else ...`: numba 0.68 got that wrong
                    _store(de, ci, j + 1, _mul_gelu_grad(a, a2e, ci, j))
                else:
                    _store(do, ci, j + 1, _mul_gelu_grad(a, a2o, ci, j))


@njit(**_LANE)
def _up1_transposed(w1, de, do, a1, h1):
    """h1 [c2, L2 + 2, 16] (position + 1) = ∂L/∂a1 from de/do: h1 position t feeds a2e[t + 1] (w_e0),
    a2e[t] (w_e1), a2o[t] (w_o0) and a2o[t − 1] (w_o1)."""
    c2, c1 = w1.shape[2], w1.shape[3]
    l2 = de.shape[1] - 2
    for ci in range(c2):
        for t in range(l2):
            a = _fill(de[0, 0, 0] * 0)
            for co in range(c1):
                a = _fma(a, w1[0, 0, ci, co], de, co, t + 2)
                a = _fma(a, w1[0, 1, ci, co], de, co, t + 1)
                a = _fma(a, w1[1, 0, ci, co], do, co, t + 1)
                a = _fma(a, w1[1, 1, ci, co], do, co, t)
            _store(h1, ci, t + 1, _mul_gelu_grad(a, a1, ci, t + 1))
