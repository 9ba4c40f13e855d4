"""MODIS MCD43-style kernel-driven BRDF parameters (RossThick–LiSparse-R) and the products made from them.

The MCD43 model (Lucht, Schaaf & Strahler 2000; MODIS BRDF/Albedo ATBD v5, Strahler et al. 1999)::

    R(θ_s, θ_v, φ, λ) = f_iso(λ) + f_vol(λ) K_vol(θ_s, θ_v, φ) + f_geo(λ) K_geo(θ_s, θ_v, φ)

with K_vol = RossThick and K_geo = LiSparse-R (h/b = 2, b/r = 1), the same kernels as the BRF-GS
head (:mod:`brfgs.brdf.kernels`, paper eqs 14–19). f = (f_iso, f_vol, f_geo) is fitted by linear
least squares to BRF samples over a direction grid (:func:`direction_grid`); MCD43's products
follow from f exactly as the ATBD defines them:

- NBAR (MCD43A4): R at nadir view (θ_v = 0) for a given sun zenith (MCD43 uses local solar noon);
- black-sky albedo (MCD43A3): α_bs(θ) = Σ_k f_k (g0_k + g1_k θ² + g2_k θ³), θ in radians, with
  the ATBD's polynomial coefficients :data:`BSA_POLY` (a fit to the kernels' directional-hemispherical
  integrals: it differs from exact quadrature, :func:`brfgs.brdf.integrals.black_sky`, by up to
  0.019 for RossThick and 0.006 for LiSparse-R at θ = 0–60°; ``brfgs products`` writes both);
- white-sky albedo: α_ws = Σ_k f_k H_k with the ATBD's integrals :data:`WSA_INTEGRALS`.

Angles in degrees in the public API; all maths in float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from numpy.typing import ArrayLike

from brfgs.brdf import kernels as K

__all__ = ["KERNELS", "BSA_POLY", "WSA_INTEGRALS", "DEFAULT_GRID", "DirectionGrid", "direction_grid",
           "design_matrix", "fit_kernel_weights", "KernelFitAccumulator", "nbar", "black_sky_albedo",
           "white_sky_albedo"]

KERNELS = ("iso", "vol", "geo")
# MODIS BRDF/Albedo ATBD (Strahler et al. 1999, Table 1; Lucht et al. 2000 eq. 49): black-sky albedo
# polynomial α_bs_k(θ) = g0 + g1 θ² + g2 θ³ (θ in rad) per kernel, and the white-sky integrals.
BSA_POLY = np.array([[1.0, 0.0, 0.0],
                     [-0.007574, -0.070987, 0.307588],
                     [-1.284909, -0.166314, 0.041840]])  # [3 kernels, 3 coefficients]
WSA_INTEGRALS = np.array([1.0, 0.189184, -1.377622])  # [3]


@dataclass(frozen=True)
class DirectionGrid:
    """Sun/view directions at which the model's BRF is sampled for the fit (all degrees).

    Every combination of sun zenith × (nadir + every view zenith > 0 × every relative azimuth);
    φ = φ_view − φ_sun (0 = backscatter). The default spans what MODIS sees over 16 days
    (sun 20–60°, views to 60°) and the full relative-azimuth circle, 45° apart: 3 × (1 + 3 × 8) = 75
    directions, with a well-conditioned design (cond(AᵀA) ≈ 140).
    """

    sun_zeniths_deg: tuple[float, ...] = (20.0, 40.0, 60.0)
    view_zeniths_deg: tuple[float, ...] = (0.0, 20.0, 40.0, 60.0)
    rel_azimuths_deg: tuple[float, ...] = field(default=tuple(float(a) for a in range(0, 360, 45)))

    def describe(self) -> dict:
        return {"sun_zeniths_deg": list(self.sun_zeniths_deg), "view_zeniths_deg": list(self.view_zeniths_deg),
                "rel_azimuths_deg": list(self.rel_azimuths_deg), "n_directions": len(direction_grid(self)[0])}


DEFAULT_GRID = DirectionGrid()


def direction_grid(grid: DirectionGrid = DEFAULT_GRID) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sun zenith, view zenith, relative azimuth) [G] in degrees; a nadir view appears once per sun."""
    s, v, a = [], [], []
    for sz in grid.sun_zeniths_deg:
        for vz in grid.view_zeniths_deg:
            for ra in (grid.rel_azimuths_deg if vz > 0 else (0.0,)):
                s.append(sz), v.append(vz), a.append(ra)
    return np.array(s, float), np.array(v, float), np.array(a, float)


