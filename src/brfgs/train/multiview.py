"""Multi-view photometric consistency of the rendered geometry (PGSR, Chen et al. 2024; the
patch-matching idea of multi-view stereo applied to the Gaussians' own depth and normals).

For sampled pixels x of the training view being rendered, the rendered depth d and normal n
define a local plane. Its homography carries a small patch around x into a neighbouring
training view; the neighbour's *observed* image, sampled there, should match the reference's
observed patch. The loss is 1 − NCC of the two patches (all stage-1 bands together), the better
of two neighbours per pixel (one of them may not see the point). Its gradient reaches the depth
and the normal through the sampling positions, so the ground is pulled onto the height at which
all views agree: the photometric loss alone lets layered, semi-transparent ground fit each
training view with texture at view-dependent heights (docs/results.md, "Where the 58° ring loses").
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from brfgs.init.mvs import view_neighbours
from brfgs.model.camera import Camera


def patch_offsets(radius_px: int) -> Tensor:  # [P, 2] px
    """Integer offsets (dx, dy) of a (2r + 1)² patch."""
    r = torch.arange(-radius_px, radius_px + 1, dtype=torch.float32)
    dy, dx = torch.meshgrid(r, r, indexing="ij")
    return torch.stack([dx.reshape(-1), dy.reshape(-1)], -1)


def relative_pose(ref: Camera, nbr: Camera) -> tuple[Tensor, Tensor]:  # R [3, 3], t [3]
    """(R, t) with X_nbr = R X_ref + t for camera coordinates (OpenCV axes) of the two cameras."""
    a, b = ref.viewmat.double(), nbr.viewmat.double()  # world -> camera
    rel = b @ torch.linalg.inv(a)
    return rel[:3, :3].float(), rel[:3, 3].float()


def plane_warp(
    xy: Tensor,  # [N, 2] reference pixel positions (pixel centres at +0.5)
    depth: Tensor,  # [N] camera depth at xy (m)
    normal: Tensor,  # [N, 3] unit normal at xy, reference camera axes
    offsets: Tensor,  # [P, 2] patch offsets (px)
    k_ref: Tensor,  # [3, 3]
    k_nbr: Tensor,  # [3, 3]
    rot: Tensor,  # [3, 3] reference -> neighbour camera
    trans: Tensor,  # [3]
) -> tuple[Tensor, Tensor]:  # uv [N, P, 2] in the neighbour (px), z [N, P] (> 0: in front)
    """Where each patch pixel x + o lands in the neighbour under the plane through the point of
    depth ``depth`` at x with normal ``normal``: the homography K_n (R + t nᵀ / c) K_r⁻¹, c = n · X."""
    k_inv = torch.linalg.inv(k_ref)
    ones = torch.ones_like(xy[:, :1])
    x_cam = torch.cat([xy, ones], -1) @ k_inv.T * depth[:, None]  # [N, 3] the centre point
    c = (normal * x_cam).sum(-1)  # [N] plane offset n · X
    c = torch.where(c.abs() < 1e-6, torch.full_like(c, 1e-6), c)
    pix = xy[:, None, :] + offsets[None]  # [N, P, 2]
    rays = torch.cat([pix, torch.ones_like(pix[..., :1])], -1) @ k_inv.T  # [N, P, 3] camera rays, z = 1
    # H x = R x + t (n · x) / c for each patch ray (a point of the plane up to scale)
    mapped = rays @ rot.T + trans * ((rays * normal[:, None, :]).sum(-1, keepdim=True) / c[:, None, None])
    q = mapped @ k_nbr.T  # [N, P, 3]
    z = q[..., 2]
    uv = q[..., :2] / torch.where(z.abs() > 1e-9, z, torch.full_like(z, 1e-9))[..., None]
    return uv, z


def sample_image(image: Tensor, uv: Tensor) -> tuple[Tensor, Tensor]:  # [N, P, C], inside [N, P]
    """Bilinear samples of ``image`` [H, W, C] at ``uv`` [N, P, 2] (pixel centres at +0.5; differentiable
    in ``uv``) and whether each lies inside the image."""
    h, w, c = image.shape
    grid = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1)[None]  # [1, N, P, 2]
    out = F.grid_sample(image.permute(2, 0, 1)[None], grid, mode="bilinear", padding_mode="border",
                        align_corners=False)[0]  # [C, N, P]
    inside = (uv[..., 0] >= 0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= 0.5) & (uv[..., 1] <= h - 0.5)
    return out.permute(1, 2, 0), inside


def patch_ncc(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:  # [N], a's variance [N]
    """NCC of patches a, b [N, P, C] (each channel's patch mean removed, channels pooled)."""
    da = a - a.mean(1, keepdim=True)
    db = b - b.mean(1, keepdim=True)
    va, vb = (da * da).sum((1, 2)), (db * db).sum((1, 2))
    return (da * db).sum((1, 2)) / torch.sqrt(va * vb + 1e-12), va


def multiview_loss(
    depth_premult: Tensor,  # [H, W] rendered (premultiplied) depth of the reference window (m)
    normal_premult: Tensor,  # [H, W, 3] rendered (premultiplied) normal, camera axes
    alpha: Tensor,  # [H, W]
    target: Tensor,  # [H, W, C] the reference window's observed image
    valid: Tensor,  # [H, W] bool
    cam: Camera,  # the reference window's camera
    neighbours: list[tuple[Camera, Tensor]],  # (camera, observed image [H', W', C]) of a few neighbours
    gen: torch.Generator,
    n_pixels: int = 4096,
    radius_px: int = 2,
    min_alpha: float = 0.5,
) -> Tensor:
    """Mean over sampled pixels of 1 − NCC between the reference's observed patch and each
    neighbour's observed image sampled through the rendered plane (the best neighbour per pixel).
    Pixels near the window border, with alpha < ``min_alpha``, invalid, or with a flat reference
    patch do not count."""
    h, w = alpha.shape
    r = radius_px
    if h <= 2 * r or w <= 2 * r or not neighbours:
        return depth_premult.sum() * 0.0
    inner = torch.zeros_like(valid)
    inner[r : h - r, r : w - r] = True
    cand = (inner & valid & (alpha > min_alpha)).reshape(-1).nonzero()[:, 0]
    if cand.numel() == 0:
        return depth_premult.sum() * 0.0
    if cand.numel() > n_pixels:
        cand = cand[torch.randperm(cand.numel(), generator=gen)[:n_pixels]]
    rows, cols = cand // w, cand % w
    a = alpha[rows, cols].clamp_min(1e-6)
    depth = depth_premult[rows, cols] / a  # [N]
    normal = normal_premult[rows, cols]
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)  # [N, 3]
    xy = torch.stack([cols, rows], -1).to(depth.dtype) + 0.5  # [N, 2]
    offs = patch_offsets(r).to(depth.dtype)
    ref_patch = target[(rows[:, None] + offs[None, :, 1].long()), (cols[:, None] + offs[None, :, 0].long())]  # [N, P, C]
    costs = []
    for nbr_cam, nbr_img in neighbours:
        rot, trans = relative_pose(cam, nbr_cam)
        uv, z = plane_warp(xy, depth, normal, offs, cam.K.to(depth.dtype), nbr_cam.K.to(depth.dtype), rot, trans)
        vals, inside = sample_image(nbr_img.to(depth.dtype), uv)
        ncc, var = patch_ncc(ref_patch, vals)
        ok = inside.all(1) & (z > 0).all(1)
        costs.append(torch.where(ok, 1.0 - ncc, torch.full_like(ncc, float("inf"))))
    best = torch.stack(costs).min(0).values  # [N]
    keep = torch.isfinite(best) & (var > 1e-8 * offs.shape[0])
    if not bool(keep.any()):
        return depth_premult.sum() * 0.0
    return best[keep].mean()


