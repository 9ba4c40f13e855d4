"""One training step's forward pass and losses, as functions of the run state, a batch and
the options (paper eqs. 24–27 plus the geometry priors of :mod:`brfgs.train.losses`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from brfgs.model.camera import Camera
from brfgs.model.features import camera_depth_normals, gaussian_features, stage1_colors
from brfgs.model.shadows import pixel_visibility, sun_sky_light
from brfgs.model.rendering import (
    composite_background, decode_image, frustum_subset, rasterize_features, rasterize_splats,
)
from brfgs.render import RenderOutput
from brfgs.train.config import TrainConfig
from brfgs.train.images import TrainImages
from brfgs.train.losses import (depth_normal_loss, depth_smoothness_loss, flatten_loss, masked_psnr,
                                normal_smoothness_loss, spectral_tv_loss, stage1_loss, stage2_loss)
from brfgs.train.phases import Phase
from brfgs.train.dense_depth import dense_depth_loss
from brfgs.train.state import TrainState, head_config


@dataclass
class Batch:
    """One training view (or a window of it): camera, target [H, W, C], valid [H, W]."""

    index: int
    cam: Camera
    target: Tensor
    valid: Tensor
    window: tuple[int, int, int, int] | None  # x0, y0, w, h
    kind: str = "colors"  # the TrainImages store of the target: colors, full or cir


@dataclass
class StepResult:
    loss: Tensor
    psnr: float
    out: RenderOutput


def pick_view(state: TrainState, train_indices: list[int], width: int, height: int, cfg: TrainConfig,
              phase: Phase) -> tuple[int, tuple[int, int, int, int] | None]:
    """Next training view (epoch-wise permutation) and an optional patch window.

    Patches of ``patch_px`` for images larger than that (whole views otherwise, in every phase).
    """
    if not state.perm:
        state.perm = torch.randperm(len(train_indices), generator=state.gen).tolist()
    i = train_indices[state.perm.pop()]
    P = cfg.patch_px
    if P > 0 and width * height > P * P:
        pw, ph = min(P, width), min(P, height)
        x0 = int(torch.randint(0, width - pw + 1, (1,), generator=state.gen))
        y0 = int(torch.randint(0, height - ph + 1, (1,), generator=state.gen))
        return i, (x0, y0, pw, ph)
    return i, None


def make_batch(state: TrainState, images: TrainImages, phase: Phase, i: int, window) -> Batch:
    """The camera and target of view ``i`` for ``phase``, cropped to ``window`` (x0, y0, w, h)."""
    cam = state.cameras[i]
    kind = {Phase.STAGE1: "colors", Phase.CIR: "cir"}.get(phase, "full")
    if window is None:
        target, valid = images(kind).get(i)
    else:                   # the window alone (read from the file when the frame is not cached)
        cam = cam.crop(*window)
        target, valid = images(kind).get_window(i, window)
    return Batch(i, cam, target, valid, window, kind)


def neighbours(means: Tensor, k: int = 8) -> Tensor:  # [N, k] long
    """Indices of each Gaussian's k nearest other Gaussians (means [N, 3])."""
    n = means.shape[0]
    pts = means.detach().numpy()
    _, nbr = cKDTree(pts).query(pts, k=min(k, n - 1) + 1)
    return torch.as_tensor(np.asarray(nbr).reshape(n, -1)[:, 1:], dtype=torch.long)


def _features(state: TrainState, cfg: TrainConfig, phase: Phase, cam: Camera, i: int) -> Tensor:
    """Per-Gaussian features [N, C] the phase renders for training frame ``i`` (under its sun)."""
    if phase == Phase.STAGE1:
        return stage1_colors(state.gaussians, cam, state.sun_of(i))
    neural = state.neural if phase != Phase.CIR else None
    return gaussian_features(state.gaussians, cam, state.sun_of(i), head_config(cfg), neural, ref_sun=state.sun)


