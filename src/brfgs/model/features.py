"""Per-Gaussian features to rasterize for one camera: stage-1 colours, the appearance head's
latent (paper eq. 12), geometry channels for the surface priors.

Stage 1 renders the per-Gaussian reflectance of the stage-1 bands (``colors``, optionally view
dependent through SH rest terms). Stage 2 renders the latent z_k(omega_i, omega_o) of every
Gaussian (eq. 12, :func:`brfgs.brdf.head.evaluate_head`); ω_o of Gaussian k is
``normalize(camera centre − μ_k)`` (:func:`brfgs.brdf.geometry.view_directions`).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from brfgs.brdf.geometry import gaussian_normals, shading_normals, view_directions
from brfgs.brdf.head import HeadConfig, evaluate_head, hybrid_kernels, roughness_from_raw
from brfgs.model.camera import Camera
from brfgs.model.gaussians import GaussianModel

# Per-Gaussian tensors the appearance heads read (brfgs.brdf.head.init_head_params names).
HEAD_PARAM_KEYS = ("z_iso", "z_vol", "z_geo", "z_spec", "rho_raw", "sh", "color")


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

    def forward(
        self,
        feat: Tensor,  # [N, d]
        omega_o: Tensor,  # [N, 3] unit, toward the camera
        omega_i: Tensor,  # [N, 3] unit, toward the sun
    ) -> Tensor:  # [N, d]
        cos_phase = (omega_o * omega_i).sum(-1, keepdim=True)  # [N, 1]
        return feat + self.net(torch.cat([feat, omega_o, cos_phase], -1))


def head_params(model: GaussianModel) -> dict[str, Tensor]:
    """The per-Gaussian appearance tensors of ``model`` that the head reads ({name: [N, ...]})."""
    return {k: v for k, v in model.params.items() if k in HEAD_PARAM_KEYS}


def gaussian_features(
    model: GaussianModel,
    cam: Camera,
    sun_dir: Tensor,  # [3] unit, toward the sun
    head_cfg: HeadConfig | None,
    neural: NeuralHead | None = None,
    ref_sun: Tensor | None = None,  # [3] the centring sun of the centred form (default: sun_dir)
) -> Tensor:  # [N, C]
    """Per-Gaussian latent (or CIR colour of the "cir" variant) [N, C] for ``cam``: the appearance
    head (hybrid eq. 12 or SH) or the neural head; the centred training form when ``model.centred``."""
    omega_o = view_directions(model.means, cam.centre)  # [N, 3]
    if model.appearance == "neural":
        assert neural is not None
        return neural(model["feat"], omega_o, sun_dir.expand_as(omega_o))
    normals = None
    if head_cfg.needs_normals:
        normals = shading_normals(model.quats, model.scales, omega_o, model.params.get("normals"))
    if model.centred and head_cfg.kind == "hybrid":
        return centred_hybrid_latent(model, head_cfg, normals, sun_dir, omega_o, ref_sun)
    return evaluate_head(head_cfg, head_params(model), normals, sun_dir, omega_o)


def stage1_colors(model: GaussianModel, cam: Camera, sun_dir: Tensor | None = None) -> Tensor:  # [N, k]
    """Stage-1 reflectance of the stage-1 bands [N, k] for ``cam``: ``colors`` plus, when the model
    has ``colors_kernels`` [N, 2, k], the kernel terms c_vol K_Ross + c_geo K_Li of eq. 12 on the
    stage-1 bands (``sun_dir`` [3] unit, toward the sun)."""
    col = model["colors"]
    if "colors_kernels" not in model:
        return col
    omega_o = view_directions(model.means, cam.centre)  # [N, 3]
    kern = hybrid_kernels(None, sun_dir, omega_o, components=("vol", "geo"))  # {"vol", "geo"}: [N]
    c_vol, c_geo = model["colors_kernels"].unbind(1)  # [N, k] each
    # two products of [N, k] (a broadcast [N, 2, 1] x [N, 2, k] product and its sum cost ~3x as much)
    return col + (kern["vol"][:, None] * c_vol + kern["geo"][:, None] * c_geo)


def camera_depth(model: GaussianModel, cam: Camera) -> Tensor:  # [N] m
    """Camera-space depth [N] (m along the optical axis) of every Gaussian centre for ``cam``."""
    vm = cam.viewmat.to(model.means.dtype)  # [4, 4] world -> camera
    return model.means @ vm[2, :3] + vm[2, 3]


def camera_depth_normals(model: GaussianModel, cam: Camera) -> Tensor:  # [N, 4]
    """Per-Gaussian geometry features [N, 4] for ``cam``: camera-space depth (m along the optical
    axis) and the unit normal (:func:`brfgs.brdf.geometry.gaussian_normals`, facing the camera)
    in camera axes (OpenCV: x right, y down, z forward).

    Rasterized and divided by alpha they give the expected depth and normal maps used by the
    depth-normal consistency loss (:func:`brfgs.train.losses.depth_normal_loss`).
    """
    means = model.means
    vm = cam.viewmat.to(means.dtype)  # [4, 4] world -> camera
    n_world = gaussian_normals(model.quats, model.scales, view_directions(means, cam.centre))  # [N, 3]
    n_cam = n_world @ vm[:3, :3].T  # [N, 3]
    return torch.cat([camera_depth(model, cam)[:, None], n_cam], -1)


def _hybrid_kernels_at(model: GaussianModel, head_cfg: HeadConfig, normals: Tensor | None, sun_dir: Tensor,
                       omega_o: Tensor) -> dict[str, Tensor]:
    """Kernel values {"vol","geo","spec": [N]} of every Gaussian for the view directions ω_o [N, 3]."""
    rho = roughness_from_raw(model["rho_raw"], head_cfg.rho_min) if "rho_raw" in model else None
    return hybrid_kernels(normals, sun_dir.to(omega_o.dtype), omega_o, rho, head_cfg.components, head_cfg.normal_frame,
                          min_cos=head_cfg.min_cos, f0=head_cfg.f0)


def kernel_reference(model: GaussianModel, head_cfg: HeadConfig, sun_dir: Tensor) -> dict[str, Tensor]:
    """Kernel values {"vol","geo","spec": [N]} of every Gaussian for a nadir view (omega_o = +z)."""
    up = torch.zeros_like(model.means)  # [N, 3]
    up[:, 2] = 1.0
    normals = None
    if head_cfg.needs_normals:
        normals = shading_normals(model.quats, model.scales, up, model.params.get("normals"))
    return _hybrid_kernels_at(model, head_cfg, normals, sun_dir, up)


def centred_hybrid_latent(
    model: GaussianModel,
    head_cfg: HeadConfig,
    normals: Tensor | None,  # [N, 3] shading normals (None without the specular term)
    sun_dir: Tensor,  # [3]
    omega_o: Tensor,  # [N, 3]
    ref_sun: Tensor | None = None,  # [3] the centring sun (default: sun_dir)
) -> Tensor:  # [N, d]
    """Eq. 12 in the centred (NBAR-like) parametrisation used during training, [N, d]:

        z_k(omega_i, omega_o) = z'_iso + sum_j z_j (K_j(omega_i, omega_o) - K_j(omega_ref, nadir))

    z'_iso is then the latent of a nadir view under the reference sun ω_ref (the scene's: one
    centring for every frame, also when frames have their own suns). Same function class as eq. 12 (the Li-Sparse
    kernel is about -1 at every geometry, which makes z_iso and z_geo nearly collinear in the
    plain form and slows Adam); :func:`uncentre` converts back to eq. 12 for saving.
    """
    comps = head_cfg.components
    ks = _hybrid_kernels_at(model, head_cfg, normals, sun_dir, omega_o)
    ref = kernel_reference(model, head_cfg, sun_dir if ref_sun is None else ref_sun)
    out = model["z_iso"] if "iso" in comps else None
    for c in ("vol", "geo", "spec"):
        if c not in comps:
            continue
        term = model[f"z_{c}"] * (ks[c] - ref[c]).unsqueeze(-1)
        out = term if out is None else out + term
    return out


@torch.no_grad()
def uncentre(model: GaussianModel, head_cfg: HeadConfig, sun_dir: Tensor) -> dict[str, Tensor]:
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
