"""Fused CPU implementation of the three kernels of the hybrid head (numba).

One parallel loop over Gaussians computes K_Ross, K_Li and K_Cook (paper eqs 14–23) from
ω_i, ω_o, n_k and ρ_k with the shared cosines, and one loop computes their exact
hand-written reverse-mode gradients (recomputing the forward intermediates instead of
storing them). The maths is identical, operation by operation, to the torch path of
:mod:`brfgs.brdf.kernels` (same clamps, same safe branches; MODIS b/r = 1); the tests check
values against it and gradients with ``torch.autograd.gradcheck``.

Used by :func:`brfgs.brdf.head.hybrid_latent` when the tensors are on the CPU
(``backend="auto"``); the torch path serves CUDA and double-backward.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

__all__ = ["available", "fused_kernels", "combine"]

try:  # numba is a declared dependency; stay importable without it
    import numba as nb

    _HAVE_NUMBA = True
except Exception:  # pragma: no cover
    _HAVE_NUMBA = False

_TINY = 1e-30
_PI = math.pi


def available() -> bool:
    """True when the fused CPU path can be used."""
    return _HAVE_NUMBA


if _HAVE_NUMBA:

    @nb.njit(cache=True, inline="always")
    def _add_scaled(gx, gy, gz, a, vx, vy, vz):
        """(gx, gy, gz) + a·(vx, vy, vz): one adjoint update of a dot product's input."""
        return gx + a * vx, gy + a * vy, gz + a * vz

    @nb.njit(cache=True, inline="always")
    def _strides(wi, nrm, rho, need_c, nframe):
        """Row steps of the inputs (0: one row broadcast to every Gaussian) and whether normals are read."""
        step_i = 1 if wi.shape[0] > 1 else 0
        have_n = nrm.shape[0] > 1 or (need_c or nframe)
        step_r = 1 if rho.shape[0] > 1 else 0
        return step_i, have_n, step_r

    @nb.njit(cache=True, inline="always")
    def _gather(wi, wo, nrm, rho, k, step_i, have_n, step_r):
        """Inputs of Gaussian k: ω_i, ω_o, the normal n' flipped toward ω_o, the flip sign, ρ."""
        j = k * step_i
        ix, iy, iz = wi[j, 0], wi[j, 1], wi[j, 2]
        ox, oy, oz = wo[k, 0], wo[k, 1], wo[k, 2]
        if have_n:
            nx, ny, nz = nrm[k, 0], nrm[k, 1], nrm[k, 2]
        else:
            nx, ny, nz = 0.0, 0.0, 1.0
        sg = 1.0
        if nx * ox + ny * oy + nz * oz < 0.0:
            sg = -1.0
            nx, ny, nz = -nx, -ny, -nz
        return ix, iy, iz, ox, oy, oz, nx, ny, nz, sg, rho[k * step_r]

    @nb.njit(cache=True, inline="always")
    def _zenith_frame(nframe, nx, ny, nz, iz, oz, min_, mon, min_cos):
        """Frame "up" u of Ross/Li (n' or +z), the cosines μ_i, μ_o in it and their clamped values.

        Returns (ux, uy, uz, mui, muo, mi, mo).
        """
        if nframe:
            ux, uy, uz = nx, ny, nz
            mui, muo = min_, mon
        else:
            ux, uy, uz = 0.0, 0.0, 1.0
            mui, muo = iz, oz
        return ux, uy, uz, mui, muo, max(mui, min_cos), max(muo, min_cos)

    @nb.njit(cache=True, inline="always")
    def _ross_phase(c):
        """(asin c', f(c')) with c' = clamp(c, −1, 1), f = c' asin c' + sqrt(1 − c'²) (eq. 15)."""
        cc = min(max(c, -1.0), 1.0)
        asn = math.asin(cc)
        return asn, cc * asn + math.sqrt((1.0 - cc) * (1.0 + cc))

    @nb.njit(cache=True, inline="always")
    def _li_terms(ix, iy, iz, ox, oy, oz, ux, uy, uz, mui, muo, mi, mo, hb):
        """Intermediates of Li-Sparse-R (eqs 16–19) in the frame u.

        Returns (si, so, hi (3), ho (3), d (3), ω_i × ω_o (3), det, x, r, m, ct, sq, g): secants,
        in-plane vectors h = ω − μ u, d = hi si − ho so, det = (ω_i × ω_o)·u, x = det si so,
        r = sqrt(|d|² + x²), m = si + so, cos t clipped, sqrt(1 − cos² t), g = t − sin t cos t.
        """
        si = 1.0 / mi
        so = 1.0 / mo
        hix = ix - mui * ux
        hiy = iy - mui * uy
        hiz = iz - mui * uz
        hox = ox - muo * ux
        hoy = oy - muo * uy
        hoz = oz - muo * uz
        dx = hix * si - hox * so
        dy = hiy * si - hoy * so
        dz = hiz * si - hoz * so
        d2 = dx * dx + dy * dy + dz * dz
        cxx = iy * oz - iz * oy
        cxy = iz * ox - ix * oz
        cxz = ix * oy - iy * ox
        det = cxx * ux + cxy * uy + cxz * uz
        x = det * si * so
        r = math.sqrt(max(d2 + x * x, 0.0))
        m = si + so
        ct = min(max(hb * r / m, -1.0), 1.0)
        sq = math.sqrt((1.0 - ct) * (1.0 + ct))
        g = math.acos(ct) - ct * sq
        return (si, so, hix, hiy, hiz, hox, hoy, hoz, dx, dy, dz, cxx, cxy, cxz, det, x, r, m, ct, sq, g)

    @nb.njit(cache=True, inline="always")
    def _cook_terms(c, min_, mon, rk, min_cos, f0):
        """Intermediates of Cook–Torrance (eqs 20–23) from cosines, as in kernels.cook_torrance_cos.

        Returns (hh_raw, hh, s, q, nh2, r2, den, dd, a, om, om2, ff, mic, moc, ri, ro): |ω_i + ω_o|²
        (raw, clamped), μ_i + μ_o, (n·h)² (raw, clipped), ρ², the GGX denominator, D, h·ω_o,
        1 − h·ω_o and its square, Schlick F, the clamped cosines and the two horizon ramps.
        """
        hh_raw = 2.0 + 2.0 * c
        hh = max(hh_raw, _TINY)
        s = min_ + mon
        q = s * s / hh
        nh2 = min(max(q, 0.0), 1.0)
        r2 = rk * rk
        den = nh2 * (r2 - 1.0) + 1.0
        dd = r2 / (_PI * den * den)
        a = math.sqrt(max(0.5 * (1.0 + c), 0.0))
        om = 1.0 - a
        om2 = om * om
        ff = f0 + (1.0 - f0) * (om2 * om2 * om)
        mic = max(min_, min_cos)
        moc = max(mon, min_cos)
        ri = min(max(min_ / min_cos, 0.0), 1.0)
        ro = min(max(mon / min_cos, 0.0), 1.0)
        return hh_raw, hh, s, q, nh2, r2, den, dd, a, om, om2, ff, mic, moc, ri, ro

    @nb.njit(cache=True, inline="always")
    def _fwd_one(ix, iy, iz, ox, oy, oz, nx, ny, nz, rho, need_r, need_l, need_c, nframe, min_cos, f0, hb):
        """Kernel values (K_Ross, K_Li, K_Cook) of one Gaussian; n is already flipped toward ω_o."""
        c = ix * ox + iy * oy + iz * oz
        min_ = nx * ix + ny * iy + nz * iz
        mon = nx * ox + ny * oy + nz * oz
        kr = 0.0
        kl = 0.0
        kc = 0.0
        if need_r or need_l:
            ux, uy, uz, mui, muo, mi, mo = _zenith_frame(nframe, nx, ny, nz, iz, oz, min_, mon, min_cos)
            if need_r:
                kr = _ross_phase(c)[1] / (mi + mo) - 0.25 * _PI
            if need_l:
                li = _li_terms(ix, iy, iz, ox, oy, oz, ux, uy, uz, mui, muo, mi, mo, hb)
                si, so, m, g = li[0], li[1], li[17], li[20]
                kl = g * m / _PI - m + 0.5 * (1.0 + c) * si * so
        if need_c:
            ck = _cook_terms(c, min_, mon, rho, min_cos, f0)
            dd, ff, mic, moc, ri, ro = ck[7], ck[11], ck[12], ck[13], ck[14], ck[15]
            kc = dd * ff * (ri * ro) / (4.0 * mic * moc)
        return kr, kl, kc

    @nb.njit(parallel=True, cache=True)
    def _fwd(wi, wo, nrm, rho, need_r, need_l, need_c, nframe, min_cos, f0, hb, out):
        n = wo.shape[0]
        step_i, have_n, step_r = _strides(wi, nrm, rho, need_c, nframe)
        for k in nb.prange(n):
            ix, iy, iz, ox, oy, oz, nx, ny, nz, _sg, rk = _gather(wi, wo, nrm, rho, k, step_i, have_n, step_r)
            kr, kl, kc = _fwd_one(ix, iy, iz, ox, oy, oz, nx, ny, nz, rk, need_r, need_l, need_c, nframe, min_cos, f0, hb)
            out[k, 0] = kr
            out[k, 1] = kl
            out[k, 2] = kc

    @nb.njit(parallel=True, cache=True)
    def _bwd(wi, wo, nrm, rho, need_r, need_l, need_c, nframe, min_cos, f0, hb, gk, g_wi, g_wo, g_n, g_rho):
        """Reverse mode of _fwd: gk [N, 3] → g_wi [N, 3], g_wo [N, 3], g_n [N, 3], g_rho [N]."""
        n = wo.shape[0]
        step_i, have_n, step_r = _strides(wi, nrm, rho, need_c, nframe)
        for k in nb.prange(n):
            ix, iy, iz, ox, oy, oz, nx, ny, nz, sg, rk = _gather(wi, wo, nrm, rho, k, step_i, have_n, step_r)
            gr = gk[k, 0] if need_r else 0.0
            gl = gk[k, 1] if need_l else 0.0
            gc_ = gk[k, 2] if need_c else 0.0

            c = ix * ox + iy * oy + iz * oz
            min_ = nx * ix + ny * iy + nz * iz
            mon = nx * ox + ny * oy + nz * oz
            # accumulated adjoints
            g_c = 0.0
            g_min = 0.0  # d/d(n'·ω_i), n' = flipped normal
            g_mon = 0.0
            gix = 0.0
            giy = 0.0
            giz = 0.0
            gox = 0.0
            goy = 0.0
            goz = 0.0
            gux = 0.0  # adjoint of the flipped normal n'
            guy = 0.0
            guz = 0.0
            grho = 0.0
            if need_r or need_l:
                ux, uy, uz, mui, muo, mi, mo = _zenith_frame(nframe, nx, ny, nz, iz, oz, min_, mon, min_cos)
                g_mi = 0.0
                g_mo = 0.0
                g_mui = 0.0
                g_muo = 0.0
                if need_r:
                    asn, fr = _ross_phase(c)
                    qr = 1.0 / (mi + mo)
                    g_c += gr * asn * qr
                    g_q = -gr * fr * qr * qr
                    g_mi += g_q
                    g_mo += g_q
                if need_l:
                    (si, so, hix, hiy, hiz, hox, hoy, hoz, dx, dy, dz, cxx, cxy, cxz, det, x, r, m, _ct, sq,
                     g) = _li_terms(ix, iy, iz, ox, oy, oz, ux, uy, uz, mui, muo, mi, mo, hb)
                    # K = g m/π − m + ½(1 + c) si so
                    g_m = gl * (g / _PI - 1.0)
                    g_g = gl * m / _PI
                    g_c += gl * 0.5 * si * so
                    g_si = gl * 0.5 * (1.0 + c) * so
                    g_so = gl * 0.5 * (1.0 + c) * si
                    g_ct = g_g * (-2.0 * sq)  # 0 when clipped (sq = 0)
                    g_r = g_ct * hb / m
                    g_m += -g_ct * hb * r / (m * m)
                    g_si += g_m
                    g_so += g_m
                    g_s = g_r * 0.5 / r if r > 0.0 else 0.0
                    g_x = 2.0 * x * g_s
                    g_det = g_x * si * so
                    g_si += g_x * det * so
                    g_so += g_x * det * si
                    # d2 = |d|², d = hi si − ho so
                    gdx = 2.0 * dx * g_s
                    gdy = 2.0 * dy * g_s
                    gdz = 2.0 * dz * g_s
                    g_si += gdx * hix + gdy * hiy + gdz * hiz
                    g_so -= gdx * hox + gdy * hoy + gdz * hoz
                    ghix, ghiy, ghiz = gdx * si, gdy * si, gdz * si
                    ghox, ghoy, ghoz = -gdx * so, -gdy * so, -gdz * so
                    # h = ω − μ u
                    gix += ghix
                    giy += ghiy
                    giz += ghiz
                    gox += ghox
                    goy += ghoy
                    goz += ghoz
                    g_mui -= ghix * ux + ghiy * uy + ghiz * uz
                    g_muo -= ghox * ux + ghoy * uy + ghoz * uz
                    if nframe:
                        gux -= mui * ghix + muo * ghox
                        guy -= mui * ghiy + muo * ghoy
                        guz -= mui * ghiz + muo * ghoz
                        # det = (ω_i × ω_o)·u
                        gux += g_det * cxx
                        guy += g_det * cxy
                        guz += g_det * cxz
                    # ∂det/∂ω_i = ω_o × u, ∂det/∂ω_o = u × ω_i
                    gix += g_det * (oy * uz - oz * uy)
                    giy += g_det * (oz * ux - ox * uz)
                    giz += g_det * (ox * uy - oy * ux)
                    gox += g_det * (uy * iz - uz * iy)
                    goy += g_det * (uz * ix - ux * iz)
                    goz += g_det * (ux * iy - uy * ix)
                    g_mi += -g_si * si * si
                    g_mo += -g_so * so * so
                if mui >= min_cos:
                    g_mui += g_mi
                if muo >= min_cos:
                    g_muo += g_mo
                if nframe:
                    g_min += g_mui
                    g_mon += g_muo
                else:
                    giz += g_mui
                    goz += g_muo
            if need_c:
                (hh_raw, hh, s, q, nh2, r2, den, dd, a, om, om2, ff, mic, moc, ri,
                 ro) = _cook_terms(c, min_, mon, rk, min_cos, f0)
                qq = 1.0 / (4.0 * mic * moc)
                kc = dd * ff * ri * ro * qq
                g_dd = gc_ * ff * ri * ro * qq
                g_ff = gc_ * dd * ri * ro * qq
                if min_ >= min_cos:
                    g_min -= gc_ * kc / mic
                if mon >= min_cos:
                    g_mon -= gc_ * kc / moc
                if min_ >= 0.0 and min_ <= min_cos:
                    g_min += gc_ * dd * ff * ro * qq / min_cos
                if mon >= 0.0 and mon <= min_cos:
                    g_mon += gc_ * dd * ff * ri * qq / min_cos
                g_om = g_ff * (1.0 - f0) * 5.0 * om2 * om2
                if a > 0.0:
                    g_c += -g_om * 0.25 / a
                g_den = g_dd * (-2.0 * dd / den)
                g_r2 = g_dd / (_PI * den * den) + g_den * nh2
                grho += g_r2 * 2.0 * rk
                g_nh2 = g_den * (r2 - 1.0)
                if q <= 1.0:
                    g_q = g_nh2
                    g_s2 = g_q * 2.0 * s / hh
                    g_min += g_s2
                    g_mon += g_s2
                    if hh_raw >= _TINY:
                        g_c += 2.0 * (-g_q * q / hh)
            # μ' = n'·ω
            if need_c or nframe:
                gix, giy, giz = _add_scaled(gix, giy, giz, g_min, nx, ny, nz)
                gox, goy, goz = _add_scaled(gox, goy, goz, g_mon, nx, ny, nz)
                gux += g_min * ix + g_mon * ox
                guy += g_min * iy + g_mon * oy
                guz += g_min * iz + g_mon * oz
            # c = ω_i·ω_o
            gix, giy, giz = _add_scaled(gix, giy, giz, g_c, ox, oy, oz)
            gox, goy, goz = _add_scaled(gox, goy, goz, g_c, ix, iy, iz)
            g_wi[k, 0] = gix
            g_wi[k, 1] = giy
            g_wi[k, 2] = giz
            g_wo[k, 0] = gox
            g_wo[k, 1] = goy
            g_wo[k, 2] = goz
            g_n[k, 0] = sg * gux
            g_n[k, 1] = sg * guy
            g_n[k, 2] = sg * guz
            g_rho[k] = grho

    @nb.njit(parallel=True, cache=True)
    def _combine_fwd(z_iso, z_vol, z_geo, z_spec, kk, use, out):
        n, d = out.shape
        for k in nb.prange(n):
            a0 = 1.0 if use[0] else 0.0
            kr = kk[k, 0] if use[1] else 0.0
            kl = kk[k, 1] if use[2] else 0.0
            kc = kk[k, 2] if use[3] else 0.0
            for e in range(d):
                v = 0.0
                if use[0]:
                    v += z_iso[k, e] * a0
                if use[1]:
                    v += z_vol[k, e] * kr
                if use[2]:
                    v += z_geo[k, e] * kl
                if use[3]:
                    v += z_spec[k, e] * kc
                out[k, e] = v

    @nb.njit(parallel=True, cache=True)
    def _combine_bwd(z_vol, z_geo, z_spec, kk, use, g, g_vol, g_geo, g_spec, g_k):
        n, d = g.shape
        for k in nb.prange(n):
            kr = kk[k, 0]
            kl = kk[k, 1]
            kc = kk[k, 2]
            sr = 0.0
            sl = 0.0
            sc = 0.0
            for e in range(d):
                ge = g[k, e]
                if use[1]:
                    g_vol[k, e] = ge * kr
                    sr += ge * z_vol[k, e]
                if use[2]:
                    g_geo[k, e] = ge * kl
                    sl += ge * z_geo[k, e]
                if use[3]:
                    g_spec[k, e] = ge * kc
                    sc += ge * z_spec[k, e]
            g_k[k, 0] = sr
            g_k[k, 1] = sl
            g_k[k, 2] = sc


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