class MultiView:
    """What the loss needs beyond the batch: each training frame's neighbour frames and the run's
    image stores (``images(kind).get(frame)`` -> observed image [H, W, C], valid mask)."""

    def __init__(self, table: dict[int, list[int]], images, cameras: list[Camera], per_step: int = 2):
        self.table, self.images, self.cameras, self.per_step = table, images, cameras, per_step

    def neighbours(self, frame: int, kind: str, gen: torch.Generator) -> list[tuple[Camera, Tensor]]:
        """``per_step`` of the frame's neighbours, drawn from ``gen``, with their observed images
        from the store ``kind`` (that of the batch's target, so that the channels match)."""
        nb = self.table.get(int(frame), [])
        if not nb:
            return []
        pick = torch.randperm(len(nb), generator=gen)[: self.per_step].tolist()
        return [(self.cameras[nb[j]], self.images(kind).get(nb[j])[0]) for j in pick]


def view_neighbour_table(cameras: list[Camera], train_indices: list[int], k: int = 4) -> dict[int, list[int]]:
    """For each training frame, its ``k`` training neighbours with the closest viewing direction
    (from the cameras' mean look-at point, approximated by the centre of their centres projected
    along their axes)."""
    cen = np.stack([cameras[i].centre.numpy().astype(np.float64) for i in train_indices])
    fwd = np.stack([cameras[i].viewmat.numpy()[2, :3].astype(np.float64) for i in train_indices])  # optical axes
    # the point closest to all optical axes (least squares): sum (I - f fᵀ) (p - c) = 0
    a = sum(np.eye(3) - np.outer(f, f) for f in fwd)
    b = sum((np.eye(3) - np.outer(f, f)) @ c for f, c in zip(fwd, cen))
    target = np.linalg.lstsq(a, b, rcond=None)[0]
    table = view_neighbours(cen, target, k)
    return {train_indices[i]: [train_indices[j] for j in nb] for i, nb in enumerate(table)}
