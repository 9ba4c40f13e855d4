"""BRDF kernels of BRF-GS (paper eqs 14–23) as pure, batched torch functions.

All kernels are written in cosines (no acos/atan of input angles), so one set of
dot products serves all three kernels and every value and gradient stays finite:

* ``μ_i = ω_i·n``, ``μ_o = ω_o·n`` — cosines of the sun and view zenith in the frame
  whose "up" is ``n`` (``n = +z`` for the remote-sensing kernels unless the caller asks
  for the Gaussian's own normal frame);
* ``cos ξ = ω_i·ω_o`` — the phase angle (paper eq. 15 / Lucht et al. 2000 eq. 43),
  frame independent.

Directions follow ``docs/data-format.md``: ω_i points toward the sun, ω_o toward
the sensor, both away from the surface; with ``d = (sinθ sinφ, sinθ cosφ, cosθ)``,
relative azimuth φ = φ_view − φ_sun and φ = 0 is backscatter (hotspot at θ_v = θ_s, φ = 0).

Numerical safety (documented behaviour, tested):

* zenith cosines are clamped from below to ``min_cos`` (default ``MIN_COS`` =
  cos 89.5°) for Ross-Thick and Li-Sparse-R: a direction at or below the horizon
  of the frame is treated as grazing. Nothing changes for zenith angles up to 89.5°.
* the two singular-looking scalar functions of the kernels have finite derivatives on
  the whole domain and are implemented as custom autograd functions:
  ``f(c) = (π/2 − acos c)·c + sqrt(1 − c²)`` with ``f'(c) = asin c`` (Ross-Thick), and
  ``g(c) = acos c − c·sqrt(1 − c²)`` with ``g'(c) = −2 sqrt(1 − c²)`` (Li overlap).
* the Li-Sparse distance ``sqrt(D² + (tanθ_i tanθ_v sin φ)²)`` has a cusp at the
  hotspot (the kernel's physical hotspot peak); its gradient there is taken as 0
  (the symmetric sub-gradient, which is also what central differences give).
* Li-Sparse-R itself is C¹ but not C² where the crown shadows stop overlapping
  (cos t = 1, e.g. θ_i = θ_v = 30°, φ = 180° for h/b = 2): g'(1) = 0, so gradients are
  continuous there, but finite-difference checks exactly at that point are off by ~sqrt(ε).
* Cook–Torrance uses ``max(μ, min_cos)`` in its denominator and a linear ramp
  ``clamp(μ / min_cos, 0, 1)`` for each of μ_i, μ_o, so the specular lobe is exactly
  eq. 20 for directions above ``min_cos`` and goes continuously to 0 for a sun or
  sensor behind the facet (back-facing normals give 0, never NaN).

Public functions (vectors): :func:`ross_thick`, :func:`li_sparse_r`,
:func:`cook_torrance`; angle conveniences: :func:`ross_thick_angles`,
:func:`li_sparse_r_angles`, :func:`cook_torrance_angles`; cosine cores used by the
fused head: :func:`ross_thick_cos`, :func:`li_sparse_r_vec_terms`, :func:`cook_torrance_cos`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

__all__ = [
    "MIN_COS",
    "F0_DIELECTRIC",
    "LI_HB",
    "LI_BR",
    "ross_thick",
    "li_sparse_r",
    "cook_torrance",
    "ross_thick_angles",
    "li_sparse_r_angles",
    "cook_torrance_angles",
    "ross_thick_cos",
    "li_sparse_r_vec_terms",
    "cook_torrance_cos",
    "frame_cosines",
    "directions_from_angles",
]

#: Lower clamp of zenith cosines (cos 89.5°): grazing directions are treated as 89.5°.
MIN_COS: float = math.cos(math.radians(89.5))
#: Schlick normal-incidence reflectance of dielectrics (paper, after eq. 23).
F0_DIELECTRIC: float = 0.04
#: MODIS crown shape of Li-Sparse-R: relative height h/b and shape b/r (Lucht et al. 2000).
LI_HB: float = 2.0
LI_BR: float = 1.0

_INV_PI = 1.0 / math.pi
_PI_4 = math.pi / 4.0
_TINY = 1e-30


# ----------------------------------------------------------------------------------------
# Scalar primitives with finite derivatives everywhere
# ----------------------------------------------------------------------------------------
class _RossPhase(torch.autograd.Function):
    """f(c) = (π/2 − ξ) cos ξ + sin ξ with c = cos ξ; f'(c) = asin(c) (finite on [−1, 1])."""

    @staticmethod
    def forward(ctx, c):
        c = c.clamp(-1.0, 1.0)
        a = torch.asin(c)
        ctx.save_for_backward(a)
        return torch.addcmul(torch.sqrt((1.0 - c) * (1.0 + c)), c, a)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        (a,) = ctx.saved_tensors
        return grad * a


