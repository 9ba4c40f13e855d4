"""Plane-sweep stereo for one reference view: camera geometry, windowed NCC, plane families and the
best plane per pixel (the matching half of :mod:`brfgs.init.mvs`).

A pixel's score at a plane is the mean of the best half of its neighbours' normalised
cross-correlation over a small window, all bands pooled (:func:`windowed_ncc`,
:func:`best_half_mean`: COLMAP's and ACMM's view selection in its simplest form). Two families of
planes are swept: fronto-parallel planes of the reference camera and level planes z = const
(Gallup et al. 2007), each spaced so that the image moves about ``plane_step_px`` between planes
(:func:`parallax_spaced`); a pixel keeps the better family's best plane, refined by a parabola
through the scores beside it (:func:`depth_map`). Cameras follow docs/data-format.md (OpenGL
camera-to-world, converted to OpenCV axes by :func:`cv_pose`); pixel centres lie at +0.5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from brfgs.data.cameras import GL_TO_CV, Intrinsics



def matching_scale(width: int, height: int, max_size_px: int) -> int:
    """Integer area-downscale factor so that the longer side is at most ``max_size_px``."""
    return max(1, math.ceil(max(width, height) / max(int(max_size_px), 1)))


def scaled_intrinsics(intr: Intrinsics, factor: int) -> Intrinsics:
    """Intrinsics of an image area-downscaled by ``factor`` (pixel centres stay at +0.5)."""
    if factor == 1:
        return intr
    return Intrinsics(fl_x=intr.fl_x / factor, fl_y=intr.fl_y / factor, cx=intr.cx / factor,
                      cy=intr.cy / factor, w=intr.w // factor, h=intr.h // factor)


def cv_pose(c2w_gl: np.ndarray) -> tuple[Tensor, Tensor]:  # [3, 3], [3]
    """Camera-to-world rotation (OpenCV axes) and centre of an OpenGL camera-to-world [4, 4]."""
    c2w = np.asarray(c2w_gl, np.float64) @ GL_TO_CV
    return torch.as_tensor(c2w[:3, :3], dtype=torch.float64), torch.as_tensor(c2w[:3, 3], dtype=torch.float64)


def sweep_depths(near_m: float, far_m: float, n: int) -> Tensor:  # [n] m, increasing
    """``n`` depths from ``near_m`` to ``far_m``, uniform in inverse depth."""
    inv = torch.linspace(1.0 / near_m, 1.0 / far_m, n, dtype=torch.float64)
    return 1.0 / inv


def pixel_grid(intr: Intrinsics) -> Tensor:  # [H, W, 3] homogeneous pixel coordinates (u, v, 1)
    """Pixel centres (u + 0.5, v + 0.5, 1) of an image, float64."""
    v, u = torch.meshgrid(torch.arange(intr.h, dtype=torch.float64) + 0.5,
                          torch.arange(intr.w, dtype=torch.float64) + 0.5, indexing="ij")
    return torch.stack([u, v, torch.ones_like(u)], -1)


def intrinsic_matrix(intr: Intrinsics) -> Tensor:  # [3, 3]
    return torch.tensor([[intr.fl_x, 0.0, intr.cx], [0.0, intr.fl_y, intr.cy], [0.0, 0.0, 1.0]], dtype=torch.float64)


def backproject(depth_m: Tensor, intr: Intrinsics, rot: Tensor, centre: Tensor) -> Tensor:  # [H, W, 3] m
    """World points of every pixel at camera depth ``depth_m`` [H, W] (along the optical axis)."""
    rays = pixel_grid(intr) @ torch.linalg.inv(intrinsic_matrix(intr)).T  # [H, W, 3] camera, z = 1
    return (rays * depth_m.to(torch.float64)[..., None]) @ rot.T + centre


def project(points_m: Tensor, intr: Intrinsics, rot: Tensor, centre: Tensor) -> tuple[Tensor, Tensor]:
    """Pixel coordinates [..., 2] (pixel centres at +0.5) and camera depth [...] (m) of world points [..., 3]."""
    pc = (points_m - centre) @ rot  # [..., 3] camera (OpenCV): R^T (X - C)
    z = pc[..., 2]
    uv = torch.stack([intr.fl_x * pc[..., 0] / z + intr.cx, intr.fl_y * pc[..., 1] / z + intr.cy], -1)
    return uv, z


def warp_to_reference(
    images: Tensor,  # [K, C, H', W'] the neighbour views, float32
    uv: Tensor,  # [K, H, W, 2] where each reference pixel lands in each neighbour (px)
    z: Tensor,  # [K, H, W] its depth there (m)
) -> tuple[Tensor, Tensor]:  # [K, C, H, W], valid [K, H, W]
    """Bilinear samples of each neighbour at ``uv`` and whether they lie inside it, in front of the camera."""
    h, w = images.shape[-2:]
    grid = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1).to(images.dtype)  # [K, H, W, 2]
    out = F.grid_sample(images, grid, mode="bilinear", padding_mode="border", align_corners=False)
    valid = (z > 0) & (uv[..., 0] >= 0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= 0.5) & (uv[..., 1] <= h - 0.5)
    return out, valid


def box_mean(x: Tensor, window_px: int) -> Tensor:  # [N, C, H, W]
    """Mean of ``x`` [N, C, H, W] over a ``window_px`` square around each pixel, clipped at the
    border (as ``avg_pool2d(..., count_include_pad=False)``), by running sums along each axis."""
    r = int(window_px) // 2
    h, w = x.shape[-2:]

    def run(y: Tensor, dim: int, n: int) -> Tensor:  # windowed sums along one axis
        c = torch.cumsum(F.pad(y, (0, 0, r + 1, r) if dim == -2 else (r + 1, r)), dim)
        return c.narrow(dim, 2 * r + 1, n) - c.narrow(dim, 0, n)

    ones = torch.ones(1, 1, h, w, dtype=x.dtype)
    count = run(run(ones, -2, h), -1, w)
    return run(run(x, -2, h), -1, w) / count


def window_stats(a: Tensor, window_px: int) -> tuple[Tensor, Tensor]:  # [N, C, H, W], [N, H, W]
    """Window means of each channel of ``a`` [N, C, H, W] and the window's total variance
    Σ_c (mean(a_c²) − mean(a_c)²) (``window_px`` square, border-clipped)."""
    c = a.shape[1]
    box = box_mean(torch.cat([a, (a * a).sum(1, keepdim=True)], 1), window_px)
    ma = box[:, :c]
    return ma, (box[:, c] - (ma * ma).sum(1)).clamp_min(0)


def windowed_ncc(
    a: Tensor,  # [N, C, H, W] or [1, C, H, W]
    b: Tensor,  # [N, C, H, W]
    window_px: int,
    a_stats: tuple[Tensor, Tensor] | None = None,  # window_stats(a), when already known
) -> Tensor:  # [N, H, W] in [-1, 1]
    """Normalised cross-correlation of ``a`` and ``b`` over a window of ``window_px`` pixels
    around each pixel, all channels together (each channel's window mean removed; flat windows
    score 0). The channel sums are taken before the window sums: C + 2 window sums for b."""
    ma, va = a_stats if a_stats is not None else window_stats(a, window_px)
    c = b.shape[1]
    box = box_mean(torch.cat([b, (b * b).sum(1, keepdim=True), (a * b).sum(1, keepdim=True)], 1), window_px)
    mb = box[:, :c]
    cov = box[:, c + 1] - (ma * mb).sum(1)  # [N, H, W]
    vb = (box[:, c] - (mb * mb).sum(1)).clamp_min(0)
    den = torch.sqrt(va * vb)
    return torch.where(den > 1e-12, cov / den.clamp_min(1e-12), torch.zeros_like(cov))


def best_half_mean(
    scores: Tensor,  # [K, ...] NCC per neighbour
    valid: Tensor,  # [K, ...] bool
) -> Tensor:  # [...]: mean of the best ceil(n_valid / 2) scores, -1 with fewer than 2 valid
    """Per pixel, the mean of the best half of the valid neighbours' scores (occlusion-tolerant)."""
    s = torch.where(valid, scores, torch.full_like(scores, -2.0))
    srt = torch.sort(s, dim=0, descending=True).values  # [K, ...]
    n = valid.sum(0)  # [...]
    take = torch.clamp((n + 1) // 2, min=1)
    rank = torch.arange(s.shape[0]).reshape(-1, *([1] * (s.dim() - 1)))
    mean = (srt * (rank < take)).sum(0) / take
    return torch.where(n >= 2, mean, torch.full_like(mean, -1.0))


@dataclass
class PlaneFamily:
    """Swept planes n · X = s (world, m): a unit normal [3] and increasing offsets s [D]."""

    normal: Tensor  # [3]
    offsets: Tensor  # [D] m


def fronto_parallel(ref_pose: tuple[Tensor, Tensor], depths_m: Tensor) -> PlaneFamily:
    """Planes parallel to the reference image at the camera depths ``depths_m`` [D]."""
    n = ref_pose[0][:, 2]  # the optical axis in world coordinates
    return PlaneFamily(n, depths_m + n @ ref_pose[1])


def horizontal(heights_m: Tensor) -> PlaneFamily:
    """Level planes z = h (ground and roofs of a landscape) at the heights ``heights_m`` [D]."""
    return PlaneFamily(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), heights_m)


