"""Reference rasterizer in plain PyTorch (autograd for every gradient).

Readable and vectorised per tile: for each 16×16 tile a dense [pixels, K] block of
alphas for the K Gaussians binned to the tile, compositing by ``cumprod``. It is the
reference the tests compare the fast backends against; see ``_common`` for the
semantics.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from brfgs.render._common import (
    ALPHA_MAX, ALPHA_MIN, EPS2D, EXTENT_ABS, EXTENT_REL, T_MIN, TILE, fov_limits, n_tiles,
)


@dataclass
class Projection:
    """Per-Gaussian screen-space quantities of one camera."""

    means2d: torch.Tensor   # [N, 2] pixels (x right, y down)
    conics: torch.Tensor    # [N, 3] (a, b, c) of the inverse 2D covariance
    depths: torch.Tensor    # [N] z in camera coordinates, metres
    radii_xy: torch.Tensor  # [N, 2] float, half extent of the α ≥ 1/255 box, pixels (0 if invisible)
    rect: torch.Tensor      # [N, 4] int64 tile rectangle (tx0, ty0, tx1, ty1), inclusive
    visible: torch.Tensor   # [N] bool


def _rotmat_unshared(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N, 3, 3] from quaternions [N, 4] (wxyz, normalised here).

    The same values as :func:`brfgs.render.geometry.quat_to_rotmat` (bit for bit), but every entry
    forms its own products, so autograd sums the quaternion gradient in another order (it differs
    from the shared formula's in the last bits). Kept so that ``backend="torch"`` (the ``tiny``
    training preset) reproduces earlier runs bit for bit; replace it with the shared formula when
    that may change.
    """
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(q.shape[:-1] + (3, 3))


def camera_cov2d(
    means: Tensor,  # [N, 3] m, world
    quats: Tensor,  # [N, 4] (w, x, y, z), any norm
    scales: Tensor,  # [N, 3] m
    viewmat: Tensor,  # [4, 4] float64 world -> camera (OpenCV axes)
    K: Tensor,  # [3, 3] float64 px
    width: int,  # px
    height: int,  # px
    near: float,  # m
    far: float,  # m
) -> tuple[Tensor, Tensor, Tensor]:  # camera coords [N, 3] m, in_depth [N] bool, cov2d [N, 2, 2] px²
    """Camera coordinates and the EWA image covariance J W Σ Wᵀ Jᵀ without the low-pass
    (3DGS, Kerbl et al. 2023, eq. 5; the Jacobian's x/z, y/z clamped to 1.3× the field of view)."""
    dtype = means.dtype
    Rw = viewmat[:3, :3].to(dtype)  # [3, 3]
    tw = viewmat[:3, 3].to(dtype)   # [3]
    fx, fy = float(K[0, 0]), float(K[1, 1])
    pc = means @ Rw.T + tw          # [N, 3] camera coordinates (OpenCV)
    z = pc[:, 2]
    in_depth = (z > near) & (z < far)
    zs = torch.where(in_depth, z, torch.ones_like(z))  # safe divisor
    x, y = pc[:, 0], pc[:, 1]
    lxn, lxp, lyn, lyp = fov_limits(K, width, height)
    tx = zs * torch.clamp(x / zs, -lxn, lxp)
    ty = zs * torch.clamp(y / zs, -lyn, lyp)
    zero = torch.zeros_like(zs)
    J = torch.stack([fx / zs, zero, -fx * tx / (zs * zs),
                     zero, fy / zs, -fy * ty / (zs * zs)], -1).reshape(-1, 2, 3)  # [N, 2, 3]
    R = _rotmat_unshared(quats)                 # [N, 3, 3]
    M = R * scales[:, None, :]                  # [N, 3, 3] = R S
    cov3 = M @ M.transpose(1, 2)                # [N, 3, 3] world
    covc = Rw @ cov3 @ Rw.T                     # [N, 3, 3] camera
    return pc, in_depth, J @ covc @ J.transpose(1, 2)  # [N, 2, 2]


