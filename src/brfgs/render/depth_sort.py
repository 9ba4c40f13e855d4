"""Front-to-back order of the visible Gaussians: a stable LSD radix sort of their depths (numba).

``np.argsort(depth, kind="stable")`` sorts floats by comparison (timsort); for the 10⁴–10⁶ depths of a
view it cost more than binning the Gaussians into tiles. The radix sort maps each float to an unsigned
integer key of the same width whose order is the floats' order (IEEE 754: flip every bit of a negative
number, only the sign bit of a non-negative one) and sorts the keys 8 bits at a time, each pass stable,
so equal depths keep their input order: the same permutation as the stable argsort for any depths
without NaN (tests/test_depth_sort.py). −0.0 sorts before +0.0 here; visible depths are beyond the near
plane, so both cases are out of reach.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["stable_depth_order"]


@njit(cache=True, nogil=True)
def _radix_argsort(keys, n_passes):
    """Stable argsort [N] of unsigned integer ``keys`` [N], 8 bits per pass over the lowest n_passes bytes
    (keys travel with their indices, so each pass reads memory in order)."""
    n = keys.shape[0]
    order, k = np.arange(n), keys.copy()
    order2, k2 = np.empty(n, np.int64), np.empty_like(keys)
    count = np.empty(257, np.int64)
    for b in range(n_passes):
        shift = 8 * b
        count[:] = 0
        for i in range(n):
            count[((k[i] >> shift) & 0xFF) + 1] += 1
        if count[1:].max() == n:                      # every key has the same byte here: nothing to move
            continue
        for r in range(256):
            count[r + 1] += count[r]
        for i in range(n):
            r = (k[i] >> shift) & 0xFF
            dst = count[r]
            count[r] = dst + 1
            order2[dst] = order[i]
            k2[dst] = k[i]
        order, order2 = order2, order
        k, k2 = k2, k
    return order


def _ordered_keys(depth: np.ndarray) -> np.ndarray:
    """Unsigned keys [N] whose unsigned order is the order of the floats ``depth`` [N] (float32/float64)."""
    bits = {4: np.uint32, 8: np.uint64}[depth.dtype.itemsize]
    u = np.ascontiguousarray(depth).view(bits)
    sign = bits(1) << bits(8 * depth.dtype.itemsize - 1)
    return np.where(u & sign, ~u, u | sign)


def stable_depth_order(depth: np.ndarray) -> np.ndarray:
    """Indices [N] (int64) that sort ``depth`` [N] (float32 or float64, m) ascending, ties in input order:
    ``np.argsort(depth, kind="stable")`` for depths without NaN."""
    depth = np.asarray(depth)
    if depth.dtype not in (np.float32, np.float64):
        depth = depth.astype(np.float64)
    if depth.shape[0] < 2:
        return np.arange(depth.shape[0], dtype=np.int64)
    return _radix_argsort(_ordered_keys(depth), depth.dtype.itemsize)
