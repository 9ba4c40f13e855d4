"""Rendering a :class:`GaussianModel` for one camera: appearance head -> rasterizer -> decoder.

Stage 1 renders the per-Gaussian reflectance of the selected bands (``colors``).
Stage 2 renders the latent z_k(omega_i, omega_o) of every Gaussian (paper eq. 12, via
:func:`brfgs.brdf.head.evaluate_head`) to a latent image [H, W, d] and decodes each pixel
with the spectral decoder D_phi (eq. 13) to a reflectance cube [H, W, B].
The background (where accumulated opacity < 1) is a learned vector in the rendered space.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from brfgs.model.gaussians import GaussianModel


@dataclass
class Camera:
    """One pinhole camera: world-to-camera ``viewmat`` [4,4] (OpenCV axes), ``K`` [3,3], size, centre [3]."""

    name: str
    viewmat: torch.Tensor
    K: torch.Tensor
    width: int
    height: int
    centre: torch.Tensor

    def crop(self, x0: int, y0: int, w: int, h: int) -> "Camera":
        """The camera seeing only the pixel window [x0, x0+w) x [y0, y0+h) (principal point shifted)."""
        K = self.K.clone()
        K[0, 2] -= x0
        K[1, 2] -= y0
        return Camera(self.name, self.viewmat, K, int(w), int(h), self.centre)


def camera_from_c2w(name: str, c2w_gl: np.ndarray, K: np.ndarray, width: int, height: int) -> Camera:
    """Camera from an OpenGL camera-to-world matrix (conventions.md) and intrinsics."""
    from brfgs.data.cameras import viewmat_from_c2w

    c2w = np.asarray(c2w_gl, np.float64)
    vm = viewmat_from_c2w(c2w)
    return Camera(
        name,
        torch.as_tensor(np.asarray(vm), dtype=torch.float32),
        torch.as_tensor(np.asarray(K), dtype=torch.float32),
        int(width),
        int(height),
        torch.as_tensor(c2w[:3, 3], dtype=torch.float32),
    )


class NeuralHead(nn.Module):
    """MS-Splatting-style baseline: per-Gaussian feature f_k + view direction -> MLP -> latent.

    z_k = f_k + MLP([f_k, omega_o, cos(phase)]) (last layer zero-initialised, so a fresh
    head is view-independent). Shared across Gaussians; output in the autoencoder's latent space.
    """

    def __init__(self, dim: int, hidden: int = 64):
        super().__init__()
        self.dim = dim
        self.hidden = hidden
        self.net = nn.Sequential(nn.Linear(dim + 4, hidden), nn.GELU(), nn.Linear(hidden, hidden), nn.GELU(), nn.Linear(hidden, dim))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, feat: torch.Tensor, omega_o: torch.Tensor, omega_i: torch.Tensor) -> torch.Tensor:
        cos_phase = (omega_o * omega_i).sum(-1, keepdim=True)  # [N,1]
        return feat + self.net(torch.cat([feat, omega_o, cos_phase], -1))


def view_dirs(means: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """omega_o [N, 3]: unit vectors from each Gaussian toward the camera centre (conventions.md)."""
    d = centre[None, :].to(means.dtype) - means
    return d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def gaussian_features(
    model: GaussianModel,
    cam: Camera,
    sun_dir: torch.Tensor,
    head_cfg,
    neural: NeuralHead | None = None,
    what: str = "latent",
) -> torch.Tensor:
    """Per-Gaussian features [N, C] to rasterize for ``cam``.

    what="colors": stage-1 selected-band reflectance [N, k]; "latent": the appearance head
    (hybrid/SH in latent space, SH on CIR for the "cir" variant, or the neural head).
    """
    if what == "colors":
        return stage1_colors(model, cam)
    means = model.means
    omega_o = view_dirs(means, cam.centre)
    if model.appearance == "neural":
        assert neural is not None
        return neural(model["feat"], omega_o, sun_dir.expand_as(omega_o))
    from brfgs.brdf.head import evaluate_head

    normals = None
    if head_cfg.needs_normals:
        from brfgs.brdf.geometry import shading_normals

        normals = shading_normals(model.quats, model.scales, omega_o, model.params.get("normals"))
    params = {k: v for k, v in model.params.items() if k in ("z_iso", "z_vol", "z_geo", "z_spec", "rho_raw", "sh", "color")}
    if getattr(model, "centred", False) and head_cfg.kind == "hybrid":
        return centred_hybrid_latent(model, head_cfg, normals, sun_dir, omega_o)
    return evaluate_head(head_cfg, params, normals, sun_dir, omega_o)


def stage1_colors(model: GaussianModel, cam: Camera) -> torch.Tensor:
    """Stage-1 reflectance of the selected bands [N, k] for ``cam``: ``colors`` plus, when the model
    has ``colors_rest`` [N, s, k], the SH rest terms Σ_j Y_j(ω_o) · rest_j (degree 1–3, 3DGS style)."""
    col = model["colors"]
    if "colors_rest" not in model:
        return col
    from brfgs.brdf.sh import sh_basis

    rest = model["colors_rest"]  # [N, s, k]
    degree = {3: 1, 8: 2, 15: 3}[rest.shape[1]]
    basis = sh_basis(degree, view_dirs(model.means, cam.centre))[:, 1:]  # [N, s]
    return col + (basis[:, :, None] * rest).sum(1)


def camera_depth_normals(model: GaussianModel, cam: Camera) -> torch.Tensor:
    """Per-Gaussian geometry features [N, 4] for ``cam``: camera-space depth (m along the optical
    axis) and the unit normal (:func:`brfgs.brdf.geometry.gaussian_normals`, facing the camera)
    in camera axes (OpenCV: x right, y down, z forward).

    Rasterized and divided by alpha they give the expected depth and normal maps used by the
    depth-normal consistency loss (:func:`brfgs.train.losses.depth_normal_loss`).
    """
    from brfgs.brdf.geometry import gaussian_normals

    means = model.means
    vm = cam.viewmat.to(means.dtype)  # [4, 4] world -> camera
    n_world = gaussian_normals(model.quats, model.scales, view_dirs(means, cam.centre))  # [N, 3]
    n_cam = n_world @ vm[:3, :3].T  # [N, 3]
    return torch.cat([camera_depth(model, cam)[:, None], n_cam], -1)


def camera_depth(model: GaussianModel, cam: Camera) -> torch.Tensor:
    """Camera-space depth [N] (m along the optical axis) of every Gaussian centre for ``cam``."""
    vm = cam.viewmat.to(model.means.dtype)  # [4, 4] world -> camera
    return model.means @ vm[2, :3] + vm[2, 3]


def camera_depth_squared(model: GaussianModel, cam: Camera) -> torch.Tensor:
    """Per-Gaussian squared camera-space depth t² [N, 1] (m²) for ``cam``; rasterized next to the
    depth of :func:`camera_depth_normals` it gives the ray-wise depth variance
    (:func:`brfgs.train.losses.depth_concentration_loss`)."""
    depth = camera_depth(model, cam)  # [N]
    return (depth * depth)[:, None]


def kernel_reference(model: GaussianModel, head_cfg, sun_dir: torch.Tensor) -> dict[str, torch.Tensor]:
    """Kernel values {"vol","geo","spec": [N]} of every Gaussian for a nadir view (omega_o = +z)."""
    from brfgs.brdf.head import hybrid_kernels, roughness_from_raw

    up = torch.zeros_like(model.means)
    up[:, 2] = 1.0
    normals = None
    if head_cfg.needs_normals:
        from brfgs.brdf.geometry import shading_normals

        normals = shading_normals(model.quats, model.scales, up, model.params.get("normals"))
    rho = roughness_from_raw(model["rho_raw"], head_cfg.rho_min) if "rho_raw" in model else None
    return hybrid_kernels(normals, sun_dir.to(up.dtype), up, rho, head_cfg.components, head_cfg.normal_frame,
                          min_cos=head_cfg.min_cos, f0=head_cfg.f0)


def centred_hybrid_latent(model: GaussianModel, head_cfg, normals, sun_dir, omega_o) -> torch.Tensor:
    """Eq. 12 in the centred (NBAR-like) parametrisation used during training, [N, d]:

        z_k(omega_i, omega_o) = z'_iso + sum_j z_j (K_j(omega_i, omega_o) - K_j(omega_i, nadir))

    z'_iso is then the latent of a nadir view. Same function class as eq. 12 (the Li-Sparse
    kernel is about -1 at every geometry, which makes z_iso and z_geo nearly collinear in the
    plain form and slows Adam); :func:`uncentre` converts back to eq. 12 for saving.
    """
    from brfgs.brdf.head import hybrid_kernels, roughness_from_raw

    comps = head_cfg.components
    rho = roughness_from_raw(model["rho_raw"], head_cfg.rho_min) if "rho_raw" in model else None
    ks = hybrid_kernels(normals, sun_dir.to(omega_o.dtype), omega_o, rho, comps, head_cfg.normal_frame,
                        min_cos=head_cfg.min_cos, f0=head_cfg.f0)
    ref = kernel_reference(model, head_cfg, sun_dir)
    out = model["z_iso"] if "iso" in comps else None
    for c in ("vol", "geo", "spec"):
        if c not in comps:
            continue
        term = model[f"z_{c}"] * (ks[c] - ref[c]).unsqueeze(-1)
        out = term if out is None else out + term
    return out


@torch.no_grad()
def uncentre(model: GaussianModel, head_cfg, sun_dir: torch.Tensor) -> dict[str, torch.Tensor]:
    """Head tensors in the plain eq. 12 form: z_iso = z'_iso - sum_j z_j K_j(omega_i, nadir).

    Exact for the model's current geometry (the spec reference depends on n_k). Without the
    "iso" component the model is trained uncentred, so nothing changes.
    """
    out = {k: v.detach().clone() for k, v in model.params.items()}
    if "iso" not in head_cfg.components:
        return out
    ref = kernel_reference(model, head_cfg, sun_dir)
    for c in ("vol", "geo", "spec"):
        if c in head_cfg.components:
            out["z_iso"] -= model[f"z_{c}"].detach() * ref[c].unsqueeze(-1)
    return out


def rasterize_features(model: GaussianModel, feats: torch.Tensor, cam: Camera, backend: str = "auto"):
    """Rasterize ``feats [N, C]`` for ``cam``; returns the rasterizer's output (image [H,W,C], alpha, meta)."""
    from brfgs.render import rasterize

    return rasterize(
        model.means,
        model.quats,
        model.scales,
        model.opacities,
        feats,
        cam.viewmat,
        cam.K,
        cam.width,
        cam.height,
        backend=backend,
    )


def composite_background(image: torch.Tensor, alpha: torch.Tensor, bg: torch.Tensor | None) -> torch.Tensor:
    """image + (1 - alpha) * bg for a premultiplied render [H, W, C]."""
    if bg is None:
        return image
    return image + (1.0 - alpha)[..., None] * bg


def decode_image(decoder, latent: torch.Tensor, chunk: int = 1 << 16) -> torch.Tensor:
    """Decode a latent image [H, W, d] to reflectance [H, W, B] pixel by pixel (eq. 13)."""
    h, w, d = latent.shape
    flat = latent.reshape(-1, d)
    if flat.shape[0] <= chunk:
        return decoder.decode(flat).reshape(h, w, -1)
    parts = [decoder.decode(flat[i : i + chunk]) for i in range(0, flat.shape[0], chunk)]
    return torch.cat(parts, 0).reshape(h, w, -1)