def project(
    means: Tensor,  # [N, 3] m, world
    quats: Tensor,  # [N, 4] (w, x, y, z), any norm
    scales: Tensor,  # [N, 3] m
    opacities: Tensor,  # [N]
    viewmat: Tensor,  # [4, 4] float64 world -> camera (OpenCV axes)
    K: Tensor,  # [3, 3] float64 px
    width: int,  # px
    height: int,  # px
    near: float,  # m, near plane
    far: float,  # m, far plane
) -> Projection:  # per-Gaussian screen-space quantities, see Projection
    """EWA projection of 3D Gaussians to the image (3DGS, Kerbl et al. 2023, eqs 5–6; gsplat conventions)."""
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    pc, in_depth, cov2 = camera_cov2d(means, quats, scales, viewmat, K, width, height, near, far)
    z = pc[:, 2]
    zs = torch.where(in_depth, z, torch.ones_like(z))  # safe divisor
    x, y = pc[:, 0], pc[:, 1]
    a2 = cov2[:, 0, 0] + EPS2D
    b2 = cov2[:, 0, 1]
    c2 = cov2[:, 1, 1] + EPS2D
    det = a2 * c2 - b2 * b2
    ok = in_depth & (det > 0) & (opacities > ALPHA_MIN)
    det_s = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([c2 / det_s, -b2 / det_s, a2 / det_s], -1)   # [N, 3]
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], -1)   # [N, 2]
    # Footprint: box of the ellipse σ ≤ ln(255 o) (non-differentiable), float64.
    with torch.no_grad():
        o64 = opacities.detach().double().clamp_min(ALPHA_MIN)
        smax = torch.log(255.0 * o64) * (1 + EXTENT_REL) + EXTENT_ABS
        rx = torch.sqrt(2.0 * smax * a2.detach().double().clamp_min(0))
        ry = torch.sqrt(2.0 * smax * c2.detach().double().clamp_min(0))
        mx = means2d[:, 0].detach().double()
        my = means2d[:, 1].detach().double()
        px0 = torch.floor(mx - rx) - 1
        px1 = torch.ceil(mx + rx)
        py0 = torch.floor(my - ry) - 1
        py1 = torch.ceil(my + ry)
        ok = ok & (px1 >= 0) & (px0 <= width - 1) & (py1 >= 0) & (py0 <= height - 1)
        ok = ok & torch.isfinite(mx) & torch.isfinite(my)
        px0 = px0.clamp(0, width - 1).nan_to_num(0).long()
        px1 = px1.clamp(0, width - 1).nan_to_num(0).long()
        py0 = py0.clamp(0, height - 1).nan_to_num(0).long()
        py1 = py1.clamp(0, height - 1).nan_to_num(0).long()
        rect = torch.stack([px0 // TILE, py0 // TILE, px1 // TILE, py1 // TILE], -1)
        radii_xy = torch.where(ok[:, None], torch.stack([rx, ry], -1), torch.zeros_like(torch.stack([rx, ry], -1)))
    return Projection(means2d, conics, z, radii_xy.to(means.dtype), rect, ok)


def bin_tiles(
    proj: Projection,
    width: int,  # px
    height: int,  # px
) -> tuple[Tensor, Tensor]:  # tile_start [T + 1] int64, Gaussian ids [E] int64
    """Tile lists sorted by tile, then depth (stable): tile t holds ids[tile_start[t]:tile_start[t + 1]]."""
    ntx, nty = n_tiles(width, height)
    vis = torch.nonzero(proj.visible).squeeze(1)                     # [V]
    order = vis[torch.sort(proj.depths.detach()[vis], stable=True).indices]  # [V] front to back
    r = proj.rect[order]                                              # [V, 4]
    w = r[:, 2] - r[:, 0] + 1
    h = r[:, 3] - r[:, 1] + 1
    cnt = w * h                                                       # [V]
    gid = torch.repeat_interleave(order, cnt)                         # [E]
    first = torch.repeat_interleave(torch.cumsum(cnt, 0) - cnt, cnt)
    local = torch.arange(gid.numel()) - first                         # index within the rectangle
    rw = torch.repeat_interleave(w, cnt)
    tx = torch.repeat_interleave(r[:, 0], cnt) + local % rw
    ty = torch.repeat_interleave(r[:, 1], cnt) + local // rw
    tile = ty * ntx + tx
    srt = torch.sort(tile, stable=True).indices                       # keeps depth order inside a tile
    counts = torch.bincount(tile, minlength=ntx * nty)
    start = torch.zeros(ntx * nty + 1, dtype=torch.long)
    start[1:] = torch.cumsum(counts, 0)
    return start, gid[srt]


def raster(
    proj: Projection,
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D] any channels
    width: int,  # px
    height: int,  # px
    absgrad: bool = False,
) -> tuple[Tensor, Tensor]:  # image [H, W, D], alpha [H, W]
    """Composite ``colors`` front to back per 16×16 tile (α-blending of 3DGS, cumprod transmittance).

    With ``absgrad`` the backward pass also fills ``proj.means2d.absgrad`` [N, 2]: each pixel's
    gradient of the means taken apart (autograd of a per-pixel copy) and summed in absolute value."""
    ntx, nty = n_tiles(width, height)
    absacc = None
    if absgrad and proj.means2d.requires_grad:
        absacc = torch.zeros(proj.means2d.shape, dtype=proj.means2d.dtype)  # [N, 2], filled by hooks
        proj.means2d.absgrad = absacc
    start, gids = bin_tiles(proj, width, height)
    dtype = colors.dtype
    D = colors.shape[1]
    rows = []
    ar = torch.arange(TILE, dtype=dtype)
    for ty in range(nty):
        row_img, row_alpha = [], []
        y0 = ty * TILE
        th = min(TILE, height - y0)
        for tx in range(ntx):
            x0 = tx * TILE
            tw = min(TILE, width - x0)
            t = ty * ntx + tx
            ids = gids[start[t]:start[t + 1]]                         # [K] (K may be 0)
            py, px = torch.meshgrid(ar[:th] + (y0 + 0.5), ar[:tw] + (x0 + 0.5), indexing="ij")
            m = proj.means2d[ids][None]                               # [1, K, 2]
            if absacc is not None and m.requires_grad:
                m = m.expand(th * tw, -1, -1)                         # [P, K, 2] a copy per pixel
                m.register_hook(_abs_sum_into(absacc, ids))
            cn = proj.conics[ids]                                     # [K, 3]
            dx = px.reshape(-1, 1) - m[:, :, 0]                       # [P, K]
            dy = py.reshape(-1, 1) - m[:, :, 1]                       # [P, K]
            sigma = 0.5 * (cn[None, :, 0] * dx * dx + cn[None, :, 2] * dy * dy) + cn[None, :, 1] * dx * dy
            alpha = torch.clamp(opacities[ids][None, :] * torch.exp(-sigma), max=ALPHA_MAX)  # [P, K]
            keep = (alpha >= ALPHA_MIN) & (sigma >= 0)
            with torch.no_grad():
                a_keep = torch.where(keep, alpha, torch.zeros_like(alpha))
                t_incl = torch.cumprod(1 - a_keep, dim=1)             # transmittance after each pair
                use = keep & (t_incl >= T_MIN)                        # 3DGS stops before T < 1e-4
            a = torch.where(use, alpha, torch.zeros_like(alpha))      # [P, K]
            ones = torch.ones(a.shape[0], 1, dtype=dtype)
            trans = torch.cat([ones, torch.cumprod(1 - a, dim=1)], 1)  # [P, K + 1] transmittance
            w = a * trans[:, :-1]                                     # [P, K] blending weights
            img = w @ colors[ids]                                     # [P, D]
            row_img.append(img.reshape(th, tw, D))
            row_alpha.append((1 - trans[:, -1]).reshape(th, tw))
        rows.append((torch.cat(row_img, 1), torch.cat(row_alpha, 1)))
    image = torch.cat([r[0] for r in rows], 0)
    alpha = torch.cat([r[1] for r in rows], 0)
    return image, alpha


def _abs_sum_into(acc: Tensor, ids: Tensor):
    """A gradient hook that adds Σ_p |grad[p]| [K, 2] to the rows ``ids`` of ``acc`` [N, 2]."""
    def hook(grad: Tensor | None) -> None:  # grad [P, K, 2]
        if grad is not None:  # (None when only other inputs' gradients are asked for)
            acc.index_add_(0, ids, grad.detach().abs().sum(0))
    return hook