def _sync_threads() -> None:
    """Use as many numba threads as torch does (torch.set_num_threads is the one knob)."""
    nb.set_num_threads(max(1, min(torch.get_num_threads(), nb.config.NUMBA_NUM_THREADS)))


def _call(kernel, *args) -> None:
    """Run a numba kernel with torch's thread count; tensors go in as numpy views (outputs are written
    into torch-owned memory, which autograd can steal)."""
    _sync_threads()
    kernel(*[_np(a) if isinstance(a, torch.Tensor) else a for a in args])


class _FusedKernelsFn(torch.autograd.Function):
    @staticmethod
    def forward(ctx, wi, wo, nrm, rho, flags):
        # flags = (need_r, need_l, need_c, normal_frame, min_cos, f0, hb), the kernels' trailing arguments
        ctx.flags = flags
        ctx.save_for_backward(wi, wo, nrm, rho)
        out = torch.empty((wo.shape[0], 3), dtype=wo.dtype)
        _call(_fwd, wi, wo, nrm, rho, *flags, out)
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, gk):
        wi, wo, nrm, rho = ctx.saved_tensors
        n, dt = wo.shape[0], wo.dtype
        gwi, gwo, gn = (torch.empty((n, 3), dtype=dt) for _ in range(3))
        grho = torch.empty((n,), dtype=dt)
        _call(_bwd, wi, wo, nrm, rho, *ctx.flags, gk.to(dt), gwi, gwo, gn, grho)
        # an input given as one row for all Gaussians gets the sum of the per-Gaussian gradients
        gwi, gn, grho = (g.sum(0, keepdim=True) if x.shape[0] == 1 else g for g, x in ((gwi, wi), (gn, nrm), (grho, rho)))
        return gwi, gwo, gn, grho, None