def design_matrix(sun_zenith_deg: ArrayLike, view_zenith_deg: ArrayLike, rel_azimuth_deg: ArrayLike) -> np.ndarray:
    """Kernel values [G, 3] = (1, K_vol, K_geo) for each direction (degrees, broadcast to [G]); float64."""
    ts, tv, phi = (torch.as_tensor(np.radians(np.atleast_1d(np.asarray(x, float))), dtype=torch.float64)
                   for x in np.broadcast_arrays(sun_zenith_deg, view_zenith_deg, rel_azimuth_deg))
    vol = K.ross_thick_angles(ts, tv, phi)
    geo = K.li_sparse_r_angles(ts, tv, phi)
    return torch.stack([torch.ones_like(vol), vol, geo], -1).numpy()


def fit_kernel_weights(brf: ArrayLike, design: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares kernel weights of BRF samples.

    brf: [..., G] BRF at the G directions of ``design`` [G, 3]. Returns (f [..., 3] =
    (f_iso, f_vol, f_geo), rmse [...] of the fit over the G samples).
    """
    r = np.asarray(brf, float)
    a = np.asarray(design, float)
    f, *_ = np.linalg.lstsq(a, r.reshape(-1, r.shape[-1]).T, rcond=None)  # [3, P]
    f = f.T.reshape(r.shape[:-1] + (3,))
    resid = r - f @ a.T
    return f, np.sqrt(np.mean(resid ** 2, -1))


class KernelFitAccumulator:
    """Streaming least squares for maps: add the BRF maps of a few directions at a time, then solve.

    Keeps AᵀA [3, 3], Aᵀr [3, P] and Σ r² [P] in float64 (32 bytes per map value P), so a fit over
    G directions never holds G maps; each batch is one matrix product. The residual follows from
    the normal equations: Σ (r − a·f)² = Σ r² − f·Aᵀr.
    """

    def __init__(self) -> None:
        self.ata = torch.zeros(3, 3, dtype=torch.float64)
        self.atr: torch.Tensor | None = None
        self.r2: torch.Tensor | None = None
        self.shape: tuple[int, ...] = ()
        self.n = 0

    def add(self, brf: ArrayLike, kernels_rows: ArrayLike) -> None:
        """brf: [k, ...] BRF maps at k directions; kernels_rows: [k, 3] = (1, K_vol, K_geo) there."""
        a = torch.as_tensor(np.asarray(kernels_rows, float)).reshape(-1, 3)          # [k, 3]
        r = torch.as_tensor(np.asarray(brf), dtype=torch.float64)                    # [k, ...]
        if r.shape[0] != a.shape[0]:
            raise ValueError(f"{r.shape[0]} BRF maps for {a.shape[0]} kernel rows")
        if self.atr is None:
            self.shape = tuple(r.shape[1:])
            self.atr = torch.zeros(3, r[0].numel(), dtype=torch.float64)
            self.r2 = torch.zeros(r[0].numel(), dtype=torch.float64)
        r = r.reshape(a.shape[0], -1)                                                 # [k, P]
        self.ata += a.T @ a
        self.atr.addmm_(a.T, r)
        self.r2 += (r * r).sum(0)
        self.n += a.shape[0]

    def solve(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(f [..., 3], rmse [...], condition number of AᵀA)."""
        if self.n < 3 or self.atr is None:
            raise ValueError("a kernel fit needs at least three directions")
        f = torch.linalg.solve(self.ata, self.atr)                                    # [3, P]
        sse = (self.r2 - (f * self.atr).sum(0)).clamp_min(0.0)
        rmse = torch.sqrt(sse / self.n)
        return (f.T.reshape(self.shape + (3,)).numpy(), rmse.reshape(self.shape).numpy(),
                float(torch.linalg.cond(self.ata)))


def nbar(f: ArrayLike, sun_zenith_deg: float) -> np.ndarray:
    """Nadir BRDF-adjusted reflectance [...] of weights f [..., 3] for a sun zenith (deg)."""
    k = design_matrix(sun_zenith_deg, 0.0, 0.0).reshape(3)
    return np.asarray(f, float) @ k


def black_sky_albedo(f: ArrayLike, sun_zenith_deg: float) -> np.ndarray:
    """MCD43 black-sky (directional-hemispherical) albedo [...] of f [..., 3] (ATBD polynomial)."""
    t = math.radians(sun_zenith_deg)
    g = BSA_POLY @ np.array([1.0, t * t, t ** 3])  # [3]
    return np.asarray(f, float) @ g


def white_sky_albedo(f: ArrayLike) -> np.ndarray:
    """MCD43 white-sky (bihemispherical) albedo [...] of f [..., 3]."""
    return np.asarray(f, float) @ WSA_INTEGRALS