def geometry_regulariser(state: TrainState, cfg: TrainConfig, out: RenderOutput, n_feat: int, batch: Batch,
                         use_priors: bool, strategy=None) -> Tensor | None:
    """Flatness loss and the densification strategy's own prior plus, when ``use_priors``, the
    depth-normal, depth smoothness and dense-depth priors on the rendered geometry channels (None
    when all are off)."""
    c = cfg
    greg = c.lambda_flat * flatten_loss(state.gaussians["log_scales"]) if c.lambda_flat > 0 else None
    prior = strategy.regulariser(state.gaussians) if strategy is not None else None
    if prior is not None:
        greg = prior if greg is None else greg + prior
    if not use_priors:
        return greg
    geo = out.image[..., n_feat:]  # [H, W, 4] depth, normal
    terms = []
    if c.lambda_normal > 0:
        terms.append(c.lambda_normal * depth_normal_loss(geo[..., :4], out.alpha, batch.cam.K))
    if c.lambda_depth_smooth > 0:
        terms.append(c.lambda_depth_smooth * depth_smoothness_loss(geo[..., 0], out.alpha, batch.target, batch.valid))
    dense = state.dense_depth.target(batch.index, batch.cam, batch.window) if c.lambda_dense_depth > 0 and \
        state.dense_depth else None
    if dense is not None:
        terms.append(c.lambda_dense_depth * dense_depth_loss(geo[..., 0], out.alpha, dense))
    if terms:
        greg = sum(terms) if greg is None else greg + sum(terms)
    return greg


def _plus(loss: Tensor, reg: Tensor | None) -> Tensor:
    return loss if reg is None else loss + reg


def _spectral_loss(state: TrainState, cfg: TrainConfig, phase: Phase, lat: Tensor, batch: Batch,
                   greg: Tensor | None, gen: torch.Generator, light: Tensor | None = None) -> tuple[Tensor, float]:
    """Decode the latent image and score it on all bands (eqs. 25–27); stage 2 samples rays
    (drawn from ``gen``). ``light`` [H, W, B] (option shadows): the illumination the decoded
    spectra are multiplied by."""
    c = cfg
    h, w = lat.shape[:2]
    target, valid = batch.target, batch.valid
    if phase == Phase.STAGE2 and 0 < c.stage2_rays < h * w:
        # ray sampling: decode and score a random subset of the rendered pixels
        idx = torch.randperm(h * w, generator=gen)[: c.stage2_rays]
        flat_lat = lat.reshape(h * w, -1)  # [H·W, d]
        if c.lambda_spectral_tv > 0:  # the scored pixels' TV neighbours are decoded with them, once each
            spectra_at = _decode_once(state.decoder, flat_lat, idx, w, h)
        else:
            spectra_at = lambda q: decode_image(state.decoder, flat_lat[q])  # noqa: E731
        if light is not None:
            flat_light, unlit = light.reshape(h * w, -1), spectra_at
            spectra_at = lambda q: unlit(q) * flat_light[q]  # noqa: E731
        pred = spectra_at(idx) * _frame_gain(state, batch.index)  # [R, B]
        greg = _plus_irradiance_prior(state, cfg, batch.index, greg)
        tgt, val = target.reshape(h * w, -1)[idx], valid.reshape(-1)[idx]
        if c.lambda_spectral_tv > 0:
            tv = _spectral_tv(spectra_at, target, valid, idx, pred)
            greg = _plus(c.lambda_spectral_tv * tv, greg)
        return _plus(stage2_loss(pred, tgt, val, c.beta_cos), greg), masked_psnr(pred, tgt, val)
    spectra = decode_image(state.decoder, lat)
    return _score_spectra(state, cfg, phase, spectra if light is None else spectra * light, batch, greg)


def _neighbour_pairs(idx: Tensor, w: int, h: int) -> list[tuple[Tensor, Tensor]]:
    """For the right and the lower neighbour of the pixels ``idx`` [R] (flat indices of an
    [H, W] view): which of them have one inside the view (ok [R] bool) and its flat index [R_ok]."""
    y, x = idx // w, idx % w
    pairs = []
    for dy, dx in ((0, 1), (1, 0)):
        ok = (y + dy < h) & (x + dx < w)  # [R]
        pairs.append((ok, ((y + dy) * w + (x + dx))[ok]))
    return pairs


def _decode_once(decoder, flat_lat: Tensor, idx: Tensor, w: int, h: int):
    """Decode the latents ``flat_lat`` [H·W, d] of the pixels ``idx`` [R] and of their right and
    lower neighbours (:func:`_spectral_tv` needs them), each pixel once although the sets overlap;
    returns ``spectra_at(q [R']) -> [R', B]`` for any of them. The decoder works per pixel, so this
    is the same map as decoding each set apart."""
    need = torch.unique(torch.cat([idx] + [q for _, q in _neighbour_pairs(idx, w, h)]))  # [U] sorted
    spectra = decode_image(decoder, flat_lat[need])  # [U, B]
    return lambda q: spectra[torch.searchsorted(need, q)]


def _brightness(target: Tensor, valid: Tensor) -> tuple[Tensor, Tensor]:
    """The band-mean observed reflectance of each pixel of ``target`` [H, W, B] ([H, W]) and its
    mean over the ``valid`` [H, W] pixels (the spectral TV's edge scale)."""
    bright = torch.nan_to_num(target, nan=0.0).mean(-1)  # [H, W]
    return bright, bright[valid].mean().clamp_min(1e-6)


