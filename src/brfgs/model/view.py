"""The one render path: a trained model and a camera -> latent, reflectance cube, CIR, alpha,
depth and normal maps.

:func:`render` is what evaluation, ``brfgs render``, ``brf``, ``products``, ``export``, the
benchmarks and the viewer call. Per Gaussian it evaluates the appearance head for the sun (paper
eq. 12; :mod:`brfgs.model.features`), rasterizes (premultiplied, :func:`brfgs.render.rasterize`),
composites the learned background with (1 − α) and decodes with the spectral decoder D_φ in the
model's decode order (:class:`brfgs.model.trained.RenderSettings`):

- ``"gaussian"`` — eq. 13 as published: r_k = D_φ(z_k(ω_i, ω_o)) per Gaussian, then the spectra
  are alpha-blended (B channels rasterized);
- ``"pixel"`` — the latents are alpha-blended and each pixel decoded, D_φ(Σ_k w_k z_k) (d
  channels rasterized). With a nonlinear decoder the two differ; with a linear basis
  (D(z) = W z + b) they are the same, and :func:`render` always blends latents.

Training uses the same pieces (:mod:`brfgs.model.rendering`) with gradients.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from brfgs.brdf.geometry import gaussian_normals, view_directions
from brfgs.data.angles import angles_from_direction
from brfgs.data.cir import cir_composite
from brfgs.model.camera import Camera
from brfgs.model.rendering import (FeaturesFn, composite_background, decode_image, frustum_subset,
                                   rasterize_splats)
from brfgs.model.shadows import pixel_visibility, sun_sky_light
from brfgs.model.trained import TrainedModel
from brfgs.spectral.decoders import is_linear
from brfgs.render import RenderOutput


@dataclass
class RenderedView:
    """One rendered view (numpy planes unless said otherwise).

    image: raw premultiplied features [H, W, C] (torch); latent: background-composited latent
    [H, W, d] (None for custom features, the CIR variant or decode order "gaussian"); cube: reflectance [H, W, B] (None
    unless decoded); cir: CIR composite [H, W, 3] in [0, 1]-ish (None unless decoded, or always for
    the CIR variant); alpha [H, W]; depth [H, W] (m along the optical axis, 0 where nothing);
    normal [H, W, 3] (unit, world, facing the camera, 0 where α = 0; None unless asked);
    sun_lit [H, W]: a model trained with shadows, the blended direct-sun visibility of the latent's
    pixels (background lit): the spectra decoded from ``latent`` times (1 − f_b) sun_lit + f_b
    (:func:`brfgs.model.shadows.sun_sky_light`) are ``cube`` (None otherwise).
    """

    image: Tensor
    alpha: np.ndarray
    depth: np.ndarray
    latent: np.ndarray | None = None
    cube: np.ndarray | None = None
    cir: np.ndarray | None = None
    normal: np.ndarray | None = None
    sun_lit: np.ndarray | None = None
    timings_s: dict = field(default_factory=dict)


def _rasterize_subset(model: TrainedModel, cam: Camera, features: FeaturesFn, want_normals: bool, cull: bool,
                      backend: str) -> RenderOutput:
    """Rasterize ``features`` of the Gaussians that can touch ``cam`` (all when not ``cull``)."""
    f = model.frozen()
    means = f["means"]
    idx = frustum_subset(means, f["max_scale"], cam) if cull else torch.arange(means.shape[0])
    omega_o = view_directions(means[idx], cam.centre)  # [n, 3]
    feats = features(idx, omega_o).to(means.dtype).contiguous()  # [n, C]
    normals = gaussian_normals(f["quats"][idx], f["scales"][idx], omega_o).contiguous() if want_normals else None
    if idx.numel() == 0:
        z = torch.zeros(cam.height, cam.width)
        return RenderOutput(torch.zeros(cam.height, cam.width, feats.shape[1]), z, z.clone(),
                            torch.zeros(cam.height, cam.width, 3) if want_normals else None, {"backend": "none"})
    return rasterize_splats(means[idx].contiguous(), f["quats"][idx].contiguous(), f["scales"][idx].contiguous(),
                            f["opacities"][idx].contiguous(), feats, cam, backend, model.render_settings.antialias,
                            normals, supersample=model.render_settings.supersample)


def _unit_normals(normal: Tensor | None) -> np.ndarray | None:
    """Blended normals [H, W, 3] scaled to unit length (0 where nothing was hit)."""
    if normal is None:
        return None
    n = normal.numpy().astype(np.float64)
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(nn > 1e-8, n / np.maximum(nn, 1e-12), 0.0).astype(np.float32)


def sky_share(model: TrainedModel, diffuse_fraction=None, omega_i: Tensor | None = None) -> Tensor:  # [B] float32
    """f_b to light a shadowed model's spectra with: ``diffuse_fraction`` (one number or one per band:
    the sky of the frame rendered, e.g. another flight's), else the model's own for the sun ω_i [3]
    (:meth:`TrainedModel.diffuse_fraction`; default the acquisition's sun)."""
    if diffuse_fraction is None:
        z = None if omega_i is None else math.degrees(float(angles_from_direction(omega_i.double())[0]))
        return model.diffuse_fraction(z)
    f = torch.as_tensor(np.asarray(diffuse_fraction, np.float64), dtype=torch.float32)
    return f.expand(len(model.wavelengths_nm)).contiguous() if f.ndim == 0 else f


def spectral_features(model: TrainedModel, omega_i: Tensor, order: str | None = None,
                      backend: str = "auto", diffuse_fraction=None) -> FeaturesFn:
    """Per-Gaussian features whose rendering gives the model's spectra for the sun ω_i [3]:
    latents [n, d] (decode order "pixel") or decoded spectra [n, B] ("gaussian", eq. 13). A model
    trained with shadows adds each Gaussian's direct-sun visibility V as a last channel (order
    "pixel") or multiplies its spectrum by the illumination (1 − f_b) V + f_b ("gaussian"; f_b
    :func:`sky_share`)."""
    order = order or model.render_settings.decode_order
    vis = model.sun_visibility_toward(omega_i, backend) if model.shadowed else None  # [N]
    f_b = sky_share(model, diffuse_fraction, omega_i) if model.shadowed else None  # [B]

    def features(idx: Tensor, omega_o: Tensor) -> Tensor:
        lat = model.gaussian_latent(omega_i, omega_o, idx)  # [n, d]
        if order == "gaussian":
            spec = decode_image(model.decoder, lat)  # [n, B]
            return spec if vis is None else spec * sun_sky_light(f_b, vis[idx].to(spec.dtype))
        return lat if vis is None else torch.cat([lat, vis[idx, None].to(lat.dtype)], 1)

    return features


def split_light(model: TrainedModel, image: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor | None]:
    """A rendered image of :func:`spectral_features` in order "pixel" [..., C] as (latents [..., d], the
    pixel's direct-sun visibility [...] with the background lit, or None for a model without shadows)."""
    if not model.shadowed:
        return image, None
    return image[..., :-1], pixel_visibility(image[..., -1], alpha)


@torch.no_grad()
def pixel_spectra(model: TrainedModel, image: Tensor, alpha: Tensor, order: str | None = None,
                  diffuse_fraction=None) -> np.ndarray:
    """Reflectance [..., B] of rendered pixels ``image`` [..., C] (premultiplied features of
    :func:`spectral_features`) with coverage ``alpha`` [...]: the background composited, then
    decoded per pixel and lit under the sky ``diffuse_fraction`` (order "pixel"; default the model's at its
    acquisition's sun: pass :func:`sky_share` of the sun the features were rendered for),
    or the decoded background spectrum composited ("gaussian")."""
    order = order or model.render_settings.decode_order
    bg = model.bg_latent
    if order == "gaussian":
        bg_spec = None if bg is None else decode_image(model.decoder, bg.to(image.dtype)[None])[0]  # [B]
        return composite_background(image, alpha, bg_spec).numpy().astype(np.float32)
    lat, vis = split_light(model, image, alpha)
    return _lit(model, _decode_hits(model, composite_background(lat, alpha, bg), alpha), vis, diffuse_fraction)


def _lit(model: TrainedModel, cube: np.ndarray, vis: Tensor | None, diffuse_fraction=None) -> np.ndarray:
    """``cube`` [..., B] times the sun and sky illumination of the pixels' visibility ``vis`` [...] (None: as is)
    under the sky ``diffuse_fraction`` (:func:`sky_share`)."""
    if vis is None:
        return cube
    cube *= sun_sky_light(sky_share(model, diffuse_fraction), vis.float()).numpy()
    return cube


def _decode_hits(model: TrainedModel, latent: Tensor, alpha: Tensor) -> np.ndarray:
    """Decoded cube [..., B] of latents [..., d]; pixels showing only the background share one
    decoded spectrum (a linear basis decodes every pixel: one product per pixel costs less than the copies)."""
    bg = model.bg_latent
    hit = alpha > 0
    if bg is None or is_linear(model.decoder) or bool(hit.all()):
        return decode_image(model.decoder, latent).numpy()
    bg_spec = decode_image(model.decoder, bg.to(latent.dtype)[None])[0].numpy()  # [B]
    cube = np.broadcast_to(bg_spec, tuple(latent.shape[:-1]) + bg_spec.shape).copy()
    if bool(hit.any()):
        cube[hit.numpy()] = decode_image(model.decoder, latent[hit]).numpy()
    return cube


@torch.no_grad()
def render(
    model: TrainedModel,
    cam: Camera,
    *,
    sun_zenith_deg: float | None = None,
    sun_azimuth_deg: float | None = None,
    features: FeaturesFn | None = None,
    decode: bool = True,
    normals: bool = False,
    cull: bool = True,
    backend: str = "auto",
    decode_order: str | None = None,
    diffuse_fraction=None,
) -> RenderedView:
    """Render ``model`` from ``cam`` under a sun (default: the acquisition's).

    With ``features`` None the appearance head's latent is rendered, the learned background
    composited, and (``decode``) decoded to reflectance in the model's decode order (or
    ``decode_order``: "pixel" | "gaussian", see the module docstring) and the CIR composite
    formed; the CIR variant renders its CIR colours directly. With ``features(idx, omega_o) -> [n, C]``
    any per-Gaussian quantity (kernel contributions, NBAR latents, ...) is rasterized instead
    and returned raw in ``image``. A model trained with shadows is lit under the sky
    ``diffuse_fraction`` (one number or one per band: e.g. another flight's frame; default the
    model's for this sun, :func:`sky_share`). ``cull`` drops Gaussians that cannot touch the image first
    (same image, less work). A model with a linear spectral basis blends latents in either order
    (the same spectra, :class:`brfgs.model.trained.RenderSettings`).
    """
    t0 = time.perf_counter()
    omega_i = model.sun_direction(sun_zenith_deg, sun_azimuth_deg)  # [3]
    custom = features is not None
    order = "pixel" if not model.spectral else (decode_order or model.render_settings.decode_order)
    if order not in ("pixel", "gaussian"):
        raise ValueError(f"decode_order must be pixel or gaussian, got {order!r}")
    if is_linear(model.decoder):
        order = "pixel"  # affine decoding: blending latents gives the spectra of blending decoded Gaussians
    by_gaussian = not custom and decode and order == "gaussian"
    if model.shadowed and not custom:  # the sky of this sun (or the one given), for every path below
        diffuse_fraction = sky_share(model, diffuse_fraction, omega_i)
    if not custom:
        features = spectral_features(model, omega_i, "gaussian" if by_gaussian else "pixel", backend,
                                     diffuse_fraction) \
            if model.spectral else (lambda idx, omega_o: model.gaussian_latent(omega_i, omega_o, idx))
    out = _rasterize_subset(model, cam, features, normals, cull, backend)
    t1 = time.perf_counter()
    rv = RenderedView(image=out.image, alpha=out.alpha.numpy(), depth=out.depth.numpy(), normal=_unit_normals(out.normal))
    if by_gaussian:
        rv.cube = pixel_spectra(model, out.image, out.alpha, "gaussian")
        rv.cir = cir_composite(rv.cube, model.cir_indices, model.cir_scale)
    elif not custom and model.spectral:
        rv.image, vis = split_light(model, out.image, out.alpha)
        rv.sun_lit = None if vis is None else vis.numpy()
        latent = composite_background(rv.image, out.alpha, model.bg_latent)  # [H, W, d]
        rv.latent = latent.numpy().astype(np.float32, copy=False)  # a view of the float32 planes: no copy
        if decode:
            rv.cube = _lit(model, _decode_hits(model, latent, out.alpha), vis, diffuse_fraction)
            rv.cir = cir_composite(rv.cube, model.cir_indices, model.cir_scale)
    elif not custom:  # CIR variant: SH colours on the CIR composite
        rv.cir = composite_background(out.image, out.alpha, model.extra.get("bg_colors")).clamp(0, 1).numpy()
    rv.timings_s = {"rasterize_s": t1 - t0, "decode_s": time.perf_counter() - t1, "total_s": time.perf_counter() - t0}
    return rv


@torch.no_grad()
def sun_visibility_map(model: TrainedModel, cam: Camera, visibility: Tensor, backend: str = "auto",
                       min_alpha: float = 0.1) -> np.ndarray:  # [H, W] float32
    """The view's sun visibility: Gaussian visibilities ``visibility`` [N] (e.g.
    :meth:`TrainedModel.sun_visibility`) blended by ``cam``'s weights and divided by its opacity;
    NaN where the opacity is below ``min_alpha``."""
    vis = visibility.to(model.frozen()["means"].dtype)
    rv = render(model, cam, features=lambda idx, omega_o: vis[idx][:, None], decode=False, backend=backend)
    a = rv.alpha.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(a >= min_alpha, rv.image[..., 0].numpy().astype(np.float64) / a, np.nan)
    return np.clip(out, 0.0, 1.0).astype(np.float32)
