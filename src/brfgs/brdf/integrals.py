"""Hemispherical integrals of the kernels, for albedo and NBAR products (Lucht et al. 2000).

Black-sky (directional-hemispherical) kernel integral at sun zenith θ_s::

    h_k(θ_s) = (1/π) ∫_0^{2π} ∫_0^{π/2} K_k(θ_s, θ_v, φ) cos θ_v sin θ_v dθ_v dφ

White-sky (bihemispherical) integral::

    H_k = 2 ∫_0^{π/2} h_k(θ_s) cos θ_s sin θ_s dθ_s

For a kernel-driven BRF R = f_iso + f_vol K_vol + f_geo K_geo the albedos are
α_bs(θ_s) = Σ f_k h_k(θ_s) and α_ws = Σ f_k H_k (isotropic: h = H = 1).
The same normalisation is used for the Cook–Torrance term of eq. 12 (K_Cook is a BRDF in
sr⁻¹ added like a BRF kernel), so z_spec·h_cook is that term's albedo contribution in the
model's units.

Computed once numerically in float64 (Gauss–Legendre in cos θ and in φ ∈ [0, π], the
kernels being even in φ) with the same kernels as the model, and cached
(functools.lru_cache), so no hard-coded table is needed. Expected (Lucht et al. 2000,
Table 1): H_Ross = 0.189184, H_Li = −1.377622.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from brfgs.brdf import kernels as K
from brfgs.errors import UserError

__all__ = ["KERNEL_NAMES", "canonical_kernel", "black_sky", "black_sky_many", "white_sky"]

KERNEL_NAMES = ("isotropic", "ross_thick", "li_sparse_r", "cook_torrance")
_ALIASES = {
    "iso": "isotropic",
    "isotropic": "isotropic",
    "ross": "ross_thick",
    "ross_thick": "ross_thick",
    "rossthick": "ross_thick",
    "vol": "ross_thick",
    "li": "li_sparse_r",
    "li_sparse_r": "li_sparse_r",
    "lisparser": "li_sparse_r",
    "lisparse": "li_sparse_r",
    "geo": "li_sparse_r",
    "cook": "cook_torrance",
    "cook_torrance": "cook_torrance",
    "spec": "cook_torrance",
}

# quadrature sizes: converged to ~1e-6 (Ross 0.1891864, Li −1.3776579; Lucht et al. print
# 0.189184 and −1.377622), checked by tests against the published values and 1-D quadrature
_N_MU_VIEW = 96
_N_PHI = 128
_N_MU_SUN = 32
_TINY_COS = 1e-12  # no horizon clamp inside the integrals (nodes never reach the horizon)


def canonical_kernel(name: str) -> str:
    """Canonical kernel name for ``name`` (aliases: iso/vol/geo/spec, ross, li, cook, ...)."""
    key = str(name).strip().lower().replace("-", "_")
    if key not in _ALIASES:
        raise UserError(f"unknown kernel {name!r}; expected one of {KERNEL_NAMES}", field="kernel")
    return _ALIASES[key]


@functools.lru_cache(maxsize=None)
def _gauss_legendre(n: int, a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (b - a) * x + 0.5 * (b + a), 0.5 * (b - a) * w


def _kernel_values(name: str, ts, tv, phi, roughness: float | None) -> torch.Tensor:
    """Kernel on float64 angle tensors (broadcast), without horizon clamp."""
    if name == "ross_thick":
        return K.ross_thick_angles(ts, tv, phi, min_cos=_TINY_COS)
    if name == "li_sparse_r":
        return K.li_sparse_r_angles(ts, tv, phi, min_cos=_TINY_COS)
    if name == "cook_torrance":
        return K.cook_torrance_angles(ts, tv, phi, float(roughness), min_cos=_TINY_COS)
    raise AssertionError(name)


def black_sky_many(
    name: str,  # kernel (aliases accepted)
    sun_zenith_rad: float | np.ndarray,  # float or [S] rad, in [0, π/2)
    *,
    roughness: float | None = None,  # ρ for "cook_torrance"
) -> np.ndarray:  # [S] float64, unitless
    """Black-sky integrals h_k(θ_s) for an array of sun zeniths.

    ``roughness`` is required for "cook_torrance" (horizontal facet, F0 = 0.04); it is
    ignored otherwise.
    """
    name = canonical_kernel(name)
    ts = np.atleast_1d(np.asarray(sun_zenith_rad, dtype=np.float64))
    if np.any(~np.isfinite(ts)) or np.any(ts < 0) or np.any(ts >= math.pi / 2):
        raise UserError("sun zenith must be in [0, π/2) radians", field="sun_zenith_rad")
    if name == "isotropic":
        return np.ones_like(ts)
    if name == "cook_torrance":
        if roughness is None or not (0.0 < float(roughness) <= 1.0):
            raise UserError("cook_torrance integrals need roughness in (0, 1]", field="roughness")
    mu, wmu = _gauss_legendre(_N_MU_VIEW, 0.0, 1.0)
    ph, wph = _gauss_legendre(_N_PHI, 0.0, math.pi)
    with torch.no_grad():
        tv = torch.from_numpy(np.arccos(mu))[:, None]  # [M, 1]
        phi = torch.from_numpy(ph)[None, :]  # [1, P]
        w2 = torch.from_numpy(wmu * mu)[:, None] * torch.from_numpy(wph)[None, :]  # [M, P]
        out = np.empty_like(ts)
        for j, t in enumerate(ts):
            k = _kernel_values(name, torch.tensor(float(t), dtype=torch.float64), tv, phi, roughness)
            # (1/π)·2·∫_0^π dφ ∫_0^1 K μ dμ
            out[j] = float((k * w2).sum()) * 2.0 / math.pi
    return out


@functools.lru_cache(maxsize=4096)
def _black_sky_cached(name: str, sun_zenith_rad: float, roughness: float | None) -> float:
    return float(black_sky_many(name, sun_zenith_rad, roughness=roughness)[0])


def black_sky(
    name: str,  # kernel (aliases accepted)
    sun_zenith_rad: float,  # rad, in [0, π/2)
    *,
    roughness: float | None = None,  # ρ for "cook_torrance" (horizontal facet)
) -> float:  # unitless
    """Black-sky (directional-hemispherical) integral h_k(θ_s) of kernel ``name`` (cached).

    Args:
        name: "isotropic", "ross_thick", "li_sparse_r" or "cook_torrance" (aliases accepted).
        sun_zenith_rad: θ_s in [0, π/2).
        roughness: ρ for "cook_torrance" (horizontal facet).
    Returns: h_k(θ_s), unitless (isotropic → 1).
    """
    name = canonical_kernel(name)
    r = float(roughness) if (roughness is not None and name == "cook_torrance") else None
    return _black_sky_cached(name, float(sun_zenith_rad), r)


@functools.lru_cache(maxsize=64)
def _white_sky_cached(name: str, roughness: float | None) -> float:
    if name == "isotropic":
        return 1.0
    mu_s, w = _gauss_legendre(_N_MU_SUN, 0.0, 1.0)
    h = black_sky_many(name, np.arccos(mu_s), roughness=roughness)
    return float(2.0 * np.sum(w * mu_s * h))


def white_sky(
    name: str,  # kernel (aliases accepted)
    *,
    roughness: float | None = None,  # ρ for "cook_torrance"
) -> float:  # unitless
    """White-sky (bihemispherical) integral H_k of kernel ``name`` (cached).

    Ross-Thick ≈ 0.189184 and Li-Sparse-R ≈ −1.377622 (Lucht et al. 2000); isotropic 1.
    """
    name = canonical_kernel(name)
    r = float(roughness) if (roughness is not None and name == "cook_torrance") else None
    if name == "cook_torrance" and r is None:
        raise UserError("cook_torrance integrals need roughness in (0, 1]", field="roughness")
    return _white_sky_cached(name, r)
