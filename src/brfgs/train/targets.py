"""Per-Gaussian targets from the training images: what initialises colours and heads."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from brfgs.data.cameras import pixel_rays, project_points
from brfgs.model import GaussianModel
from brfgs.model.camera import Camera
from brfgs.model.rendering import rasterize_splats
from brfgs.render.geometry import project_pinhole
from brfgs.train.images import ImageStore


@torch.no_grad()
def projected_targets(model: GaussianModel, store: ImageStore, cams: list[Camera], indices: list[int]) -> Tensor:
    """Mean observed target [N, C] at each Gaussian centre over the views ``indices`` (no
    occlusion test); Gaussians no view sees get the mean over all."""
    means = model.means.detach()  # [N, 3]
    acc = None
    cnt = torch.zeros(means.shape[0])
    for i in indices:
        img, valid = store.get(i)
        cam = cams[i]
        uv, z = project_pinhole(means, cam.viewmat, cam.K)  # [N, 2], [N]
        ui, vi = torch.floor(uv[:, 0]).long(), torch.floor(uv[:, 1]).long()
        ok = (z > 0) & (ui >= 0) & (vi >= 0) & (ui < cam.width) & (vi < cam.height)
        uic, vic = ui.clamp(0, cam.width - 1), vi.clamp(0, cam.height - 1)
        ok &= valid[vic, uic]
        vals = img[vic, uic]  # [N, C]
        if acc is None:
            acc = torch.zeros(means.shape[0], vals.shape[1])
        acc += vals * ok[:, None]
        cnt += ok
    mean_all = acc.sum(0) / cnt.sum().clamp_min(1)
    out = acc / cnt.clamp_min(1)[:, None]
    out[cnt == 0] = mean_all
    return out


def _blend_weighted_sums(model: GaussianModel, views, backend: str, antialiased: bool, supersample: int) -> Tensor:
    """Σ_p w_kp t_p [N, C] over the views ``views`` (an iterable of (camera, t [H, W, C])), w_kp the
    rendering weight of Gaussian k in pixel p: the gradient of Σ_p <image_p(f), t_p> in the features
    f, one rasterization and backward per view."""
    m = model
    means, quats, scales, opac = m.means.detach(), m.quats.detach(), m.scales.detach(), m.opacities.detach()
    acc = None
    for cam, t in views:
        f = torch.zeros(m.n, t.shape[-1], requires_grad=True)
        with torch.enable_grad():
            out = rasterize_splats(means, quats, scales, opac, f, cam, backend, antialiased, supersample=supersample)
            (out.image * t).sum().backward()
        acc = f.grad.clone() if acc is None else acc + f.grad
    return acc


def _with_fallback(res: Tensor, weight: Tensor, fallback) -> Tensor:
    """``res`` [N, C] with the rows whose blending weight ``weight`` [N] is below 1e-3 taken from
    ``fallback()`` [N, C] (Gaussians no view sees)."""
    weak = weight < 1e-3
    if weak.any():
        res[weak] = fallback()[weak]
    return res.detach()


def backprojected_targets(model: GaussianModel, store: ImageStore, cams: list[Camera], indices: list[int],
                          encode=None, backend: str = "auto", antialiased: bool = False,
                          supersample: int = 1) -> Tensor:
    """Per-Gaussian mean target [N, C] weighted by the rendering weights (occlusion-aware).

    For each view, d/df of sum_p <image_p(f), t_p> is sum_p w_kp t_p, so one rasterization +
    backward per view accumulates sum_p w_kp t_p and sum_p w_kp (an extra channel of ones); the
    ratio is the blending-weighted mean of the pixels Gaussian k contributes to. Targets pass
    through ``encode`` (e.g. the spectral encoder) first when given. Gaussians that no view sees
    fall back to the centre-projection mean (:func:`projected_targets`).
    """
    def views():
        for i in indices:
            for cam, img, valid in store.tiles(i, cams[i]):   # the whole view, or windows of a large one
                with torch.no_grad():
                    t = encode(img) if encode is not None else img
                yield cam, torch.cat([t * valid[..., None], valid[..., None].float()], -1)  # [H, W, C+1]

    acc = _blend_weighted_sums(model, views(), backend, antialiased, supersample)

    def fallback():
        out = projected_targets(model, store, cams, indices)
        if encode is not None:
            with torch.no_grad():
                out = encode(out)
        return out

    return _with_fallback(acc[:, :-1] / acc[:, -1:].clamp_min(1e-8), acc[:, -1], fallback)


def backprojected_reflectance(model: GaussianModel, store: ImageStore, cams: list[Camera], indices: list[int],
                              light_of, backend: str = "auto", antialiased: bool = False,
                              supersample: int = 1) -> Tensor:  # [N, B]
    """Per-Gaussian reflectance of the lit surface [N, B] from images taken under a known
    illumination ``light_of(i, cam) -> [h, w, B]`` of view ``i`` seen by ``cam`` (the view's camera or a
    window's; relative to the open sky): per band the
    least-squares fit of t_p ≈ ρ_k L_p over the pixels each Gaussian blends into, weighted by the
    blending weights, ρ_k = Σ_p w_kp L_p t_p / Σ_p w_kp L_p² (a shadowed pixel, L small, counts
    little: its ρ estimate t / L carries the noise divided by L). Gaussians that no view sees fall
    back to the centre-projection mean (:func:`projected_targets`)."""
    def views():
        for i in indices:
            for cam, img, valid in store.tiles(i, cams[i]):   # the whole view, or windows of a large one
                light = light_of(i, cam) * valid[..., None]  # [H, W, B]
                yield cam, torch.cat([torch.nan_to_num(img) * light, light * light], -1)  # [H, W, 2B]

    acc = _blend_weighted_sums(model, views(), backend, antialiased, supersample)
    b = acc.shape[1] // 2
    return _with_fallback(acc[:, :b] / acc[:, b:].clamp_min(1e-8), acc[:, b:].mean(1),
                          lambda: projected_targets(model, store, cams, indices))


def ground_footprints(scene, pts: np.ndarray, c2w: np.ndarray):
    """Where the training images see the ground: (xy [Q, 2] of their border rays on the plane at
    the points' median height, seen(xyz [M, 3]) -> bool [M]: inside at least one training image)."""
    z0 = float(np.median(pts[:, 2]))
    cover = []
    for i in scene.train_indices:
        o, d = pixel_rays(c2w[i], scene.intrinsics)
        border = np.concatenate([o[0], o[-1], o[:, 0], o[:, -1]]), np.concatenate([d[0], d[-1], d[:, 0], d[:, -1]])
        down = border[1][:, 2] < -1e-3
        t = (z0 - border[0][down, 2]) / border[1][down, 2]
        cover.append((border[0][down] + t[:, None] * border[1][down])[:, :2])
    cover = np.concatenate(cover, 0) if cover else np.zeros((0, 2))

    def seen(xyz: np.ndarray) -> np.ndarray:
        ok = np.zeros(xyz.shape[0], bool)
        for i in scene.train_indices:
            uv, depth = project_points(xyz, c2w[i], scene.intrinsics)
            uv, depth = np.asarray(uv), np.asarray(depth)
            ok |= (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < scene.width) & (uv[:, 1] < scene.height)
        return ok

    return cover, seen