def reference_rays(intr: Intrinsics, ref_pose: tuple[Tensor, Tensor]) -> Tensor:  # [H, W, 3] world
    """World direction of every reference pixel's ray, scaled to unit camera depth."""
    return pixel_grid(intr) @ torch.linalg.inv(intrinsic_matrix(intr)).T @ ref_pose[0].T


def plane_depths(rays: Tensor, centre: Tensor, normal: Tensor, offset: Tensor) -> Tensor:  # [..., H, W] m
    """Camera depth where each ray (``reference_rays``) meets the plane(s) n · X = offset [...]
    (NaN behind the camera or parallel)."""
    nr = rays @ normal  # [H, W]
    t = (offset.reshape(*offset.shape, 1, 1) - normal @ centre) / nr
    return torch.where((t > 0) & (nr.abs() > 1e-9), t, torch.full_like(t, float("nan")))


def parallax_spaced(
    family: PlaneFamily,  # a fine sweep (increasing offsets)
    intr: Intrinsics,
    ref_pose: tuple[Tensor, Tensor],
    nbr_poses: list[tuple[Tensor, Tensor]],
    step_px: float,
    max_planes: int,
    min_planes: int = 8,
) -> PlaneFamily:
    """A subset of ``family``'s planes spaced evenly in image motion: consecutive planes move nine
    probe pixels (centre, corners, edge midpoints) by at most about ``step_px`` in any neighbour,
    using as few planes as that needs (between ``min_planes`` and ``max_planes``)."""
    us = torch.tensor([0.5, intr.w / 2, intr.w - 0.5], dtype=torch.float64)
    vs = torch.tensor([0.5, intr.h / 2, intr.h - 0.5], dtype=torch.float64)
    vv, uu = torch.meshgrid(vs, us, indexing="ij")
    probe = torch.stack([uu.reshape(-1), vv.reshape(-1), torch.ones(9, dtype=torch.float64)], -1)  # [9, 3]
    rays = probe @ torch.linalg.inv(intrinsic_matrix(intr)).T @ ref_pose[0].T  # [9, 3]
    nr = rays @ family.normal  # [9]
    t = (family.offsets[:, None] - family.normal @ ref_pose[1]) / nr  # [D, 9] camera depths
    pts = rays[None] * t[..., None] + ref_pose[1]  # [D, 9, 3]
    motion = torch.zeros(len(family.offsets) - 1, dtype=torch.float64)
    for pose in nbr_poses:
        uv, z = project(pts, intr, *pose)  # [D, 9, 2]
        step = torch.linalg.vector_norm(uv[1:] - uv[:-1], dim=-1)  # [D-1, 9]
        ok = (t[1:] > 0) & (t[:-1] > 0) & (z[1:] > 0) & (z[:-1] > 0) & torch.isfinite(step)
        motion = torch.maximum(motion, torch.where(ok, step, torch.zeros_like(step)).max(1).values)
    cum = torch.cat([torch.zeros(1, dtype=torch.float64), torch.cumsum(motion, 0)])  # [D]
    n = int(min(max(math.ceil(float(cum[-1]) / step_px) + 1, min_planes), max_planes))
    want = torch.linspace(0.0, float(cum[-1]), n, dtype=torch.float64)
    idx = torch.searchsorted(cum, want).clamp(0, len(cum) - 1).unique()
    return PlaneFamily(family.normal, family.offsets[idx])