def _spectral_tv(spectra_at, target: Tensor, valid: Tensor, idx: Tensor, pred: Tensor) -> Tensor:
    """Edge-aware spectral-angle smoothness (:func:`spectral_tv_loss`) between the pixels ``idx``
    [R] (flat indices of the [H, W] view; their spectra ``pred`` [R, B]) and their right and lower
    neighbours, whose spectra ``spectra_at(q [R'])`` [R', B] gives."""
    h, w = target.shape[:2]
    bright, scale = _brightness(target, valid)
    bright, flat_valid = bright.reshape(-1), valid.reshape(-1)  # [H·W]
    terms = []
    for ok, q in _neighbour_pairs(idx, w, h):
        p = idx[ok]
        terms.append(spectral_tv_loss(pred[ok], spectra_at(q), bright[p], bright[q], flat_valid[p] & flat_valid[q], scale))
    return sum(terms) / len(terms)


def _spectral_tv_image(pred: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """:func:`_spectral_tv` of every pixel of ``pred`` [H, W, B] against its right and lower
    neighbour: the same pairs in the same order, taken as shifted slices of the image instead of
    gathered by index (whose backward is a scatter-add over the whole image, ~10× slower on a CPU)."""
    bright, scale = _brightness(target, valid)
    all_, head, tail = slice(None), slice(None, -1), slice(1, None)
    terms = []
    for p, q in (((all_, head), (all_, tail)), ((head, all_), (tail, all_))):  # right, lower neighbour
        terms.append(spectral_tv_loss(pred[p], pred[q], bright[p], bright[q], valid[p] & valid[q], scale))
    return sum(terms) / len(terms)


def _frame_gain(state: TrainState, i: int) -> Tensor | float:
    """The learned irradiance scale of training frame ``i`` (exp of its log), or 1 (option off)."""
    log_s = state.extra.get("log_irradiance")
    return 1.0 if log_s is None else torch.exp(log_s[i])


def _plus_irradiance_prior(state: TrainState, cfg: TrainConfig, i: int, greg: Tensor | None) -> Tensor | None:
    """``greg`` plus λ (log s_i)², the prior toward 1 of the learned irradiance scale of frame ``i``."""
    log_s = state.extra.get("log_irradiance")
    return greg if log_s is None else _plus(cfg.lambda_irradiance * log_s[i] ** 2, greg)


def _score_spectra(state: TrainState, cfg: TrainConfig, phase: Phase, pred: Tensor, batch: Batch,
                   greg: Tensor | None) -> tuple[Tensor, float]:
    """Loss of the reflectance image ``pred`` [H, W, B] (eqs. 25–27, + D-SSIM on the stage-1 bands
    when joint) and its PSNR."""
    pred = pred * _frame_gain(state, batch.index)
    greg = _plus_irradiance_prior(state, cfg, batch.index, greg)
    loss = stage2_loss(pred, batch.target, batch.valid, cfg.beta_cos)
    if phase == Phase.STAGE2 and cfg.lambda_spectral_tv > 0:  # every pixel against its neighbours
        loss = loss + cfg.lambda_spectral_tv * _spectral_tv_image(pred, batch.target, batch.valid)
    if phase == Phase.JOINT and cfg.alpha_dssim > 0:
        sel = state.stage1_bands()
        loss = loss + cfg.alpha_dssim * (stage1_loss(pred[..., sel], batch.target[..., sel], batch.valid, 1.0, cfg.dssim_per_band))
    return _plus(loss, greg), masked_psnr(pred, batch.target, batch.valid)


def supersample_now(cfg: TrainConfig, phase: Phase, step: int, phase_steps: int) -> int:
    """Sub-pixel samples per axis at ``step`` of ``phase``: 1 in a geometry phase before
    ``supersample_start`` of its ``phase_steps``, else ``cfg.supersample``."""
    if phase.grows and step < int(cfg.supersample_start * phase_steps):
        return 1
    return cfg.supersample


def _rasterize(state: TrainState, feats: Tensor, cam: Camera, backend: str, subset: Tensor | None,
               absgrad: bool, ss: int) -> RenderOutput:
    """Rasterize ``feats`` [N or n, C] of all Gaussians, or of the rows ``subset`` [n], each pixel the
    mean of ``ss`` x ``ss`` sub-pixels; ``absgrad``: keep AbsGS's gradient for the densification
    (``meta["means2d"].absgrad``)."""
    g = state.gaussians
    aa = state.cfg.antialias
    if subset is None:
        return rasterize_features(g, feats, cam, backend, antialiased=aa, absgrad=absgrad, supersample=ss)
    return rasterize_splats(g.means[subset], g.quats[subset], g.scales[subset], g.opacities[subset], feats, cam,
                            backend, aa, supersample=ss)


def _decoded_features(state: TrainState, phase: Phase, lat: Tensor, cam: Camera) -> tuple[Tensor, Tensor | None]:
    """Eq. 13 as published: each Gaussian's latent decoded to its spectrum, ([n, B], subset [n] or
    None). With geometry frozen (stage 2) only the Gaussians that can touch the view are decoded."""
    subset = None
    if not phase.trains_geometry:
        g = state.gaussians
        with torch.no_grad():
            subset = frustum_subset(g.means.detach(), g.scales.detach().max(1).values, cam)
        lat = lat[subset]
    return decode_image(state.decoder, lat), subset  # [n, B]


def forward(state: TrainState, cfg: TrainConfig, phase: Phase, batch: Batch, phase_steps: int,
            nbrs: Tensor | None = None, gen: torch.Generator | None = None, strategy=None) -> StepResult:
    """Render ``batch`` for ``phase`` and compute its loss (with the phase's regularisers).

    ``phase_steps``: steps of the phase (the surface priors start at ``normal_start`` of it);
    ``nbrs`` [N, 8]: neighbour indices for the stage-2 normal smoothness (when it is on).
    With decode order "gaussian" the spectral phases blend decoded spectra (eq. 13), else
    latents decoded per pixel. ``strategy``: the densification strategy of a growing phase (its
    own prior joins the loss).
    """
    c = cfg
    surf = c.lambda_normal > 0 or c.lambda_depth_smooth > 0 or c.lambda_dense_depth > 0
    # the surface priors start at normal_start of a geometry phase
    use_priors = phase.trains_geometry and surf and state.step >= int(c.normal_start * phase_steps)
    feats = _features(state, cfg, phase, batch.cam, batch.index)
    by_gaussian = c.decode == "gaussian" and phase.fits_head
    vis = state.sun_visibility(batch.index) if c.shadows and phase == Phase.STAGE2 else None  # [N]
    subset = None
    if by_gaussian:
        feats, subset = _decoded_features(state, phase, feats, batch.cam)
        if vis is not None:  # each Gaussian's spectrum under its own light
            feats = feats * sun_sky_light(state.diffuse_fraction(batch.index), vis if subset is None else vis[subset])
    elif vis is not None:  # the visibility as a last channel, blended like the latents
        feats = torch.cat([feats, vis[:, None].to(feats.dtype)], -1)
    n_feat = feats.shape[-1]
    if use_priors:  # depth + normal channels for the surface priors
        feats = torch.cat([feats, camera_depth_normals(state.gaussians, batch.cam)], -1)
    out = _rasterize(state, feats, batch.cam, c.backend, subset, absgrad=strategy is not None and strategy.absgrad,
                     ss=supersample_now(c, phase, state.step, phase_steps))
    image = out.image[..., :n_feat]
    greg = geometry_regulariser(state, cfg, out, n_feat, batch, use_priors, strategy) if phase.trains_geometry else None
    if phase.renders_colors:
        pred = composite_background(image, out.alpha, state.extra["bg_colors"])
        loss = stage1_loss(pred, batch.target, batch.valid, c.alpha_dssim, c.dssim_per_band)
        return StepResult(_plus(loss, greg), masked_psnr(pred, batch.target, batch.valid), out)
    if phase == Phase.STAGE2 and c.lambda_normal_smooth > 0 and "normals" in state.gaussians:
        greg = c.lambda_normal_smooth * normal_smoothness_loss(state.gaussians["normals"], nbrs)
    if by_gaussian:
        bg = decode_image(state.decoder, state.extra["bg_latent"][None])[0]  # [B]
        loss, psnr = _score_spectra(state, cfg, phase, composite_background(image, out.alpha, bg), batch, greg)
    else:
        light = None
        if vis is not None:  # the pixel's blended visibility, the background lit
            vis_pix = pixel_visibility(image[..., -1], out.alpha)  # [H, W]
            image, light = image[..., :-1], sun_sky_light(state.diffuse_fraction(batch.index), vis_pix)
        lat = composite_background(image, out.alpha, state.extra["bg_latent"])
        loss, psnr = _spectral_loss(state, cfg, phase, lat, batch, greg, state.gen if gen is None else gen, light)
    return StepResult(loss, psnr, out)
