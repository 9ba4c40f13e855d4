"""The per-Gaussian reflectance head: hybrid kernel model (paper eq. 12) and baselines.

Hybrid (BRF-GS, eq. 12)::

    z_k(ω_i, ω_o) = z_iso + z_vol·K_Ross(ω_i, ω_o) + z_geo·K_Li(ω_i, ω_o) + z_spec·K_Cook(ω_i, ω_o, n_k, ρ_k)

in the d-dimensional spectral latent space (decoded by the spectral autoencoder, eq. 13).
Each component can be switched off (Table 3 ablations). With ``normal_frame=True`` the
Ross/Li kernels are evaluated in the Gaussian's own normal frame (topography-coupled
kernels: zenith angles measured from n_k instead of +z).

Baselines with the same interface (:class:`HeadConfig` / :func:`evaluate_head`):
``kind="sh"`` — spherical harmonics of degree 0–3 of ω_o in the latent space (Table 3's
SH baseline); ``kind="color"`` — one view-independent vector per Gaussian (plain
per-channel colour, for RGB/CIR-only 3DGS).

Roughness: the parameter dict stores an unconstrained ``rho_raw`` [N];
ρ = ρ_min + (1 − ρ_min)·sigmoid(rho_raw) ∈ (ρ_min, 1) (:func:`roughness_from_raw`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from brfgs.brdf import fused
from brfgs.brdf import kernels as K
from brfgs.brdf.sh import SH_C0, eval_sh, num_sh_bases
from brfgs.errors import UserError

__all__ = [
    "COMPONENTS",
    "HEAD_KINDS",
    "HeadConfig",
    "KernelConstants",
    "hybrid_kernels",
    "hybrid_latent",
    "roughness_from_raw",
    "raw_from_roughness",
    "head_param_shapes",
    "init_head_params",
    "evaluate_head",
]

COMPONENTS = ("iso", "vol", "geo", "spec")
HEAD_KINDS = ("hybrid", "sh", "color")


def _check_components(components) -> tuple[str, ...]:
    comps = tuple(components)
    bad = [c for c in comps if c not in COMPONENTS]
    if bad or len(set(comps)) != len(comps):
        raise UserError(
            f"components must be distinct names from {COMPONENTS}, got {comps}", field="components"
        )
    return comps


@dataclass(frozen=True)
class KernelConstants:
    """Constants of the kernels: the horizon clamp of the zenith cosines (see
    :mod:`brfgs.brdf.kernels`) and the Schlick F0 of the specular term (eq. 23)."""

    min_cos: float = K.MIN_COS
    f0: float = K.F0_DIELECTRIC


def hybrid_kernels(
    normals: Tensor | None,  # [N, 3] unit (needed for "spec" or normal_frame), else None
    omega_i: Tensor,  # [3] or [N, 3] unit, toward the sun
    omega_o: Tensor,  # [N, 3] unit, Gaussian → camera
    rho: Tensor | None = None,  # [N] roughness ρ in (0, 1] (needed for "spec")
    components: Sequence[str] = COMPONENTS,  # subset of ("iso", "vol", "geo", "spec")
    normal_frame: bool = False,  # Ross/Li with zenith angles from n_k
    *,
    min_cos: float = K.MIN_COS,  # horizon clamp of the cosines
    f0: float = K.F0_DIELECTRIC,  # Schlick F0 (eq. 23)
) -> dict[str, Tensor]:  # {"vol": [N], "geo": [N], "spec": [N]} for the enabled ones
    """Kernel values K_Ross (eqs 14–15), K_Li (eqs 16–19), K_Cook (eqs 20–23) of the enabled
    components, unitless (K_Cook in sr⁻¹).

    Shares the dot products of the three kernels (μ_i, μ_o, cos ξ). Normals are flipped
    to face ω_o here too, so any orientation of ``normals`` is accepted.
    """
    comps = _check_components(components)
    need_ross, need_li, need_cook = "vol" in comps, "geo" in comps, "spec" in comps
    out: dict[str, Tensor] = {}
    if not (need_ross or need_li or need_cook):
        return out
    cxi = (omega_i * omega_o).sum(-1)  # [N]  cos ξ
    if need_cook or normal_frame:
        if normals is None:
            raise ValueError("hybrid head: normals are required for the specular term / normal_frame")
        mu_o_n = (normals * omega_o).sum(-1)  # [N]
        sign = torch.where(mu_o_n < 0, -1.0, 1.0).to(mu_o_n.dtype)
        mu_o_n = mu_o_n * sign  # ≥ 0: normal faces ω_o
        mu_i_n = (normals * omega_i).sum(-1) * sign  # [N]
    if need_ross or need_li:
        if normal_frame:
            up = normals * sign.unsqueeze(-1)  # [N, 3]
            mu_i = mu_i_n.clamp_min(min_cos)
            mu_o = mu_o_n.clamp_min(min_cos)
        else:
            up = None
            mu_i = omega_i[..., 2].clamp_min(min_cos)
            mu_o = omega_o[..., 2].clamp_min(min_cos)
        if need_ross:
            out["vol"] = K.ross_thick_cos(mu_i, mu_o, cxi)
        if need_li:
            wi = omega_i.expand_as(omega_o) if omega_i.dim() == 1 else omega_i
            out["geo"] = K.li_sparse_r_vec_terms(wi, omega_o, up, mu_i, mu_o, cxi)
    if need_cook:
        if rho is None:
            raise ValueError("hybrid head: roughness rho is required for the specular term")
        out["spec"] = K.cook_torrance_cos(mu_i_n, mu_o_n, cxi, rho, f0, min_cos)
    return out


def hybrid_latent(
    z_iso: Tensor | None,  # [N, d] latent coefficients (None when the component is off)
    z_vol: Tensor | None,  # [N, d]
    z_geo: Tensor | None,  # [N, d]
    z_spec: Tensor | None,  # [N, d]
    rho: Tensor | None,  # [N] roughness ρ in (0, 1] (GGX α; see roughness_from_raw)
    normals: Tensor | None,  # [N, 3] unit (smallest-scale axis; flipped toward ω_o here as well)
    omega_i: Tensor,  # [3] or [N, 3] unit, toward the sun (ENU)
    omega_o: Tensor,  # [N, 3] unit, Gaussian → camera centre
    components: Sequence[str] = COMPONENTS,  # subset of ("iso", "vol", "geo", "spec") (Table 3 ablations)
    normal_frame: bool = False,  # Ross/Li with zenith angles from n_k (topography-coupled)
    *,
    constants: KernelConstants = KernelConstants(),  # horizon clamp, Schlick F0
    backend: str = "auto",  # "auto" | "torch" | "fused"
) -> Tensor:  # [N, d]
    """Latent directional reflectance z_k(ω_i, ω_o) of every Gaussian (paper eq. 12).

    ``backend``: "auto" (fused numba kernels on CPU tensors, torch otherwise), "torch" (pure
    torch ops; use it for double backward or CUDA) or "fused".
    """
    comps = _check_components(components)
    zs = {"iso": z_iso, "vol": z_vol, "geo": z_geo, "spec": z_spec}
    _check_latent_inputs(comps, zs, rho, normals, normal_frame)
    min_cos, f0 = constants.min_cos, constants.f0
    if _use_fused(backend, omega_o, [zs[c] for c in comps]):
        kk = fused.fused_kernels(
            normals, omega_i, omega_o, rho, "vol" in comps, "geo" in comps, "spec" in comps, normal_frame,
            min_cos, f0,
        )  # [N, 3]
        return fused.combine(z_iso, z_vol, z_geo, z_spec, kk, comps)
    ks = hybrid_kernels(normals, omega_i, omega_o, rho, comps, normal_frame, min_cos=min_cos, f0=f0)
    out = None
    for c in COMPONENTS:
        if c not in comps:
            continue
        if c == "iso":
            out = zs["iso"]
            continue
        k = ks[c].unsqueeze(-1).to(zs[c].dtype)  # [N, 1]
        if out is None:
            out = zs[c] * k
        elif out is zs["iso"]:
            out = torch.addcmul(out, zs[c], k)  # new tensor: never write into a parameter
        else:
            out = out.addcmul_(zs[c], k)
    return out


def _check_latent_inputs(comps: tuple[str, ...], zs: dict, rho, normals, normal_frame: bool) -> None:
    """ValueError when an enabled component lacks its coefficients, normals or roughness."""
    if not comps:
        raise ValueError("hybrid head: at least one component is required")
    for c in comps:
        if zs[c] is None:
            raise ValueError(f"hybrid head: z_{c} is required when component '{c}' is enabled")
    if ("spec" in comps or normal_frame) and normals is None:
        raise ValueError("hybrid head: normals are required for the specular term / normal_frame")
    if "spec" in comps and rho is None:
        raise ValueError("hybrid head: roughness rho is required for the specular term")


def _use_fused(backend: str, omega_o: Tensor, zs) -> bool:
    if backend not in ("auto", "torch", "fused"):
        raise ValueError(f"backend must be 'auto', 'torch' or 'fused', got {backend!r}")
    if backend == "torch":
        return False
    ok = (
        fused.available()
        and omega_o.device.type == "cpu"
        and omega_o.dtype in (torch.float32, torch.float64)
        and all(z.device.type == "cpu" and z.dtype == omega_o.dtype and z.dim() == 2 for z in zs)
    )
    if backend == "fused" and not ok:
        raise ValueError("fused backend needs numba and CPU float32/float64 tensors of one dtype")
    return ok


# ----------------------------------------------------------------------------------------
# Roughness parametrisation
# ----------------------------------------------------------------------------------------
def roughness_from_raw(
    rho_raw: Tensor,  # [N] unconstrained
    rho_min: float = 0.02,  # lower bound of ρ
) -> Tensor:  # [N] ρ in (ρ_min, 1)
    """Roughness ρ_k of eq. 11 (the GGX α of eq. 22): ρ = ρ_min + (1 − ρ_min)·sigmoid(rho_raw)."""
    return rho_min + (1.0 - rho_min) * torch.sigmoid(rho_raw)


def raw_from_roughness(
    rho: float | Tensor,  # float or [N] roughness ρ
    rho_min: float = 0.02,  # lower bound of ρ
) -> Tensor:  # like rho, unconstrained (default dtype)
    """Inverse of :func:`roughness_from_raw` (ρ clipped into (ρ_min, 1))."""
    rho = torch.as_tensor(rho, dtype=torch.get_default_dtype())
    p = ((rho - rho_min) / (1.0 - rho_min)).clamp(1e-6, 1 - 1e-6)
    return torch.log(p) - torch.log1p(-p)


# ----------------------------------------------------------------------------------------
# nn-free head description for the trainer
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HeadConfig:
    """Which reflectance head a model uses (options exposed by the CLI).

    kind: "hybrid" (eq. 12), "sh" (SH baseline in latent space) or "color" (no view dependence).
    components: hybrid terms to use (Table 3 ablations), subset of ("iso","vol","geo","spec").
    sh_degree: 0..3 for kind="sh".
    normal_frame: Ross/Li in the Gaussian's normal frame (topography-coupled kernels).
    rho_min: lower bound of the roughness ρ; rho_init: initial ρ.
    min_cos: horizon clamp of the kernel cosines (cos 89.5° by default).
    f0: Schlick F0 of the specular term.
    """

    kind: str = "hybrid"
    components: tuple[str, ...] = COMPONENTS
    sh_degree: int = 3
    normal_frame: bool = False
    rho_min: float = 0.02
    rho_init: float = 0.5
    min_cos: float = K.MIN_COS
    f0: float = K.F0_DIELECTRIC

    def __post_init__(self):
        if self.kind not in HEAD_KINDS:
            raise UserError(f"head kind must be one of {HEAD_KINDS}, got {self.kind!r}", field="kind")
        object.__setattr__(self, "components", _check_components(self.components))
        if self.kind == "hybrid" and not self.components:
            raise UserError("hybrid head needs at least one component", field="components")
        if self.sh_degree not in (0, 1, 2, 3):
            raise UserError(f"sh_degree must be 0..3, got {self.sh_degree}", field="sh_degree")
        if not (0.0 < self.rho_min < 1.0):
            raise UserError(f"rho_min must be in (0, 1), got {self.rho_min}", field="rho_min")
        if not (self.rho_min < self.rho_init < 1.0):
            raise UserError(f"rho_init must be in (rho_min, 1), got {self.rho_init}", field="rho_init")
        if not (0.0 < self.min_cos < 1.0):
            raise UserError(f"min_cos must be in (0, 1), got {self.min_cos}", field="min_cos")
        if not (0.0 <= self.f0 <= 1.0):
            raise UserError(f"f0 must be in [0, 1], got {self.f0}", field="f0")

    @property
    def view_dependent(self) -> bool:
        return self.kind == "sh" and self.sh_degree > 0 or (
            self.kind == "hybrid" and any(c != "iso" for c in self.components)
        )

    @property
    def needs_normals(self) -> bool:
        return self.kind == "hybrid" and ("spec" in self.components or self.normal_frame)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["components"] = list(self.components)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "HeadConfig":
        d = dict(d)
        if "components" in d:
            d["components"] = tuple(d["components"])
        return cls(**d)


def head_param_shapes(config: HeadConfig, n: int, d: int) -> dict[str, tuple[int, ...]]:
    """Names and shapes of the per-Gaussian parameters of a head (leading dim is always N).

    hybrid: z_<component> [N, d] for each enabled component, rho_raw [N] if "spec";
    sh: sh [N, (deg+1)², d]; color: color [N, d].
    """
    if config.kind == "hybrid":
        shapes = {f"z_{c}": (n, d) for c in COMPONENTS if c in config.components}
        if "spec" in config.components:
            shapes["rho_raw"] = (n,)
        return shapes
    if config.kind == "sh":
        return {"sh": (n, num_sh_bases(config.sh_degree), d)}
    return {"color": (n, d)}


def init_head_params(
    config: HeadConfig,
    n: int,  # number of Gaussians N
    d: int,  # latent dimension
    *,
    z_init: Tensor | None = None,  # [N, d] initial view-independent latent, or None (zeros)
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> dict[str, Tensor]:  # {name: [N, ...]}
    """Allocate and initialise the per-Gaussian head parameters (plain tensors, no grad).

    The view-independent part starts at ``z_init`` [N, d] (e.g. the encoded colours of the
    initial points; zeros if None) and every view-dependent term at 0, so a fresh model is
    Lambertian: hybrid → z_iso = z_init (or, without "iso", the first enabled term's
    coefficients stay 0); sh → DC = z_init / C0; color → z_init. rho_raw starts at
    ``raw_from_roughness(config.rho_init)``. Deterministic (no randomness).

    Returns: {name: tensor} with the shapes of :func:`head_param_shapes`; every tensor has
    leading dimension N, so densification can index/concatenate them uniformly.
    """
    shapes = head_param_shapes(config, n, d)
    params = {k: torch.zeros(s, dtype=dtype, device=device) for k, s in shapes.items()}
    base = None
    if z_init is not None:
        if tuple(z_init.shape) != (n, d):
            raise ValueError(f"z_init must be [{n}, {d}], got {tuple(z_init.shape)}")
        base = z_init.detach().to(dtype=dtype, device=device)
    if base is not None:
        if config.kind == "hybrid" and "iso" in config.components:
            params["z_iso"].copy_(base)
        elif config.kind == "sh":
            params["sh"][:, 0].copy_(base / SH_C0)
        elif config.kind == "color":
            params["color"].copy_(base)
    if "rho_raw" in params:
        params["rho_raw"].fill_(float(raw_from_roughness(config.rho_init, config.rho_min)))
    return params


def evaluate_head(
    config: HeadConfig,
    params: dict[str, Tensor],  # per-Gaussian parameters, leading dimension N
    normals: Tensor | None,  # [N, 3] unit, or None when the head needs none
    omega_i: Tensor,  # [3] or [N, 3] unit, toward the sun
    omega_o: Tensor,  # [N, 3] unit, Gaussian → camera
) -> Tensor:  # [N, d]
    """Latent reflectance of every Gaussian for one view, for any head kind (hybrid: eq. 12).

    Args:
        config: the head description.
        params: per-Gaussian parameters as made by :func:`init_head_params` (possibly
            nn.Parameters, possibly a subset of Gaussians — all leading dims equal).
        normals: [N, 3] (used by hybrid "spec"/normal_frame; may be None otherwise).
        omega_i: [3] or [N, 3] toward the sun; omega_o: [N, 3] Gaussian → camera.
    """
    if config.kind == "color":
        return params["color"]
    if config.kind == "sh":
        return eval_sh(config.sh_degree, params["sh"], omega_o)
    rho = None
    if "spec" in config.components:
        rho = roughness_from_raw(params["rho_raw"], config.rho_min)
    return hybrid_latent(
        params.get("z_iso"),
        params.get("z_vol"),
        params.get("z_geo"),
        params.get("z_spec"),
        rho,
        normals,
        omega_i.to(omega_o.dtype),
        omega_o,
        config.components,
        config.normal_frame,
        constants=KernelConstants(config.min_cos, config.f0),
    )