def sweep_scores(
    ref: Tensor,  # [C, H, W] reference view (bands normalised), float32
    nbrs: Tensor,  # [K, C, H, W] neighbour views, float32
    intr: Intrinsics,
    ref_pose: tuple[Tensor, Tensor],  # rotation [3, 3], centre [3]
    nbr_poses: list[tuple[Tensor, Tensor]],  # K of them
    family: PlaneFamily,
    window_px: int = 5,
    chunk: int = 8,
) -> Tensor:  # [D, H, W] best-half mean NCC per plane (-1: no score)
    """Score every plane of ``family`` at every reference pixel: the neighbours warped into the
    reference by the plane's homography, NCC over the window, best half of the neighbours."""
    k_mat = intrinsic_matrix(intr)
    rays = reference_rays(intr, ref_pose)  # [H, W, 3]
    mx = torch.stack([rays @ rot @ k_mat.T for rot, _ in nbr_poses]).float()  # [K, H, W, 3]
    t0 = torch.stack([(ref_pose[1] - c) @ rot @ k_mat.T for rot, c in nbr_poses]).float()  # [K, 3]
    n_k, _, h, w = nbrs.shape
    a_stats = window_stats(ref[None], window_px)
    scores = []
    for start in range(0, len(family.offsets), chunk):
        dep = plane_depths(rays, ref_pose[1], family.normal, family.offsets[start : start + chunk]).float()  # [P, H, W]
        ok = torch.isfinite(dep)
        q = mx[None] * torch.nan_to_num(dep, nan=1.0)[:, None, :, :, None] + t0[None, :, None, None, :]  # [P, K, H, W, 3]
        z = q[..., 2]
        uv = q[..., :2] / torch.where(z.abs() > 1e-12, z, torch.full_like(z, 1e-12))[..., None]
        n_p = dep.shape[0]
        warped, valid = warp_to_reference(nbrs.repeat(n_p, 1, 1, 1), uv.reshape(n_p * n_k, h, w, 2),
                                          z.reshape(n_p * n_k, h, w))
        valid = valid.reshape(n_p, n_k, h, w) & ok[:, None]
        ncc = windowed_ncc(ref[None], warped, window_px, a_stats).reshape(n_p, n_k, h, w)
        scores.append(best_half_mean(ncc.transpose(0, 1), valid.transpose(0, 1)))
    return torch.cat(scores).to(torch.float64)


