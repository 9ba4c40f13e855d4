"""numba kernels of the ``cpu`` rasterizer: binning, tile raster and its backward (the projection:
:mod:`brfgs.render._numba_project`).

Everything is compiled with ``cache=True`` (the first use compiles for ~15–30 s and writes ``__pycache__``;
later processes load the cache; a kernel compiled in the process and one loaded from the cache may differ
in the last bits in float64). Kernels work for float32 and float64 arrays; scalar arithmetic inside is
float64. Semantics: see ``brfgs.render._common``.

Parallel structure (``prange``):
* raster forward/backward: one iteration per 16×16 tile. A Gaussian is iterated only over the pixels
  of its α ≥ 1/255 ellipse inside the tile (row spans from the conic), not over every pixel of the tile;
* the backward writes one gradient row per tile–Gaussian entry (race free) and a second
  pass, one iteration per Gaussian, reduces the entries of each Gaussian.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from brfgs.render._common import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE

_FM = {"nsz", "arcp", "contract", "reassoc"}  # fast-math without nnan/ninf/afn


@njit(cache=True, nogil=True)
def bin_tiles(order, rect, n_tiles_x, n_tiles_total, n_gauss):
    """Tile lists from Gaussians ``order`` [V] (visible, front to back) and tile rectangles.

    Returns tile_start [T+1], tile_gid [E] (per tile in depth order), and the per-Gaussian
    index of its entries: gauss_start [N+1], gauss_entry [E].
    """
    counts = np.zeros(n_tiles_total, np.int64)
    gcount = np.zeros(n_gauss, np.int64)
    for j in range(order.shape[0]):
        g = order[j]
        c = 0
        for ty in range(rect[g, 1], rect[g, 3] + 1):
            for tx in range(rect[g, 0], rect[g, 2] + 1):
                counts[ty * n_tiles_x + tx] += 1
                c += 1
        gcount[g] = c
    tile_start = np.zeros(n_tiles_total + 1, np.int64)
    for t in range(n_tiles_total):
        tile_start[t + 1] = tile_start[t] + counts[t]
    gauss_start = np.zeros(n_gauss + 1, np.int64)
    for g in range(n_gauss):
        gauss_start[g + 1] = gauss_start[g] + gcount[g]
    E = tile_start[n_tiles_total]
    tile_gid = np.empty(E, np.int32)
    gauss_entry = np.empty(E, np.int64)
    cursor = tile_start[:-1].copy()
    for j in range(order.shape[0]):
        g = order[j]
        c = gauss_start[g]
        for ty in range(rect[g, 1], rect[g, 3] + 1):
            for tx in range(rect[g, 0], rect[g, 2] + 1):
                t = ty * n_tiles_x + tx
                pos = cursor[t]
                cursor[t] = pos + 1
                tile_gid[pos] = g
                gauss_entry[c] = pos
                c += 1
    return tile_start, tile_gid, gauss_start, gauss_entry


@njit(cache=True, inline="always")
def _span(a, inv_a, b, c, smax, dy, mx, x0, x1):
    """Pixel columns [lo, hi] of a tile row (x0 ≤ px < x1) that can lie inside σ ≤ smax."""
    bdy = b * dy
    disc = bdy * bdy - a * (c * dy * dy - 2.0 * smax)
    if disc < 0.0:
        return 0, -1
    sq = math.sqrt(disc)
    lo = max(x0, int(math.floor(mx + (-bdy - sq) * inv_a - 0.5)))
    hi = min(x1 - 1, int(math.ceil(mx + (-bdy + sq) * inv_a - 0.5)))
    return lo, hi


@njit(cache=True, inline="always")
def _tile(tile_start, t, n_tiles_x, width, height):
    """Pixel box [x0, x1) × [y0, y1) of tile t and its entries [s, e) in the tile lists."""
    tx = t % n_tiles_x
    ty = t // n_tiles_x
    x0 = tx * TILE
    y0 = ty * TILE
    x1 = min(x0 + TILE, width)
    y1 = min(y0 + TILE, height)
    return x0, y0, x1, y1, tile_start[t], tile_start[t + 1]


@njit(cache=True, inline="always")
def _tile_state():
    """Per-pixel state of a tile: transmittance T (1) and 1 + local index of the last entry (0)."""
    return np.ones(TILE * TILE, np.float64), np.zeros(TILE * TILE, np.int32)


@njit(cache=True, inline="always")
def _sigma(a, b, c, px, mx, dy):
    """(dx, σ) of the pixel column px: dx = pixel centre − mean, σ = ½(a dx² + c dy²) + b dx dy."""
    dx = px + 0.5 - mx
    return dx, 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy


@njit(cache=True, inline="always")
def _exp_neg(wbuf, sigma):
    """exp(−σ) in the precision of ``wbuf`` (expf for a float32 buffer)."""
    wbuf[0] = -sigma
    return math.exp(wbuf[0])


@njit(cache=True, inline="always")
def _splat(means2d, conics, opac, radii, smax_all, g, y0, y1):
    """(mx, my, a, b, c, o, smax, inv_a, ya, yb) of Gaussian g; [ya, yb]: the rows of [y0, y1) it reaches."""
    mx = float(means2d[g, 0]); my = float(means2d[g, 1])
    a = float(conics[g, 0]); b = float(conics[g, 1]); c = float(conics[g, 2])
    o = float(opac[g])
    smax = smax_all[g]
    inv_a = 1.0 / a
    ry = float(radii[g, 1])
    ya = max(y0, int(math.floor(my - ry - 0.5)))
    yb = min(y1 - 1, int(math.ceil(my + ry - 0.5)))
    return mx, my, a, b, c, o, smax, inv_a, ya, yb


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def raster_fwd(means2d, conics, opac, radii, smax_all, colors, tile_start, tile_gid, width, height, n_tiles_x,
               image, t_final, n_used):
    """Front-to-back compositing per tile.

    colors [N,D] → image [H,W,D] (every pixel written), t_final [H,W] final transmittance,
    n_used [H,W] int32: 1 + local index (in its tile list) of the last composited entry, 0 if none.
    """
    D = colors.shape[1]
    for t in prange(tile_start.shape[0] - 1):
        x0, y0, x1, y1, s, e = _tile(tile_start, t, n_tiles_x, width, height)
        T, last = _tile_state()
        done = np.zeros(TILE * TILE, np.bool_)
        acc = np.zeros((TILE * TILE, D), image.dtype)
        wbuf = np.zeros(1, image.dtype)  # casts the weight to the image dtype for the channel loop
        n_done = 0
        n_pix = (x1 - x0) * (y1 - y0)
        for k in range(s, e):
            g = tile_gid[k]
            mx, my, a, b, c, o, smax, inv_a, ya, yb = _splat(means2d, conics, opac, radii, smax_all, g, y0, y1)
            for py in range(ya, yb + 1):
                dy = py + 0.5 - my
                lo, hi = _span(a, inv_a, b, c, smax, dy, mx, x0, x1)
                row = (py - y0) * TILE - x0
                for px in range(lo, hi + 1):
                    li = row + px
                    if done[li]:
                        continue
                    dx, sigma = _sigma(a, b, c, px, mx, dy)
                    if sigma < 0.0:
                        continue
                    al = min(ALPHA_MAX, o * _exp_neg(wbuf, sigma))  # exp in the image's precision
                    if al < ALPHA_MIN:
                        continue
                    Tp = T[li]
                    Tn = Tp * (1.0 - al)
                    if Tn < T_MIN:
                        done[li] = True
                        n_done += 1
                        continue
                    wbuf[0] = al * Tp
                    w = wbuf[0]
                    for ch in range(D):
                        acc[li, ch] += w * colors[g, ch]
                    T[li] = Tn
                    last[li] = k - s + 1
            if n_done == n_pix:
                break
        for py in range(y0, y1):
            for px in range(x0, x1):
                li = (py - y0) * TILE + (px - x0)
                t_final[py, px] = T[li]
                n_used[py, px] = last[li]
                for ch in range(D):
                    image[py, px, ch] = acc[li, ch]


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def raster_bwd(means2d, conics, opac, radii, smax_all, colors, tile_start, tile_gid, width, height, n_tiles_x,
               t_final, n_used, v_image, v_alpha,
               e_means2d, e_conics, e_opac, e_colors):
    """Back-to-front gradient pass per tile, one gradient row per tile–Gaussian entry.

    v_image [H,W,D], v_alpha [H,W] → e_means2d [E,2], e_conics [E,3], e_opac [E], e_colors [E,D]
    (every row written). With s_j = f_j·∂L/∂C and R_i = Σ_{j>i} w_j s_j − ∂L/∂A·T_final:
    ∂L/∂α_i = T_i s_i − R_i/(1−α_i).
    """
    for t in prange(tile_start.shape[0] - 1):  # (e_means2d stands in for e_absm2d: never touched when False)
        _bwd_tile(t, means2d, conics, opac, radii, smax_all, colors, tile_start, tile_gid, width, height, n_tiles_x,
                  t_final, n_used, v_image, v_alpha, e_means2d, e_conics, e_opac, e_colors, e_means2d, False)


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def raster_bwd_abs(means2d, conics, opac, radii, smax_all, colors, tile_start, tile_gid, width, height, n_tiles_x,
                   t_final, n_used, v_image, v_alpha,
                   e_means2d, e_conics, e_opac, e_colors, e_absm2d):
    """:func:`raster_bwd`, and e_absm2d [E,2]: the sum over pixels of |∂L_p/∂x|, |∂L_p/∂y| (AbsGS's
    densification signal). A kernel of its own, so that the plain one compiles as without it."""
    for t in prange(tile_start.shape[0] - 1):
        _bwd_tile(t, means2d, conics, opac, radii, smax_all, colors, tile_start, tile_gid, width, height, n_tiles_x,
                  t_final, n_used, v_image, v_alpha, e_means2d, e_conics, e_opac, e_colors, e_absm2d, True)


@njit(inline="always")
def _bwd_tile(t, means2d, conics, opac, radii, smax_all, colors, tile_start, tile_gid, width, height, n_tiles_x,
              t_final, n_used, v_image, v_alpha, e_means2d, e_conics, e_opac, e_colors, e_absm2d, absgrad):
    """The backward pass of tile ``t`` (see :func:`raster_bwd`); ``absgrad`` is a constant of the caller."""
    D = colors.shape[1]
    x0, y0, x1, y1, s, e = _tile(tile_start, t, n_tiles_x, width, height)
    T, last = _tile_state()
    R = np.zeros(TILE * TILE, np.float64)
    wbuf = np.zeros(1, e_colors.dtype)
    sbuf = np.zeros(1, e_colors.dtype)
    max_last = 0
    for py in range(y0, y1):
        for px in range(x0, x1):
            li = (py - y0) * TILE + (px - x0)
            tf = float(t_final[py, px])
            T[li] = tf
            R[li] = -float(v_alpha[py, px]) * tf
            last[li] = n_used[py, px]
            max_last = max(max_last, n_used[py, px])
    for k in range(s + max_last, e):  # entries nobody used
        e_means2d[k, 0] = 0.0; e_means2d[k, 1] = 0.0
        e_conics[k, 0] = 0.0; e_conics[k, 1] = 0.0; e_conics[k, 2] = 0.0
        e_opac[k] = 0.0
        for ch in range(D):
            e_colors[k, ch] = 0.0
        if absgrad:
            e_absm2d[k, 0] = 0.0; e_absm2d[k, 1] = 0.0
    for k in range(s + max_last - 1, s - 1, -1):
        kl = k - s
        g = tile_gid[k]
        mx, my, a, b, c, o, smax, inv_a, ya, yb = _splat(means2d, conics, opac, radii, smax_all, g, y0, y1)
        for ch in range(D):
            e_colors[k, ch] = 0.0
        g_mx = 0.0; g_my = 0.0; g_a = 0.0; g_b = 0.0; g_c = 0.0; g_o = 0.0
        ga_x = 0.0; ga_y = 0.0
        for py in range(ya, yb + 1):
            dy = py + 0.5 - my
            lo, hi = _span(a, inv_a, b, c, smax, dy, mx, x0, x1)
            for px in range(lo, hi + 1):
                li = (py - y0) * TILE + (px - x0)
                if kl >= last[li]:
                    continue
                dx, sigma = _sigma(a, b, c, px, mx, dy)
                if sigma < 0.0:
                    continue
                G = float(_exp_neg(wbuf, sigma))  # exp in the image's precision
                ar = o * G
                al = min(ALPHA_MAX, ar)
                if al < ALPHA_MIN:
                    continue
                rom = 1.0 / (1.0 - al)
                Ti = T[li] * rom
                T[li] = Ti
                w = al * Ti
                wbuf[0] = w
                wf = wbuf[0]
                sbuf[0] = 0.0
                sd = sbuf[0]
                for ch in range(D):
                    vc = v_image[py, px, ch]
                    sd += colors[g, ch] * vc
                    e_colors[k, ch] += wf * vc
                v_al = Ti * sd - R[li] * rom
                R[li] += w * sd
                if ar <= ALPHA_MAX:
                    v_sig = -v_al * ar
                    g_o += v_al * G
                    g_a += v_sig * 0.5 * dx * dx
                    g_b += v_sig * dx * dy
                    g_c += v_sig * 0.5 * dy * dy
                    g_mx -= v_sig * (a * dx + b * dy)
                    g_my -= v_sig * (b * dx + c * dy)
                    if absgrad:
                        ga_x += abs(v_sig * (a * dx + b * dy))
                        ga_y += abs(v_sig * (b * dx + c * dy))
        e_means2d[k, 0] = g_mx; e_means2d[k, 1] = g_my
        if absgrad:
            e_absm2d[k, 0] = ga_x; e_absm2d[k, 1] = ga_y
        e_conics[k, 0] = g_a; e_conics[k, 1] = g_b; e_conics[k, 2] = g_c
        e_opac[k] = g_o

@njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def reduce_entries(gauss_start, gauss_entry, e_means2d, e_conics, e_opac, e_colors,
                   v_means2d, v_conics, v_opac, v_colors):
    """Sum the per-entry gradients of each Gaussian (outputs fully written)."""
    N = gauss_start.shape[0] - 1
    D = e_colors.shape[1]
    for g in prange(N):
        m0 = 0.0; m1 = 0.0; c0 = 0.0; c1 = 0.0; c2 = 0.0; op = 0.0
        for ch in range(D):
            v_colors[g, ch] = 0.0
        for j in range(gauss_start[g], gauss_start[g + 1]):
            k = gauss_entry[j]
            m0 += e_means2d[k, 0]; m1 += e_means2d[k, 1]
            c0 += e_conics[k, 0]; c1 += e_conics[k, 1]; c2 += e_conics[k, 2]
            op += e_opac[k]
            for ch in range(D):
                v_colors[g, ch] += e_colors[k, ch]
        v_means2d[g, 0] = m0; v_means2d[g, 1] = m1
        v_conics[g, 0] = c0; v_conics[g, 1] = c1; v_conics[g, 2] = c2
        v_opac[g] = op


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def reduce_pairs(gauss_start, gauss_entry, e_pairs, v_pairs):
    """Sum the per-entry rows e_pairs [E, 2] of each Gaussian into v_pairs [N, 2] (fully written)."""
    for g in prange(gauss_start.shape[0] - 1):
        m0 = 0.0; m1 = 0.0
        for j in range(gauss_start[g], gauss_start[g + 1]):
            k = gauss_entry[j]
            m0 += e_pairs[k, 0]; m1 += e_pairs[k, 1]
        v_pairs[g, 0] = m0; v_pairs[g, 1] = m1