class _LiOverlap(torch.autograd.Function):
    """g(c) = t − sin t cos t with c = cos t (clipped to [−1, 1]); g'(c) = −2 sqrt(1 − c²).

    For c ≥ 1 (no crown overlap) g = 0 and g' = 0, continuously.
    """

    @staticmethod
    def forward(ctx, c):
        c = c.clamp(-1.0, 1.0)
        s = torch.sqrt((1.0 - c) * (1.0 + c))
        ctx.save_for_backward(s)
        return torch.acos(c) - c * s

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        (s,) = ctx.saved_tensors
        return grad * (-2.0 * s)


class _SafeSqrt(torch.autograd.Function):
    """sqrt(max(x, 0)) with derivative 1/(2 sqrt x) for x > 0 and 0 at x ≤ 0."""

    @staticmethod
    def forward(ctx, x):
        r = torch.sqrt(x.clamp_min(0.0))
        ctx.save_for_backward(r)
        return r

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        (r,) = ctx.saved_tensors
        return torch.where(r > 0, grad * 0.5 / r.clamp_min(_TINY), torch.zeros_like(grad))


def _safe_sqrt(x: Tensor) -> Tensor:
    return _SafeSqrt.apply(x)


def _dot(a: Tensor, b: Tensor) -> Tensor:
    """Dot product over the last axis (broadcasting), [...] ."""
    return (a * b).sum(-1)


# ----------------------------------------------------------------------------------------
# Cosine cores
# ----------------------------------------------------------------------------------------
def ross_thick_cos(
    mu_i: Tensor,  # [...] cos of the sun zenith, already clamped to > 0
    mu_o: Tensor,  # [...] cos of the view zenith, already clamped to > 0
    cos_xi: Tensor,  # [...] cos of the phase angle ξ, ω_i·ω_o
) -> Tensor:  # [...] (broadcast) K_Ross, unitless
    """Ross-Thick kernel from cosines (paper eqs 14–15, Lucht et al. 2000 eq. 38).

    K = ((π/2 − ξ) cos ξ + sin ξ) / (cos θ_i + cos θ_o) − π/4.
    """
    return _RossPhase.apply(cos_xi) / (mu_i + mu_o) - _PI_4


def _li_core(sec_i, sec_o, cos_xi_p, d2, x, hb: float):
    """Li-Sparse-R (Lucht et al. 2000 eqs 39–44) from secants of the primed zeniths.

    sec_i, sec_o: sec θ'_i, sec θ'_o; cos_xi_p: cos ξ'; d2: D²;
    x: tan θ'_i tan θ'_o sin φ. All [...].
    """
    m = sec_i + sec_o  # [...]
    cos_t = hb * _safe_sqrt(d2 + x * x) / m  # eq. 18 (corrected form, docs/data-format.md)
    overlap = _LiOverlap.apply(cos_t) * m * _INV_PI  # eq. 17 / Lucht eq. 40
    return overlap - m + 0.5 * (1.0 + cos_xi_p) * sec_i * sec_o  # eq. 16 / Lucht eq. 39


