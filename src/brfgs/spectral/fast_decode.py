"""The spectral decoder (eq. 13) through fused numba kernels, forward and latent gradient.

:meth:`SpectralAutoencoder.decode` (PyTorch: Linear, GELU, two ConvTranspose1d) stays the reference;
:func:`fast_decode` computes the same map with :mod:`brfgs.spectral.lane_kernels`: 16 pixels decoded
together as the lanes of one vector, every intermediate of the group (16 × 41 and 8 × 82 feature maps per
pixel) kept in the core's cache instead of streaming [N, 656] tensors through memory five times, and the
two transposed convolutions (kernel 4, stride 2, padding 1) in polyphase form: output 2j reads inputs
j − 1 (tap 3) and j (tap 1), output 2j + 1 reads j (tap 2) and j + 1 (tap 0) — half the taps of a dense
transposed convolution and no zero-stuffing. GELU is exact-form with a vectorisable erf
(:mod:`brfgs.spectral.fast_math`). Results equal the reference within float rounding
(tests/test_fast_decode.py: 1e-5). The backward gives the gradient with respect to the latent only:
:func:`fast_decode` is used when the decoder is frozen (training's default) or without gradients,
:func:`brfgs.model.rendering.decode_image` falls back to the reference otherwise.
"""

from __future__ import annotations

import contextlib
import weakref

import numba as nb
import numpy as np
import torch

from brfgs.spectral.autoencoder import SpectralAutoencoder
from brfgs.spectral.lane_kernels import decode_bwd, decode_fwd, run_vectorised

__all__ = ["DecoderPlan", "fast_decode", "can_fast_decode", "reference_decoding"]

_FUSED = [True]  # switched off by reference_decoding()


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
        self.b2 = dtype(decoder.dec_up2.bias.detach()[0].item())  # a numpy scalar: float32 stays float32 in numba
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


class _FastDecode(torch.autograd.Function):
    @staticmethod
    def forward(ctx, z, plan):
        zc = z.detach().contiguous()
        out = torch.empty(zc.shape[0], plan.n_bands, dtype=zc.dtype)
        _sync_threads()
        run_vectorised(decode_fwd, zc.numpy(), *plan.args(), plan.b2, plan.wlin, plan.blin, plan.std, plan.mean,
                       out.numpy())
        ctx.save_for_backward(zc)
        ctx.plan = plan
        return out

    @staticmethod
    def backward(ctx, g_out):
        (zc,) = ctx.saved_tensors
        plan = ctx.plan
        g_z = torch.empty_like(zc)
        _sync_threads()
        run_vectorised(decode_bwd, zc.numpy(), g_out.contiguous().numpy(), *plan.args(), plan.wlin, plan.std,
                       g_z.numpy())                        # the forward's pre-activations are recomputed
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
