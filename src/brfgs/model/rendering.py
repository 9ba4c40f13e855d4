"""The pieces of the render path, shared by rendering and training: rasterize per-Gaussian features
for a camera (:func:`rasterize_splats`, :func:`rasterize_features`), composite the learned background
with (1 − α) (:func:`composite_background`), decode latents to reflectance (paper eq. 13,
:func:`decode_image`) and cull to the view frustum (:func:`frustum_subset`).

:func:`brfgs.model.view.render` puts them together for a trained model.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor

from brfgs.spectral.decoders import is_linear
from brfgs.spectral.fast_decode import can_fast_decode, fast_decode
from brfgs.spectral.fast_linear import linear_decode
from brfgs.model.camera import Camera
from brfgs.model.gaussians import GaussianModel
from brfgs.render import RenderOutput, rasterize
from brfgs.render.rasterize import antialias_opacities
from brfgs.render.supersample import box_downsample, fine_intrinsics
from brfgs.render.geometry import project_pinhole

# features(idx [n] long, omega_o [n, 3]) -> [n, C]: per-Gaussian features of the Gaussians kept
FeaturesFn = Callable[[Tensor, Tensor], Tensor]


def rasterize_splats(
    means: Tensor,  # [N, 3] m
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3] m
    opacities: Tensor,  # [N]
    feats: Tensor,  # [N, C]
    cam: Camera,
    backend: str = "auto",
    antialiased: bool = False,
    normals: Tensor | None = None,  # [N, 3]
    absgrad: bool = False,
    supersample: int = 1,
) -> RenderOutput:
    """:func:`brfgs.render.rasterize` for ``cam``; with ``antialiased`` the opacities first get
    Mip-Splatting's compensation for the view (:func:`brfgs.render.rasterize.antialias_opacities`);
    ``absgrad``: also AbsGS's screen-space gradient (``meta["means2d"].absgrad``);
    ``supersample`` s > 1: each pixel the mean of s × s sub-pixel samples (a box integral over
    the pixel, :mod:`brfgs.render.supersample`)."""
    K, w, h = cam.K, cam.width, cam.height
    if supersample > 1:
        K, w, h = fine_intrinsics(K, supersample), w * supersample, h * supersample
    if antialiased:
        opacities = antialias_opacities(means, quats, scales, opacities, cam.viewmat, K, w, h)
    out = rasterize(means, quats, scales, opacities, feats, cam.viewmat, K, w, h,
                    backend=backend, normals=normals, absgrad=absgrad)
    return box_downsample(out, supersample)


def rasterize_features(
    model: GaussianModel,
    feats: Tensor,  # [N, C]
    cam: Camera,
    backend: str = "auto",
    antialiased: bool = False,
    absgrad: bool = False,
    supersample: int = 1,
) -> RenderOutput:
    """Rasterize ``feats`` for ``cam``: image [H, W, C] (premultiplied), alpha [H, W], depth, meta."""
    return rasterize_splats(model.means, model.quats, model.scales, model.opacities, feats, cam, backend, antialiased,
                            absgrad=absgrad, supersample=supersample)


def composite_background(
    image: Tensor,  # [H, W, C] premultiplied
    alpha: Tensor,  # [H, W]
    bg: Tensor | None,  # [C]
) -> Tensor:  # [H, W, C]
    """image + (1 - alpha) * bg for a premultiplied render."""
    if bg is None:
        return image
    return image + (1.0 - alpha)[..., None] * bg


def decode_image(decoder, latent: Tensor, chunk: int = 1 << 16) -> Tensor:
    """Decode latent vectors [..., d] to reflectance [..., B] pixel by pixel (eq. 13). A linear basis:
    one matrix product per pixel (:func:`brfgs.spectral.fast_linear.linear_decode`, differentiable in the
    latent and the basis). The autoencoder: through :func:`brfgs.spectral.fast_decode.fast_decode` when its
    weights need no gradient (a frozen or loaded decoder), else through ``decoder.decode`` (the reference)
    in chunks of ``chunk`` vectors (the decoder is per pixel: chunking does not change the result)."""
    shape, d = latent.shape[:-1], latent.shape[-1]
    flat = latent.reshape(-1, d)
    if is_linear(decoder):
        return linear_decode(decoder, flat).reshape(*shape, -1)
    if can_fast_decode(decoder, flat):                   # the fused kernels (same map, gradient to the latent)
        return fast_decode(decoder, flat).reshape(*shape, -1)
    if flat.shape[0] <= chunk:
        return decoder.decode(flat).reshape(*shape, -1)
    parts = [decoder.decode(flat[i : i + chunk]) for i in range(0, flat.shape[0], chunk)]
    return torch.cat(parts, 0).reshape(*shape, -1)


def frustum_subset(
    means: Tensor,  # [N, 3] m
    max_scale: Tensor,  # [N] m, largest standard deviation
    cam: Camera,
    margin_sigma: float = 3.0,
) -> Tensor:  # [n] long
    """Indices of Gaussians that can touch the image: in front of the camera and within the image
    grown by ``margin_sigma`` × their largest scale (a superset of what the rasterizer keeps).
    Gaussians straddling the camera plane cannot be projected reliably; 3DGS drops them too."""
    uv, z = project_pinhole(means, cam.viewmat.to(means.dtype), cam.K.to(means.dtype))  # [N, 2], [N]
    zs = z.clamp_min(1e-6)
    r = margin_sigma * max_scale
    ru = cam.K[0, 0] * r / zs + 2.0
    rv = cam.K[1, 1] * r / zs + 2.0
    u, v = uv[:, 0], uv[:, 1]
    ok = (z > 0.01) & (u + ru >= 0) & (u - ru <= cam.width) & (v + rv >= 0) & (v - rv <= cam.height)
    return torch.nonzero(ok).squeeze(1)