def li_sparse_r_vec_terms(
    omega_i: Tensor,  # [..., 3] unit, toward the sun
    omega_o: Tensor,  # [..., 3] unit, toward the sensor (broadcasts with omega_i)
    up: Tensor | None,  # [..., 3] unit frame normal, or None for +z (scene vertical)
    mu_i: Tensor,  # [...] ω_i·up clamped to ≥ min_cos
    mu_o: Tensor,  # [...] ω_o·up clamped to ≥ min_cos
    cos_xi: Tensor,  # [...] ω_i·ω_o
    hb: float = LI_HB,  # crown relative height h/b (MODIS: 2)
    br: float = LI_BR,  # crown shape b/r (MODIS: 1)
) -> Tensor:  # [...] K_Li, unitless
    """Li-Sparse-R (paper eqs 16–19) from direction vectors and their clamped cosines in the frame ``up``.

    The in-plane vectors ``u = (ω − (ω·up) up) / μ`` have length tan θ and the azimuth
    of ω, so D² = |u_i − u_o|² (eq. 19) and tan θ_i tan θ_o sin φ = det[ω_i, ω_o, up]/(μ_i μ_o),
    both computed without cancellation near the hotspot.
    """
    if up is None:
        hi = omega_i[..., :2]  # [..., 2]
        ho = omega_o[..., :2]
        det = omega_i[..., 0] * omega_o[..., 1] - omega_i[..., 1] * omega_o[..., 0]  # [...]
    else:
        hi = omega_i - _dot(omega_i, up).unsqueeze(-1) * up  # [..., 3]
        ho = omega_o - _dot(omega_o, up).unsqueeze(-1) * up
        # det[ω_i, ω_o, up] written out (separately rounded products: exactly 0 for ω_i = ω_o)
        ix, iy, iz = omega_i.unbind(-1)
        ox, oy, oz = omega_o.unbind(-1)
        nx, ny, nz = up.unbind(-1)
        det = (iy * oz - iz * oy) * nx + (iz * ox - ix * oz) * ny + (ix * oy - iy * ox) * nz
    inv_i = 1.0 / mu_i  # [...]
    inv_o = 1.0 / mu_o
    if br == 1.0:
        diff = hi * inv_i.unsqueeze(-1) - ho * inv_o.unsqueeze(-1)
        d2 = _dot(diff, diff)
        x = det * inv_i * inv_o
        return _li_core(inv_i, inv_o, cos_xi, d2, x, hb)
    # general b/r: tan θ' = (b/r) tan θ on the same azimuth (Lucht eq. 44)
    ui = hi * (br * inv_i).unsqueeze(-1)
    uo = ho * (br * inv_o).unsqueeze(-1)
    sec_i = torch.sqrt(1.0 + _dot(ui, ui))
    sec_o = torch.sqrt(1.0 + _dot(uo, uo))
    diff = ui - uo
    d2 = _dot(diff, diff)
    x = det * (br * br) * inv_i * inv_o
    cos_xi_p = (1.0 + _dot(ui, uo)) / (sec_i * sec_o)
    return _li_core(sec_i, sec_o, cos_xi_p, d2, x, hb)


def cook_torrance_cos(
    mu_i: Tensor,  # [...] n·ω_i, NOT clamped (may be negative)
    mu_o: Tensor,  # [...] n·ω_o, NOT clamped
    cos_xi: Tensor,  # [...] ω_i·ω_o
    roughness: Tensor | float,  # [...] or float: GGX α = ρ in (0, 1]
    f0: float = F0_DIELECTRIC,  # Schlick normal-incidence reflectance (1 gives F ≡ 1)
    min_cos: float = MIN_COS,  # cosines below this use the safe denominator / ramp
) -> Tensor:  # [...] K_Cook ≥ 0, sr⁻¹
    """Cook–Torrance GGX specular kernel from unclamped cosines (paper eqs 20–23).

    With h = (ω_i + ω_o)/|ω_i + ω_o| (eq. 21): |ω_i + ω_o|² = 2 + 2 cos ξ,
    n·h = (μ_i + μ_o)/|ω_i + ω_o| and h·ω_o = sqrt((1 + cos ξ)/2), so no vector is built.
    See the module docstring for the grazing-angle ramp.
    """
    hh = (2.0 + 2.0 * cos_xi).clamp_min(_TINY)  # |ω_i+ω_o|², [...]
    s = mu_i + mu_o
    nh2 = (s * s / hh).clamp(0.0, 1.0)  # (n·h)²
    r2 = roughness * roughness
    den = nh2 * (r2 - 1.0) + 1.0  # ≥ ρ²
    d_ggx = r2 / (math.pi * den * den)  # eq. 22
    one_minus_ho = 1.0 - _safe_sqrt(0.5 * (1.0 + cos_xi))  # 1 − h·ω_o
    om2 = one_minus_ho * one_minus_ho
    fres = f0 + (1.0 - f0) * (om2 * om2 * one_minus_ho)  # eq. 23 (Schlick)
    mi = mu_i.clamp_min(min_cos)
    mo = mu_o.clamp_min(min_cos)
    ramp = (mu_i / min_cos).clamp(0.0, 1.0) * (mu_o / min_cos).clamp(0.0, 1.0)
    return d_ggx * fres * ramp / (4.0 * mi * mo)  # eq. 20