def fused_kernels(
    normals: Tensor | None,  # [N, 3] or [1, 3] (any orientation; flipped toward ω_o), or None
    omega_i: Tensor,  # [3] or [N, 3] unit, toward the sun
    omega_o: Tensor,  # [N, 3] unit, toward the camera (its dtype is used throughout)
    rho: Tensor | None,  # [N] or [1] roughness ρ, or None
    need_r: bool,  # compute K_Ross
    need_l: bool,  # compute K_Li
    need_c: bool,  # compute K_Cook
    normal_frame: bool,  # Ross/Li with zenith angles from the normal
    min_cos: float,  # horizon clamp of the cosines
    f0: float,  # Schlick F0
    hb: float = 2.0,  # Li crown relative height h/b
) -> Tensor:  # [N, 3] (K_Ross, K_Li, K_Cook); disabled kernels are 0
    """The three kernels (paper eqs 14–23) on the CPU in one numba pass; differentiable (first order)."""
    wo = omega_o
    wi = omega_i.reshape(-1, 3).to(wo.dtype)
    nrm = normals.to(wo.dtype) if normals is not None else wo.new_zeros((1, 3))
    r = rho.to(wo.dtype).reshape(-1) if rho is not None else wo.new_ones((1,))
    flags = (bool(need_r), bool(need_l), bool(need_c), bool(normal_frame), float(min_cos), float(f0), float(hb))
    return _FusedKernelsFn.apply(wi, wo, nrm, r, flags)


