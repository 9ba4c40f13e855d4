"""Fast CPU rasterizer: numba kernels (``_numba_project``, ``_numba_kernels``) wrapped in autograd Functions.

Projection, its backward, the depth sort, tile binning, rasterization and its backward all
run in compiled, multi-threaded code; PyTorch only moves tensors in and out (zero copy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import torch
from torch import Tensor

from brfgs.render import _numba_kernels as nk
from brfgs.render import _numba_project as npj
from brfgs.render._common import ALPHA_MIN, EXTENT_ABS, EXTENT_REL, fov_limits, n_tiles
from brfgs.render.depth_sort import stable_depth_order
from brfgs.render.torch_backend import Projection


@dataclass
class _Binning:
    tile_start: np.ndarray   # [T+1] int64
    tile_gid: np.ndarray     # [E] int32
    gauss_start: np.ndarray  # [N+1] int64
    gauss_entry: np.ndarray  # [E] int64
    radii: np.ndarray        # [N, 2]
    smax: np.ndarray         # [N] float64 σ bound of the α ≥ 1/255 footprint (with margin)
    n_tiles_x: int


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


class _ProjectFn(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, view64, cam, width, height, near, far):
        N = means.shape[0]
        dt = means.dtype
        m2d = torch.empty(N, 2, dtype=dt)
        con = torch.empty(N, 3, dtype=dt)
        dep = torch.empty(N, dtype=dt)
        rad = torch.empty(N, 2, dtype=dt)
        rect = torch.empty(N, 4, dtype=torch.int32)
        vis = torch.empty(N, dtype=torch.bool)
        npj.project_fwd(_np(means), _np(quats), _np(scales), _np(opacities), view64, cam,
                       int(width), int(height), float(near), float(far),
                       m2d.numpy(), con.numpy(), dep.numpy(), rad.numpy(), rect.numpy(), vis.numpy())
        ctx.save_for_backward(means, quats, scales, vis)
        ctx.view64, ctx.cam = view64, cam
        ctx.mark_non_differentiable(rad, rect, vis)
        return m2d, con, dep, rad, rect, vis

    @staticmethod
    def backward(ctx, v_m2d, v_con, v_dep, _r, _rect, _vis):
        means, quats, scales, vis = ctx.saved_tensors
        N = means.shape[0]
        dt = means.dtype
        z2 = lambda v, shape: torch.zeros(shape, dtype=dt) if v is None else v  # noqa: E731
        v_m2d = z2(v_m2d, (N, 2)); v_con = z2(v_con, (N, 3)); v_dep = z2(v_dep, (N,))
        gm = torch.empty(N, 3, dtype=dt)
        gq = torch.empty(N, 4, dtype=dt)
        gs = torch.empty(N, 3, dtype=dt)
        npj.project_bwd(_np(means), _np(quats), _np(scales), ctx.view64, ctx.cam, _np(vis),
                       _np(v_m2d), _np(v_con), _np(v_dep), gm.numpy(), gq.numpy(), gs.numpy())
        return gm, gq, gs, None, None, None, None, None, None, None


class _RasterFn(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, binning: _Binning, width, height, absgrad):
        dt = colors.dtype
        D = colors.shape[1]
        image = torch.empty(height, width, D, dtype=dt)
        t_final = torch.empty(height, width, dtype=dt)
        n_used = torch.empty(height, width, dtype=torch.int32)
        with numba.parallel_chunksize(1):  # tiles differ in cost: deal them out dynamically
            nk.raster_fwd(_np(means2d), _np(conics), _np(opacities), binning.radii, binning.smax, _np(colors),
                          binning.tile_start, binning.tile_gid, int(width), int(height), binning.n_tiles_x,
                          image.numpy(), t_final.numpy(), n_used.numpy())
        ctx.save_for_backward(means2d, conics, opacities, colors, t_final, n_used)
        ctx.binning, ctx.width, ctx.height = binning, width, height
        ctx.absgrad_of = means2d if absgrad else None  # the tensor that gets .absgrad (as gsplat)
        return image, 1.0 - t_final

    @staticmethod
    def backward(ctx, v_image, v_alpha):
        means2d, conics, opacities, colors, t_final, n_used = ctx.saved_tensors
        b = ctx.binning
        N, D = colors.shape
        dt = colors.dtype
        H, W = ctx.height, ctx.width
        if v_image is None:
            v_image = torch.zeros(H, W, D, dtype=dt)
        if v_alpha is None:
            v_alpha = torch.zeros(H, W, dtype=dt)
        E = b.tile_gid.shape[0]
        e_m2d = np.empty((E, 2), dt_np(dt))
        e_con = np.empty((E, 3), dt_np(dt))
        e_op = np.empty(E, dt_np(dt))
        e_col = np.empty((E, D), dt_np(dt))
        args = (_np(means2d), _np(conics), _np(opacities), b.radii, b.smax, _np(colors), b.tile_start, b.tile_gid,
                int(W), int(H), b.n_tiles_x, _np(t_final), _np(n_used), _np(v_image.to(dt)), _np(v_alpha.to(dt)),
                e_m2d, e_con, e_op, e_col)
        absgrad = ctx.absgrad_of is not None
        e_abs = np.empty((E, 2), dt_np(dt)) if absgrad else None
        with numba.parallel_chunksize(1):
            if absgrad:
                nk.raster_bwd_abs(*args, e_abs)
            else:
                nk.raster_bwd(*args)
        v_m2d = torch.empty(N, 2, dtype=dt)
        v_con = torch.empty(N, 3, dtype=dt)
        v_op = torch.empty(N, dtype=dt)
        v_col = torch.empty(N, D, dtype=dt)
        nk.reduce_entries(b.gauss_start, b.gauss_entry, e_m2d, e_con, e_op, e_col,
                          v_m2d.numpy(), v_con.numpy(), v_op.numpy(), v_col.numpy())
        if absgrad:
            v_abs = torch.empty(N, 2, dtype=dt)
            nk.reduce_pairs(b.gauss_start, b.gauss_entry, e_abs, v_abs.numpy())
            _add_absgrad(ctx.absgrad_of, v_abs)
        return v_m2d, v_con, v_op, v_col, None, None, None, None


def _add_absgrad(means2d: Tensor, v_abs: Tensor) -> None:
    """Accumulate ``v_abs`` [N, 2] into ``means2d.absgrad`` (AbsGS; like ``.grad``, it sums
    over backward passes until the caller clears it)."""
    prev = getattr(means2d, "absgrad", None)
    means2d.absgrad = v_abs if prev is None else prev + v_abs


def dt_np(dt: torch.dtype) -> type:
    """The numpy dtype of the float tensor dtype ``dt`` (float64 or float32)."""
    return np.float64 if dt == torch.float64 else np.float32


def project(
    means: Tensor,  # [N, 3] m, world
    quats: Tensor,  # [N, 4] (w, x, y, z), any norm
    scales: Tensor,  # [N, 3] m
    opacities: Tensor,  # [N]
    viewmat: Tensor,  # [4, 4] world -> camera (OpenCV axes)
    K: Tensor,  # [3, 3] px
    width: int,  # px
    height: int,  # px
    near: float,  # m, near plane
    far: float,  # m, far plane
) -> Projection:
    """numba EWA projection (3DGS eqs 5–6), same semantics and outputs as ``torch_backend.project``."""
    view64 = np.ascontiguousarray(viewmat.detach().cpu().double().numpy())
    Kd = K.detach().cpu().double().numpy()
    cam = np.array([Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2], *fov_limits(Kd, width, height)], np.float64)
    m2d, con, dep, rad, rect, vis = _ProjectFn.apply(means, quats, scales, opacities, view64, cam,
                                                     width, height, near, far)
    return Projection(m2d, con, dep, rad, rect, vis)


def binning(
    proj: Projection,
    opacities: Tensor,  # [N]
    width: int,  # px
    height: int,  # px
) -> _Binning:
    """Depth sort (stable) and tile lists of the visible Gaussians."""
    vis = proj.visible.numpy()
    idx = np.flatnonzero(vis)
    z = proj.depths.detach().numpy()[idx]
    order = idx[stable_depth_order(z)].astype(np.int64)
    ntx, nty = n_tiles(width, height)
    rect = proj.rect.numpy()
    ts, tg, gs, ge = nk.bin_tiles(order, rect, ntx, ntx * nty, proj.means2d.shape[0])
    o = opacities.detach().numpy().astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        smax = np.log(255.0 * np.maximum(o, ALPHA_MIN)) * (1.0 + EXTENT_REL) + EXTENT_ABS
    return _Binning(ts, tg, gs, ge, _np(proj.radii_xy), smax, ntx)


def raster(
    proj: Projection,
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D] any channels
    width: int, height: int,  # px
    absgrad: bool = False,
) -> tuple[Tensor, Tensor]:  # image [H, W, D], alpha [H, W]
    """Composite ``colors`` front to back (numba, hand-written backward); with ``absgrad`` the
    backward pass also sets ``proj.means2d.absgrad`` [N, 2] (Σ_pixels |∂L_p/∂means2d|, AbsGS)."""
    b = binning(proj, opacities, width, height)
    return _RasterFn.apply(proj.means2d, proj.conics, opacities, colors, b, width, height, absgrad)