# ----------------------------------------------------------------------------------------
# Vector API
# ----------------------------------------------------------------------------------------
def frame_cosines(
    omega_i: Tensor,  # [..., 3] unit, toward the sun
    omega_o: Tensor,  # [..., 3] unit, toward the sensor
    up: Tensor | None = None,  # [..., 3] unit frame normal, or None for +z
    min_cos: float = MIN_COS,  # horizon clamp of μ
) -> tuple[Tensor, Tensor, Tensor]:  # μ_i [...], μ_o [...], cos ξ [...] (broadcast)
    """Zenith cosines in the frame ``up`` (clamped to ≥ ``min_cos``) and cos ξ = ω_i·ω_o (eq. 15)."""
    if up is None:
        mu_i = omega_i[..., 2]
        mu_o = omega_o[..., 2]
    else:
        mu_i = _dot(omega_i, up)
        mu_o = _dot(omega_o, up)
    return mu_i.clamp_min(min_cos), mu_o.clamp_min(min_cos), _dot(omega_i, omega_o)


def ross_thick(
    omega_i: Tensor,  # [..., 3] unit, toward the sun (ENU)
    omega_o: Tensor,  # [..., 3] unit, toward the sensor; broadcasts with omega_i
    up: Tensor | None = None,  # [..., 3] frame normal (topography-coupled kernel), or None for +z
    *,
    min_cos: float = MIN_COS,  # lower clamp of zenith cosines (cos 89.5°)
) -> Tensor:  # [...] K_Ross, unitless (0 for sun and view at nadir)
    """Ross-Thick volumetric kernel K_Ross (paper eqs 14–15; Lucht et al. 2000 eq. 38)."""
    mu_i, mu_o, cxi = frame_cosines(omega_i, omega_o, up, min_cos)
    return ross_thick_cos(mu_i, mu_o, cxi)


def li_sparse_r(
    omega_i: Tensor,  # [..., 3] unit, toward the sun
    omega_o: Tensor,  # [..., 3] unit, toward the sensor (broadcast)
    up: Tensor | None = None,  # [..., 3] frame normal, or None for +z
    *,
    hb: float = LI_HB,  # crown relative height h/b
    br: float = LI_BR,  # crown shape b/r
    min_cos: float = MIN_COS,  # lower clamp of zenith cosines
) -> Tensor:  # [...] K_Li, unitless (0 for sun and view at nadir, maximal at the hotspot)
    """Li-Sparse-Reciprocal geometric kernel K_Li (paper eqs 16–19; Lucht et al. 2000 eqs 39–44).

    MODIS crown shape h/b = 2, b/r = 1 by default; evaluated on primed angles
    θ' = atan((b/r) tan θ), cos t = (h/b)·sqrt(D² + (tanθ'_i tanθ'_v sinφ)²)/(secθ'_i + secθ'_v)
    clipped to [−1, 1].
    """
    omega_i, omega_o = torch.broadcast_tensors(omega_i, omega_o)
    mu_i, mu_o, cxi = frame_cosines(omega_i, omega_o, up, min_cos)
    return li_sparse_r_vec_terms(omega_i, omega_o, up, mu_i, mu_o, cxi, hb, br)


def cook_torrance(
    omega_i: Tensor,  # [..., 3] unit, toward the sun
    omega_o: Tensor,  # [..., 3] unit, toward the sensor
    normal: Tensor,  # [..., 3] unit facet normal n, NOT flipped here
    roughness: Tensor | float,  # [...] or float: ρ (GGX α) in (0, 1]
    *,
    f0: float = F0_DIELECTRIC,  # Schlick F0 (pass 1.0 for F ≡ 1)
    min_cos: float = MIN_COS,  # grazing threshold of the denominators
) -> Tensor:  # [...] K_Cook ≥ 0, sr⁻¹
    """Cook–Torrance microfacet kernel K_Cook with GGX D and Schlick F (paper eqs 20–23).

    K = D_GGX(n·h, ρ)·F(h·ω_o) / (4 (n·ω_o)(n·ω_i)), F = F0 + (1 − F0)(1 − h·ω_o)⁵. For Gaussians
    n is the smallest-scale axis flipped toward ω_o (brfgs.brdf.geometry.gaussian_normals); a sun
    or sensor behind the facet gives 0.
    """
    mu_i = _dot(omega_i, normal)
    mu_o = _dot(omega_o, normal)
    cxi = _dot(omega_i, omega_o)
    return cook_torrance_cos(mu_i, mu_o, cxi, roughness, f0, min_cos)


