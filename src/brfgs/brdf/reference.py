"""Naive reference of the hybrid head: angles first, textbook formulas, no fusion.

This is the straightforward way to write eq. 12: convert every direction to zenith and
azimuth angles (acos, atan2), evaluate Ross-Thick / Li-Sparse-R on the angles exactly as
printed in Lucht et al. (2000) eqs 38–44, build the half vector of Cook–Torrance
explicitly, and sum the four terms. It is used as the speed baseline of
:func:`brfgs.brdf.bench.bench_head` (in float64) and as a cross-check of the fast head in
the tests. It is not safe at the edge angles (nadir, hotspot) for gradients — that is
what :mod:`brfgs.brdf.kernels` is for.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["ross_thick_ref", "li_sparse_r_ref", "cook_torrance_ref", "hybrid_latent_ref"]


def ross_thick_ref(
    ti: Tensor,  # [...] sun zenith, rad
    tv: Tensor,  # [...] view zenith, rad
    phi: Tensor,  # [...] relative azimuth, rad
) -> Tensor:  # [...] K_Ross
    """Ross-Thick on angles (paper eqs 14–15; Lucht et al. 2000 eq. 38)."""
    cos_xi = torch.cos(ti) * torch.cos(tv) + torch.sin(ti) * torch.sin(tv) * torch.cos(phi)
    xi = torch.acos(cos_xi.clamp(-1, 1))
    return ((math.pi / 2 - xi) * torch.cos(xi) + torch.sin(xi)) / (torch.cos(ti) + torch.cos(tv)) - math.pi / 4


def li_sparse_r_ref(
    ti: Tensor,  # [...] sun zenith, rad
    tv: Tensor,  # [...] view zenith, rad
    phi: Tensor,  # [...] relative azimuth, rad
    hb: float = 2.0,  # crown relative height h/b
    br: float = 1.0,  # crown shape b/r
) -> Tensor:  # [...] K_Li
    """Li-Sparse-Reciprocal on angles (paper eqs 16–19; Lucht et al. 2000 eqs 39–44)."""
    tip = torch.atan(br * torch.tan(ti))
    tvp = torch.atan(br * torch.tan(tv))
    cos_xip = torch.cos(tip) * torch.cos(tvp) + torch.sin(tip) * torch.sin(tvp) * torch.cos(phi)
    d = torch.sqrt(
        (torch.tan(tip) ** 2 + torch.tan(tvp) ** 2 - 2 * torch.tan(tip) * torch.tan(tvp) * torch.cos(phi)).clamp_min(0)
    )
    sec_sum = 1 / torch.cos(tip) + 1 / torch.cos(tvp)
    cos_t = hb * torch.sqrt(d**2 + (torch.tan(tip) * torch.tan(tvp) * torch.sin(phi)) ** 2) / sec_sum
    t = torch.acos(cos_t.clamp(-1, 1))
    overlap = (t - torch.sin(t) * torch.cos(t)) * sec_sum / math.pi
    return overlap - sec_sum + 0.5 * (1 + cos_xip) / (torch.cos(tip) * torch.cos(tvp))


def cook_torrance_ref(
    omega_i: Tensor,  # [..., 3] unit, toward the sun
    omega_o: Tensor,  # [..., 3] unit, toward the sensor
    n: Tensor,  # [..., 3] unit normal
    rho: Tensor | float,  # [...] roughness ρ
    f0: float = 0.04,  # Schlick F0
) -> Tensor:  # [...] K_Cook, sr⁻¹
    """Cook–Torrance GGX/Schlick with an explicit half vector (paper eqs 20–23)."""
    h = omega_i + omega_o
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True)
    nh = (n * h).sum(-1)
    d = rho**2 / (math.pi * (nh**2 * (rho**2 - 1) + 1) ** 2)
    f = f0 + (1 - f0) * (1 - (h * omega_o).sum(-1)) ** 5
    return d * f / (4 * (n * omega_o).sum(-1) * (n * omega_i).sum(-1))


def hybrid_latent_ref(
    z_iso: Tensor,  # [N, d]
    z_vol: Tensor,  # [N, d]
    z_geo: Tensor,  # [N, d]
    z_spec: Tensor,  # [N, d]
    rho: Tensor,  # [N] roughness ρ
    normals: Tensor,  # [N, 3] unit, facing ω_o
    omega_i: Tensor,  # [3] or [N, 3] unit, toward the sun
    omega_o: Tensor,  # [N, 3] unit, toward the camera
) -> Tensor:  # [N, d]
    """Eq. 12 the naive way (vertical frame, all four components)."""
    omega_i = omega_i.expand_as(omega_o)
    ti = torch.acos(omega_i[:, 2])
    to = torch.acos(omega_o[:, 2])
    phi = torch.atan2(omega_o[:, 0], omega_o[:, 1]) - torch.atan2(omega_i[:, 0], omega_i[:, 1])
    k_ross = ross_thick_ref(ti, to, phi)
    k_li = li_sparse_r_ref(ti, to, phi)
    k_cook = cook_torrance_ref(omega_i, omega_o, normals, rho)
    return z_iso + z_vol * k_ross[:, None] + z_geo * k_li[:, None] + z_spec * k_cook[:, None]