def best_plane_depth(
    scores: Tensor,  # [D, H, W]
    family: PlaneFamily,
    rays: Tensor,  # [H, W, 3] reference_rays
    centre: Tensor,  # [3]
) -> tuple[Tensor, Tensor]:  # depth [H, W] m (NaN: none), score [H, W]
    """The best plane per pixel, refined by a parabola through its neighbours' scores (offset
    interpolated linearly between planes), as a camera depth."""
    best, k = scores.max(0)  # [H, W]
    last = scores.shape[0] - 1
    km, kp = (k - 1).clamp(0, last), (k + 1).clamp(0, last)
    sm, sp = scores.gather(0, km[None])[0], scores.gather(0, kp[None])[0]
    curv = sm - 2 * best + sp
    inner = (curv < 0) & (km != k) & (kp != k)
    off = torch.where(inner, 0.5 * (sm - sp) / torch.where(inner, curv, torch.ones_like(curv)), torch.zeros_like(best))
    off = off.clamp(-0.5, 0.5)
    s = family.offsets
    side = torch.where(off >= 0, kp, km)
    plane = s[k] + off.abs() * (s[side] - s[k])  # [H, W]
    nr = rays @ family.normal
    depth = (plane - family.normal @ centre) / nr
    ok = (best > -1) & (depth > 0) & (nr.abs() > 1e-9)
    return torch.where(ok, depth, torch.full_like(depth, float("nan"))), best


def depth_map(
    ref: Tensor,  # [C, H, W] reference view (bands normalised), float32
    nbrs: Tensor,  # [K, C, H, W] neighbour views, float32
    intr: Intrinsics,
    ref_pose: tuple[Tensor, Tensor],  # rotation [3, 3], centre [3]
    nbr_poses: list[tuple[Tensor, Tensor]],  # K of them
    families: list[PlaneFamily],
    window_px: int = 5,
) -> tuple[Tensor, Tensor]:  # depth [H, W] m (NaN: none), score [H, W]
    """Plane-sweep depth of every reference pixel over several families of planes (Gallup et al.
    2007: level planes for the ground, fronto-parallel ones for the rest): per pixel, the best
    plane of the family that scores best."""
    rays = reference_rays(intr, ref_pose)
    depth = torch.full((intr.h, intr.w), float("nan"), dtype=torch.float64)
    score = torch.full((intr.h, intr.w), -2.0, dtype=torch.float64)
    for fam in families:
        d, s = best_plane_depth(sweep_scores(ref, nbrs, intr, ref_pose, nbr_poses, fam, window_px), fam, rays,
                                ref_pose[1])
        better = (s > score) & torch.isfinite(d)
        depth, score = torch.where(better, d, depth), torch.where(better, s, score)
    return depth, score