# ----------------------------------------------------------------------------------------
# Angle API (sun at azimuth 0, view at relative azimuth φ)
# ----------------------------------------------------------------------------------------
def directions_from_angles(
    sun_zenith_rad: Tensor | float,  # [...] rad
    view_zenith_rad: Tensor | float,  # [...] rad
    rel_azimuth_rad: Tensor | float,  # [...] rad, φ = φ_view − φ_sun
) -> tuple[Tensor, Tensor]:  # ω_i [..., 3], ω_o [..., 3] unit
    """(ω_i, ω_o) for sun zenith, view zenith and relative azimuth φ.

    The sun is put at azimuth 0 and the view at azimuth φ (docs/data-format.md: φ = φ_view − φ_sun,
    φ = 0 backscatter). Inputs are tensors or floats, broadcast together.
    """
    ts, tv, phi = torch.broadcast_tensors(
        *[torch.as_tensor(a, dtype=torch.get_default_dtype()) if not torch.is_tensor(a) else a
          for a in (sun_zenith_rad, view_zenith_rad, rel_azimuth_rad)]
    )
    zero = torch.zeros_like(ts)
    omega_i = torch.stack([zero, torch.sin(ts), torch.cos(ts)], -1)
    sv = torch.sin(tv)
    omega_o = torch.stack([sv * torch.sin(phi), sv * torch.cos(phi), torch.cos(tv)], -1)
    return omega_i, omega_o


def ross_thick_angles(
    sun_zenith_rad: Tensor | float,  # [...] rad
    view_zenith_rad: Tensor | float,  # [...] rad
    rel_azimuth_rad: Tensor | float,  # [...] rad
    *,
    min_cos: float = MIN_COS,
) -> Tensor:  # [...] K_Ross
    """K_Ross (eqs 14–15) for angles in radians (broadcast); see :func:`ross_thick`."""
    wi, wo = directions_from_angles(sun_zenith_rad, view_zenith_rad, rel_azimuth_rad)
    return ross_thick(wi, wo, min_cos=min_cos)


def li_sparse_r_angles(
    sun_zenith_rad: Tensor | float,  # [...] rad
    view_zenith_rad: Tensor | float,  # [...] rad
    rel_azimuth_rad: Tensor | float,  # [...] rad
    *,
    hb: float = LI_HB,
    br: float = LI_BR,
    min_cos: float = MIN_COS,
) -> Tensor:  # [...] K_Li
    """K_Li (eqs 16–19) for angles in radians (broadcast); see :func:`li_sparse_r`."""
    wi, wo = directions_from_angles(sun_zenith_rad, view_zenith_rad, rel_azimuth_rad)
    return li_sparse_r(wi, wo, hb=hb, br=br, min_cos=min_cos)


def cook_torrance_angles(
    sun_zenith_rad: Tensor | float,  # [...] rad
    view_zenith_rad: Tensor | float,  # [...] rad
    rel_azimuth_rad: Tensor | float,  # [...] rad
    roughness: Tensor | float,  # [...] or float: GGX α in (0, 1]
    *,
    f0: float = F0_DIELECTRIC,
    min_cos: float = MIN_COS,
) -> Tensor:  # [...] K_Cook, sr⁻¹
    """K_Cook (eqs 20–23) for a horizontal facet (n = +z), angles in radians; see :func:`cook_torrance`."""
    wi, wo = directions_from_angles(sun_zenith_rad, view_zenith_rad, rel_azimuth_rad)
    n = torch.zeros_like(wi)
    n[..., 2] = 1.0
    return cook_torrance(wi, wo, n, roughness, f0=f0, min_cos=min_cos)
