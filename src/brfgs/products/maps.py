"""Per-pixel BRDF products from the hybrid kernel model (MODIS MCD43-style), rendered from nadir.

For each Gaussian k the hybrid head (paper eq. 12) gives, in the spectral latent space,

    z_k(ω_i, ω_o) = z_iso + z_vol K_Ross + z_geo K_Li + z_spec K_Cook(ρ_k, n_k)

Products (all rendered with the same nadir camera, latent background composited as in
training, decoded per pixel by the spectral decoder D, eq. 13):

- contributions at the scene's sun (or a given one) and the camera's own view directions,
  decoded *sequentially* so that the four maps add up exactly to the decoded total:
  iso = D(Z_iso), vol = D(Z_iso + Z_vol) − D(Z_iso), geo = D(Z_iso + Z_vol + Z_geo) −
  D(Z_iso + Z_vol), spec = D(Z_total) − D(Z_iso + Z_vol + Z_geo)
  (Z_c: the rendered latent of term c; with an affine decoder each map is exactly the
  term's own decoded contribution);
- NBAR: nadir view (ω_o = +z for every Gaussian), sun at ``nbar_sun_zenith_deg`` and the
  scene's sun azimuth;
- black-sky albedo α_bs(θ_s) = D(Σ_c h_c(θ_s) Z_c) and white-sky albedo α_ws =
  D(Σ_c H_c Z_c) with the kernel integrals of brfgs.brdf.integrals (Lucht et al. 2000):
  h_iso = H_iso = 1; for Cook–Torrance the integrals depend on each Gaussian's roughness ρ_k
  (tabulated over ρ and interpolated; horizontal facet). The integrals are applied in the
  latent space (exact for an affine decoder; :func:`decoder_nonlinearity` measures the
  difference to integrating decoded spectra on sample pixels). Ross/Li integrals are those of
  the vertical frame, also when the model was trained with ``normal_frame``;
- anisotropy index ANIX = max / min of the BRF over the principal plane (view zenith
  −75…75°, sun at the chosen zenith), per pixel and band (Sandmeier et al. 1998).

With a linear spectral basis (D(z) = W z + b) every product here is exact (the decoder is affine),
and each Gaussian's MODIS kernel weights per band are W z_iso + b, W z_vol, W z_geo (W z_spec the
specular weight; :func:`gaussian_kernel_weights`), which :mod:`brfgs.products.mcd43_maps` renders
instead of fitting.

Pure per-Gaussian functions (:func:`nbar_latent`, :func:`albedo_latent`, ...) are separate
from rendering so they can be tested directly.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import Tensor
from tqdm import tqdm

from brfgs.analysis.threads import torch_threads
from brfgs.analysis.views import principal_plane_directions, view_camera
from brfgs.brdf import integrals as I
from brfgs.brdf.head import evaluate_head, hybrid_kernels, roughness_from_raw
from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.cameras import Intrinsics
from brfgs.errors import UserError
from brfgs.model import Camera, TrainedModel, render
from brfgs.model.rendering import FeaturesFn, composite_background
from brfgs.spectral.decoders import is_linear

__all__ = [
    "COMPONENT_ORDER",
    "require_hybrid",
    "component_latents",
    "gaussian_kernel_weights",
    "nbar_latent",
    "spec_integrals",
    "albedo_latent",
    "nadir_camera",
    "render_products",
    "decoder_nonlinearity",
]

COMPONENT_ORDER = ("iso", "vol", "geo", "spec")
UP = torch.tensor([0.0, 0.0, 1.0])


def require_hybrid(tm: TrainedModel) -> None:
    """UserError unless the model has the hybrid kernel head and a spectral decoder."""
    hc = tm.head_cfg
    if tm.decoder is None or hc is None or getattr(hc, "kind", None) != "hybrid":
        kind = getattr(hc, "kind", "neural") if hc is not None else tm.appearance
        raise UserError(f"kernel products need a BRF-GS model with the hybrid kernel head (this one: {kind!r})",
                        field="model")


def _rho(tm: TrainedModel, params: dict[str, Tensor]) -> Tensor | None:  # [n]
    if "rho_raw" not in params:
        return None
    return roughness_from_raw(params["rho_raw"], tm.head_cfg.rho_min)


@torch.no_grad()
def component_latents(
    tm: TrainedModel,
    idx: Tensor | None,  # [n] long (None: all Gaussians)
    omega_i: Tensor,  # [3] unit, toward the sun
    omega_o: Tensor,  # [n, 3] unit, toward the camera
) -> dict[str, Tensor]:  # {c: [n, d]}
    """Per-Gaussian latent contribution of each enabled term {c: [n, d]} for ω_i [3], ω_o [n, 3].

    iso: z_iso; vol: z_vol·K_Ross; geo: z_geo·K_Li; spec: z_spec·K_Cook. Their sum is
    exactly the head's output (brfgs.brdf.head.hybrid_latent).
    """
    hc = tm.head_cfg
    p = tm.head_params(idx)
    normals = None
    if hc.needs_normals:
        normals = tm.head_normals(omega_o, idx)
    ks = hybrid_kernels(normals, omega_i.to(omega_o.dtype), omega_o, _rho(tm, p), hc.components, hc.normal_frame,
                        min_cos=hc.min_cos, f0=hc.f0)
    out = {}
    for c in COMPONENT_ORDER:
        if c not in hc.components:
            continue
        z = p[f"z_{c}"]
        out[c] = z if c == "iso" else z * ks[c].unsqueeze(-1).to(z.dtype)
    return out


@torch.no_grad()
def gaussian_kernel_weights(tm: TrainedModel, idx: Tensor | None = None) -> dict[str, Tensor]:  # {name: [n, B]}
    """Per-band kernel weights of Gaussians ``idx`` (all if None) of a model with a linear spectral basis:
    {"f_iso": W z_iso + b, "f_vol": W z_vol, "f_geo": W z_geo, "f_spec": W z_spec} for its enabled terms
    (f_iso is b without an iso term). Its BRF in band j is f_iso + f_vol K_Ross + f_geo K_Li + f_spec K_Cook."""
    require_hybrid(tm)
    if not is_linear(tm.decoder):
        raise UserError("exact kernel weights need a model with a linear spectral basis", field="model")
    p = tm.head_params(idx)
    n = tm.n_gaussians if idx is None else int(idx.numel())
    z_iso = p.get("z_iso", torch.zeros(n, tm.gaussians.latent_dim))
    out = {"f_iso": tm.decoder.decode(z_iso)}
    for c in ("vol", "geo", "spec"):
        if c in tm.head_cfg.components:
            out[f"f_{c}"] = tm.decoder.decode_weights(p[f"z_{c}"])
    return out


@torch.no_grad()
def nbar_latent(
    tm: TrainedModel,
    sun_zenith_deg: float,
    idx: Tensor | None = None,  # [n] long (None: all Gaussians)
    sun_azimuth_deg: float | None = None,
) -> Tensor:  # [n, d]
    """Nadir BRF-adjusted latent [n, d]: view ω_o = +z for every Gaussian, sun at the given zenith."""
    omega_i = tm.sun_direction(sun_zenith_deg, sun_azimuth_deg)
    n = tm.n_gaussians if idx is None else int(idx.numel())
    omega_o = UP.expand(n, 3).contiguous()
    normals = None
    if tm.head_cfg.needs_normals:
        normals = tm.head_normals(omega_o, idx)
    return evaluate_head(tm.head_cfg, tm.head_params(idx), normals, omega_i, omega_o)


# ----------------------------------------------------------------------------------------
# kernel integrals


_RHO_NODES = 8
_MU_SUN_NODES = 8  # h(θ_s) is smooth: 8 nodes agree with integrals.white_sky to 1e-7


@functools.lru_cache(maxsize=32)
def _spec_table(log_rho_lo: float, log_rho_hi: float, kind: str, sun_zenith_rad: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """(log ρ nodes, integral values) of the Cook–Torrance kernel; kind "black" or "white"."""
    n = _RHO_NODES if log_rho_hi > log_rho_lo else 1
    lx = np.linspace(log_rho_lo, log_rho_hi, n)
    vals = np.empty(n)
    with torch_threads(1):  # many small tensors: one thread is fastest on a shared machine
        _fill_table(lx, vals, kind, sun_zenith_rad)
    return lx, vals


def _fill_table(lx: np.ndarray, vals: np.ndarray, kind: str, sun_zenith_rad: float) -> None:
    if kind == "black":
        for j, r in enumerate(np.exp(lx)):
            vals[j] = float(I.black_sky_many("cook_torrance", sun_zenith_rad, roughness=float(r))[0])
    else:
        # H = 2 ∫_0^1 h(θ_s) μ_s dμ_s, Gauss–Legendre in μ_s (h is smooth in θ_s)
        x, w = np.polynomial.legendre.leggauss(_MU_SUN_NODES)
        mu = 0.5 * (x + 1.0)
        w = 0.5 * w
        for j, r in enumerate(np.exp(lx)):
            h = I.black_sky_many("cook_torrance", np.arccos(mu), roughness=float(r))
            vals[j] = float(2.0 * np.sum(w * mu * h))


def spec_integrals(
    rho: Tensor | np.ndarray,  # [n] roughness
    kind: str,
    sun_zenith_deg: float = 0.0,
) -> np.ndarray:  # [n]
    """Cook–Torrance black-sky (kind "black", at ``sun_zenith_deg``) or white-sky ("white")
    integral for each roughness ρ [n] (horizontal facet, F0 0.04).

    brfgs.brdf.integrals evaluated at 8 roughness nodes spaced in log ρ over the range of
    ``rho`` (rounded outward to 0.05 in ln ρ) and interpolated linearly in log ρ.
    """
    if kind not in ("black", "white"):
        raise ValueError(kind)
    r = np.asarray(rho.detach().numpy() if isinstance(rho, Tensor) else rho, float).reshape(-1)
    r = np.clip(r, 1e-3, 1.0)
    lo = math.floor(np.log(r.min()) / 0.05) * 0.05
    hi = min(0.0, math.ceil(np.log(r.max()) / 0.05) * 0.05)
    key_zen = round(math.radians(sun_zenith_deg), 12) if kind == "black" else 0.0
    lx, lv = _spec_table(round(lo, 6), round(max(hi, lo), 6), kind, key_zen)
    if len(lx) == 1:
        return np.full(r.shape, lv[0])
    return np.interp(np.log(r), lx, lv)


@torch.no_grad()
def albedo_latent(
    tm: TrainedModel,
    kind: str,
    sun_zenith_deg: float = 0.0,
    idx: Tensor | None = None,  # [n] long (None: all Gaussians)
) -> Tensor:  # [n, d]
    """Per-Gaussian latent albedo [n, d]: Σ_c h_c(θ_s) z_c (kind "black") or Σ_c H_c z_c ("white").

    h_iso = H_iso = 1, so a Gaussian with only z_iso has albedo latent exactly z_iso.
    """
    if kind not in ("black", "white"):
        raise ValueError(kind)
    hc = tm.head_cfg
    p = tm.head_params(idx)
    ts = math.radians(sun_zenith_deg)
    out = None
    for c in COMPONENT_ORDER:
        if c not in hc.components:
            continue
        z = p[f"z_{c}"]
        if c == "iso":
            term = z
        elif c in ("vol", "geo"):
            name = "ross_thick" if c == "vol" else "li_sparse_r"
            with torch_threads(1):
                h = I.white_sky(name) if kind == "white" else I.black_sky(name, ts)
            term = z * float(h)
        else:
            rho = _rho(tm, p)
            h = torch.as_tensor(spec_integrals(rho, kind, sun_zenith_deg), dtype=z.dtype)
            term = z * h.unsqueeze(-1)
        out = term if out is None else out + term
    return out


# ----------------------------------------------------------------------------------------
# rendering


def nadir_camera(
    tm: TrainedModel,
    size: int = 256,
    half_extent_m: float | None = None,
    centre_m: ArrayLike | None = None,  # [3] m
    distance_m: float | None = None,
) -> tuple[np.ndarray, Intrinsics]:
    """Nadir camera over the scene (c2w, Intrinsics): looks down at ``centre_m`` (default: the
    Gaussians' median position), field of view holding ``half_extent_m`` (default: half the
    Gaussians' 2–98 % horizontal extent), from ``distance_m`` (default: 10 half extents, a
    near-orthographic view whose rays are within ±6° of nadir)."""
    c = tm.scene_centre_m() if centre_m is None else np.asarray(centre_m, float)
    half = tm.scene_half_extent_m() if half_extent_m is None else float(half_extent_m)
    dist = 10.0 * half if distance_m is None else float(distance_m)
    top = float(tm.gaussians.means.detach()[:, 2].max())
    dist = max(dist, (top - c[2]) + 1.0)
    return view_camera(0.0, 0.0, dist, c, size=size, half_extent_m=half)


@dataclass
class _MapRenderer:
    """Renders per-Gaussian latent stacks for one camera and decodes them to product maps."""

    tm: TrainedModel
    cam: Camera
    backend: str
    min_alpha: float

    def latents(self, fn: FeaturesFn) -> tuple[Tensor, Tensor]:
        """(premultiplied planes [H, W, C], alpha [H, W]) of features ``fn(idx, omega_o) -> [n, C]``."""
        rv = render(self.tm, self.cam, features=fn, backend=self.backend)
        return rv.image, torch.as_tensor(rv.alpha)

    def decode(self, lat: Tensor, alpha: Tensor) -> np.ndarray:
        """Composite the latent background, decode [H, W, d] → [H, W, B]; NaN where alpha < min_alpha."""
        cube = self.tm.decode(composite_background(lat, alpha, self.tm.bg_latent))
        cube[alpha.numpy() < self.min_alpha] = np.nan
        return cube


def _contribution_maps(mr: _MapRenderer, sun_zenith_deg: float, out: dict) -> Tensor:
    """Sequentially decoded contribution maps of the enabled terms and their "total" into ``out``; alpha."""
    tm = mr.tm
    d = tm.gaussians.latent_dim
    omega_i = tm.sun_direction(sun_zenith_deg)
    comps = [c for c in COMPONENT_ORDER if c in tm.head_cfg.components]

    def fn(idx: Tensor, oo: Tensor) -> Tensor:
        cl = component_latents(tm, idx, omega_i, oo)
        return torch.cat([cl[c] for c in comps], -1)

    lat, alpha = mr.latents(fn)
    acc = prev = None
    for j, c in enumerate(comps):
        part = lat[..., j * d:(j + 1) * d]
        acc = part if acc is None else acc + part
        cur = mr.decode(acc, alpha)
        out[c] = cur if prev is None else (cur - prev)
        prev = cur
    out["total"] = prev
    return alpha


def _nbar_albedo_maps(mr: _MapRenderer, nbar_sun_zenith_deg: float, albedo_sun_zenith_deg: float,
                      which: tuple[str, ...], out: dict) -> Tensor:
    """NBAR ("nbar") and black/white-sky albedo ("bsa", "wsa") maps into ``out``, as ``which`` asks; alpha."""
    tm = mr.tm
    d = tm.gaussians.latent_dim

    def fn(idx: Tensor, oo: Tensor) -> Tensor:
        fs = []
        if "nbar" in which:
            fs.append(nbar_latent(tm, nbar_sun_zenith_deg, idx))
        if "albedo" in which:
            fs.append(albedo_latent(tm, "black", albedo_sun_zenith_deg, idx))
            fs.append(albedo_latent(tm, "white", 0.0, idx))
        return torch.cat(fs, -1)

    names = (["nbar"] if "nbar" in which else []) + (["bsa", "wsa"] if "albedo" in which else [])
    lat, alpha = mr.latents(fn)
    for j, nm in enumerate(names):
        out[nm] = mr.decode(lat[..., j * d:(j + 1) * d], alpha)
    return alpha


def _anix_map(mr: _MapRenderer, sun_zenith_deg: float, step_deg: float, max_zenith_deg: float
              ) -> tuple[np.ndarray, Tensor]:
    """(ANIX [H, W, B]: max / min BRF over the principal plane, alpha [H, W])."""
    tm = mr.tm
    d = tm.gaussians.latent_dim
    s = np.arange(-max_zenith_deg, max_zenith_deg + 1e-9, step_deg)
    zen, azv = principal_plane_directions(s, tm.sun_azimuth_deg)
    dirs = torch.as_tensor(direction_from_angles_deg(zen, azv), dtype=torch.float32)  # [G, 3]
    omega_i = tm.sun_direction(sun_zenith_deg)

    def fn(idx: Tensor, oo: Tensor) -> Tensor:
        n = int(idx.numel())
        return torch.cat([tm.gaussian_latent(omega_i, dirs[g].expand(n, 3).contiguous(), idx)
                          for g in range(dirs.shape[0])], -1)

    lat, alpha = mr.latents(fn)
    mx = mn = None
    for g in range(dirs.shape[0]):
        cube = mr.decode(lat[..., g * d:(g + 1) * d], alpha)
        mx = cube if mx is None else np.fmax(mx, cube)
        mn = cube if mn is None else np.fmin(mn, cube)
    with np.errstate(divide="ignore", invalid="ignore"):
        anix = np.where(mn > 0, mx / mn, np.nan).astype(np.float32)
    return anix, alpha


@torch.no_grad()
def render_products(
    tm: TrainedModel,
    cam: Camera,
    *,
    sun_zenith_deg: float | None = None,
    nbar_sun_zenith_deg: float | None = None,
    albedo_sun_zenith_deg: float | None = None,
    anix_step_deg: float = 5.0,
    anix_max_zenith_deg: float = 75.0,
    backend: str = "auto",
    min_alpha: float = 0.5,
    which: tuple[str, ...] = ("contributions", "nbar", "albedo", "anix"),
    progress: bool = False,
) -> dict:
    """Render the products for one camera (usually :func:`nadir_camera`).

    Returns {name: cube [H, W, B] float32} with names "iso", "vol", "geo", "spec", "total"
    (contributions), "nbar", "bsa" (black-sky), "wsa" (white-sky), "anix"; plus "alpha"
    [H, W] and "settings" (dict of the angles used).
    """
    require_hybrid(tm)
    hc = tm.head_cfg
    sz = tm.sun_zenith_deg if sun_zenith_deg is None else float(sun_zenith_deg)
    nz = sz if nbar_sun_zenith_deg is None else float(nbar_sun_zenith_deg)
    az_ = sz if albedo_sun_zenith_deg is None else float(albedo_sun_zenith_deg)
    out: dict = {"settings": {"sun_zenith_deg": sz, "sun_azimuth_deg": tm.sun_azimuth_deg,
                              "nbar_sun_zenith_deg": nz, "albedo_sun_zenith_deg": az_,
                              "anix_principal_plane_deg": [-anix_max_zenith_deg, anix_max_zenith_deg, anix_step_deg],
                              "components": list(hc.components), "normal_frame": bool(hc.normal_frame),
                              "min_alpha": min_alpha}}
    mr = _MapRenderer(tm, cam, backend, min_alpha)
    alpha = None
    with tqdm(total=len(which), desc="products", leave=False, disable=not progress) as bar:
        if "contributions" in which:
            alpha = _contribution_maps(mr, sz, out)
            bar.update()
        if "nbar" in which or "albedo" in which:
            alpha = _nbar_albedo_maps(mr, nz, az_, which, out)
            bar.update(("nbar" in which) + ("albedo" in which))
        if "anix" in which:
            out["anix"], alpha = _anix_map(mr, sz, anix_step_deg, anix_max_zenith_deg)
            bar.update()
    out["alpha"] = alpha.numpy() if alpha is not None else None
    return out


@torch.no_grad()
def decoder_nonlinearity(tm: TrainedModel, sun_zenith_deg: float, n_gaussians: int = 64, n_mu: int = 32,
                         n_phi: int = 48, seed: int = 0) -> dict:
    """How far the latent-space albedo is from integrating decoded spectra (black-sky).

    For ``n_gaussians`` random Gaussians, the black-sky albedo by Gauss–Legendre quadrature
    of the *decoded* BRF over the view hemisphere, (1/π)∫ D(z(ω_i, ω_o)) cos θ_v dω_o, is
    compared with D(Σ_c h_c z_c). Returns the mean and max absolute difference (reflectance
    units) and the mean albedo for scale.
    """
    require_hybrid(tm)
    n = tm.n_gaussians
    g = torch.Generator().manual_seed(seed)
    idx = torch.randperm(n, generator=g)[: min(n_gaussians, n)]
    omega_i = tm.sun_direction(sun_zenith_deg)
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu = 0.5 * (x + 1.0)
    wmu = 0.5 * w
    xp, wp = np.polynomial.legendre.leggauss(n_phi)
    phi = math.pi * (xp + 1.0)
    wphi = math.pi * wp
    M, PH = np.meshgrid(mu, phi, indexing="ij")                       # [n_mu, n_phi]
    W = (wmu[:, None] * wphi[None, :]) * M / math.pi                  # quadrature weights × cos θ / π
    st = np.sqrt(np.clip(1.0 - M * M, 0.0, None))
    dirs = np.stack([st * np.sin(PH), st * np.cos(PH), M], -1).reshape(-1, 3)  # [Q, 3] (conventions)
    q = dirs.shape[0]
    acc = torch.zeros(len(idx), len(tm.wavelengths_nm), dtype=torch.float64)
    oo = torch.as_tensor(dirs, dtype=torch.float32)
    wt = torch.as_tensor(W.reshape(-1), dtype=torch.float64)
    for j in range(len(idx)):
        ij = idx[j:j + 1].expand(q)
        r = torch.as_tensor(tm.decode(tm.gaussian_latent(omega_i, oo, ij))).double()  # [Q, B]
        acc[j] = (r * wt[:, None]).sum(0)
    lat = albedo_latent(tm, "black", sun_zenith_deg, idx)
    direct = torch.as_tensor(tm.decode(lat))
    diff = (acc - direct.double()).abs()
    return {"n_gaussians": int(len(idx)), "sun_zenith_deg": float(sun_zenith_deg),
            "mean_abs_diff": float(diff.mean()), "max_abs_diff": float(diff.max()),
            "mean_albedo": float(direct.abs().mean())}