class _CombineFn(torch.autograd.Function):
    @staticmethod
    def forward(ctx, z_iso, z_vol, z_geo, z_spec, kk, use):
        ref = next(z for z in (z_iso, z_vol, z_geo, z_spec) if z is not None)
        dummy = np.zeros((1, 1), dtype=_np(ref).dtype)
        out = torch.empty(tuple(ref.shape), dtype=ref.dtype)
        _call(_combine_fwd, *[dummy if z is None else z for z in (z_iso, z_vol, z_geo, z_spec)], kk,
              np.array(use, dtype=np.bool_), out)
        ctx.save_for_backward(z_vol if use[1] else None, z_geo if use[2] else None, z_spec if use[3] else None, kk)
        ctx.use = use
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, g):
        z_vol, z_geo, z_spec, kk = ctx.saved_tensors
        use = ctx.use
        n, d = g.shape
        dummy = np.zeros((1, 1), dtype=_np(g).dtype)
        outs = [torch.empty((n, d), dtype=g.dtype) if use[i] else None for i in (1, 2, 3)]
        g_k = torch.empty((n, 3), dtype=g.dtype)
        _call(_combine_bwd, *[dummy if z is None else z for z in (z_vol, z_geo, z_spec)], kk,
              np.array(use, dtype=np.bool_), g, *[dummy if o is None else o for o in outs], g_k)
        return (g if use[0] else None, *outs, g_k, None)


def combine(
    z_iso: Tensor | None,  # [N, d] (None when "iso" is off)
    z_vol: Tensor | None,  # [N, d]
    z_geo: Tensor | None,  # [N, d]
    z_spec: Tensor | None,  # [N, d]
    kk: Tensor,  # [N, 3] (K_Ross, K_Li, K_Cook) from fused_kernels
    components: Sequence[str],  # subset of ("iso", "vol", "geo", "spec")
) -> Tensor:  # [N, d]
    """z_iso + z_vol K_Ross + z_geo K_Li + z_spec K_Cook (eq. 12) in one pass (CPU, numba)."""
    use = tuple(c in components for c in ("iso", "vol", "geo", "spec"))
    zs = [z if u else None for z, u in zip((z_iso, z_vol, z_geo, z_spec), use)]
    dt = next(z for z in zs if z is not None).dtype
    zs = [z.to(dt) if z is not None else None for z in zs]
    return _CombineFn.apply(*zs, kk.to(dt), use)
