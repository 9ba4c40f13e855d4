"""MODIS MCD43-style parameter maps: f_iso, f_vol, f_geo per map pixel and band, fitted to the model's BRF.

For every direction (θ_s, θ_v, φ) of a :class:`brfgs.brdf.mcd43.DirectionGrid` the model's BRF map is
rendered from the nadir product camera exactly as the NBAR product is (each Gaussian's latent
evaluated for the sun at θ_s and the *same* view direction (θ_v, φ_sun + φ) for every Gaussian,
blended with the nadir camera's weights, decoded per pixel, paper eqs 12–13). The RossThick–LiSparse-R
weights are fitted per pixel and band by linear least squares over those maps
(:class:`brfgs.brdf.mcd43.KernelFitAccumulator`), with the RMSE of the fit; NBAR and black/white-sky
albedo follow from the weights as MCD43 defines them (:mod:`brfgs.brdf.mcd43`).

A model with a linear spectral basis (D(z) = W z + b) needs no fit: its BRF in every band is the kernel
model (plus the specular lobe) with each Gaussian's own weights f_iso = W z_iso + b, f_vol = W z_vol,
f_geo = W z_geo (f_spec = W z_spec, the Cook–Torrance weight), so the maps are those per-Gaussian
quantities rendered from the same camera (blended, the latent background composited into f_iso, as
the contribution maps are). ``fit_rmse`` is then the RMS over the grid of what the three kernels do
not hold — the specular lobe (zero without one). Models whose Ross/Li kernels are evaluated in each
Gaussian's normal frame are fitted.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from brfgs.products.maps import _MapRenderer, component_latents, require_hybrid
from brfgs.spectral.decoders import is_linear
from brfgs.brdf import mcd43 as M
from brfgs.data.angles import direction_from_angles_deg
from brfgs.model import Camera, TrainedModel

__all__ = ["MCD43_NAMES", "MCD43_METHODS", "render_mcd43", "exact_weights_available"]

MCD43_NAMES = ("f_iso", "f_vol", "f_geo", "fit_rmse", "nbar_mcd43", "bsa_mcd43", "wsa_mcd43")
MCD43_METHODS = ("auto", "fit", "exact")


def _grid_directions(tm: TrainedModel, grid: M.DirectionGrid) -> tuple[np.ndarray, Tensor, Tensor]:
    """(design [G, 3], sun directions ω_i [G, 3], view directions ω_o [G, 3]) for the model's sun azimuth."""
    sz, vz, ra = M.direction_grid(grid)
    design = M.design_matrix(sz, vz, ra)
    az_sun = np.full_like(sz, tm.sun_azimuth_deg)
    omega_i = torch.as_tensor(direction_from_angles_deg(sz, az_sun), dtype=torch.float32)
    omega_o = torch.as_tensor(direction_from_angles_deg(vz, az_sun + ra), dtype=torch.float32)
    return design, omega_i, omega_o


def exact_weights_available(tm: TrainedModel) -> bool:
    """Whether the model's kernel weights are exact per-Gaussian quantities: a linear spectral basis and
    the Ross/Li kernels in the vertical frame."""
    return is_linear(tm.decoder) and not tm.head_cfg.normal_frame


def _exact_maps(mr: _MapRenderer, design: np.ndarray, omega_i: Tensor, omega_o: Tensor, batch: int,
                progress: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, Tensor]:
    """(f [H, W, B, 3], RMS of the specular lobe over the grid [H, W, B], f_spec [H, W, B] or None, alpha)
    of a model with a linear basis: its per-Gaussian weights rendered (module docstring)."""
    tm = mr.tm
    d = tm.gaussians.latent_dim
    comps = [c for c in ("iso", "vol", "geo", "spec") if c in tm.head_cfg.components]

    def fn(idx: Tensor, oo: Tensor) -> Tensor:  # [n, d·|comps|]
        p = tm.head_params(idx)
        return torch.cat([p[f"z_{c}"] for c in comps], -1)

    lat, alpha = mr.latents(fn)
    part = {c: lat[..., j * d:(j + 1) * d] for j, c in enumerate(comps)}
    low = alpha.numpy() < mr.min_alpha

    def weight(z: Tensor) -> np.ndarray:  # W z [H, W, B], NaN where alpha < min_alpha
        w = tm.decoder.decode_weights(z).numpy().astype(np.float64)
        w[low] = np.nan
        return w

    zero = torch.zeros_like(lat[..., :d])
    f_iso = mr.decode(part.get("iso", zero), alpha).astype(np.float64)  # W (Z_iso + (1 - α) bg) + b
    f = np.stack([f_iso, weight(part.get("vol", zero)), weight(part.get("geo", zero))], -1)
    f_spec = weight(part["spec"]) if "spec" in part else None
    sq = np.zeros(f_iso.shape)
    if f_spec is not None:  # what the kernel model leaves out: the specular lobe at each grid direction
        for s in tqdm(range(0, len(design), batch), desc="MCD43 residual", leave=False, disable=not progress):
            sel = range(s, min(s + batch, len(design)))

            def spec_fn(idx: Tensor, oo: Tensor) -> Tensor:  # [n, d·|sel|]
                n = int(idx.numel())
                return torch.cat([component_latents(tm, idx, omega_i[g], omega_o[g].expand(n, 3).contiguous())["spec"]
                                  for g in sel], -1)

            lobe, _ = mr.latents(spec_fn)
            for j in range(len(sel)):
                sq += weight(lobe[..., j * d:(j + 1) * d]) ** 2
    rmse = np.sqrt(sq / len(design))
    rmse[low] = np.nan
    return f, rmse, f_spec, alpha


def _fitted_maps(mr: _MapRenderer, design: np.ndarray, omega_i: Tensor, omega_o: Tensor, batch: int,
                 progress: bool) -> tuple[np.ndarray, np.ndarray, float, Tensor]:
    """(f [H, W, B, 3], fit RMSE [H, W, B], cond(AᵀA), alpha): the least-squares fit over the grid's BRF maps."""
    tm = mr.tm
    d = tm.gaussians.latent_dim
    acc = M.KernelFitAccumulator()
    alpha = None
    for s in tqdm(range(0, len(design), batch), desc="MCD43 fit", leave=False, disable=not progress):
        sel = range(s, min(s + batch, len(design)))

        def fn(idx: Tensor, oo: Tensor) -> Tensor:  # [n, d·|sel|]
            n = int(idx.numel())
            return torch.cat([tm.gaussian_latent(omega_i[g], omega_o[g].expand(n, 3).contiguous(), idx)
                              for g in sel], -1)

        lat, alpha = mr.latents(fn)
        acc.add(np.stack([mr.decode(lat[..., j * d:(j + 1) * d], alpha) for j in range(len(sel))]),
                design[list(sel)])
    f, rmse, cond = acc.solve()
    return f, rmse, cond, alpha


@torch.no_grad()
def render_mcd43(
    tm: TrainedModel,
    cam: Camera,
    *,
    nbar_sun_zenith_deg: float,
    albedo_sun_zenith_deg: float,
    grid: M.DirectionGrid = M.DEFAULT_GRID,
    backend: str = "auto",
    min_alpha: float = 0.5,
    batch: int = 8,
    progress: bool = False,
    method: str = "auto",
) -> dict:
    """MCD43-style maps for one camera (usually :func:`brfgs.products.maps.nadir_camera`).

    Returns {name: [H, W, B] float32} for :data:`MCD43_NAMES` (and "f_spec" when the weights are exact
    and the model has a specular term), "alpha" [H, W], and "settings" (the method, the grid, its number
    of directions, the condition number of AᵀA). NaN where alpha < min_alpha. ``method``: "fit" (least
    squares over the grid), "exact" (a linear basis' own weights, :func:`exact_weights_available`) or
    "auto" (exact where available). Memory: 32 bytes per map value (H·W·B).
    """
    require_hybrid(tm)
    if method not in MCD43_METHODS:
        raise ValueError(f"method must be one of {MCD43_METHODS}, got {method!r}")
    exact = exact_weights_available(tm) if method == "auto" else method == "exact"
    if exact and not exact_weights_available(tm):
        raise ValueError("exact kernel weights need a linear spectral basis and kernels in the vertical frame")
    mr = _MapRenderer(tm, cam, backend, min_alpha)
    design, omega_i, omega_o = _grid_directions(tm, grid)
    out: dict = {}
    if exact:
        f, rmse, f_spec, alpha = _exact_maps(mr, design, omega_i, omega_o, batch, progress)
        cond = float(np.linalg.cond(design.T @ design))
        if f_spec is not None:
            out["f_spec"] = f_spec.astype(np.float32)
    else:
        f, rmse, cond, alpha = _fitted_maps(mr, design, omega_i, omega_o, batch, progress)
    out.update({name: f[..., k].astype(np.float32) for k, name in enumerate(("f_iso", "f_vol", "f_geo"))})
    out["fit_rmse"] = rmse.astype(np.float32)
    out["nbar_mcd43"] = M.nbar(f, nbar_sun_zenith_deg).astype(np.float32)
    out["bsa_mcd43"] = M.black_sky_albedo(f, albedo_sun_zenith_deg).astype(np.float32)
    out["wsa_mcd43"] = M.white_sky_albedo(f).astype(np.float32)
    out["alpha"] = alpha.numpy()
    out["settings"] = {"method": "exact" if exact else "fit",
                       "weights": "each Gaussian's own weights of the linear spectral basis, rendered; fit_rmse: the "
                       "specular lobe over the grid" if exact else "least squares over the grid's BRF maps",
                       "grid": grid.describe(), "sun_azimuth_deg": tm.sun_azimuth_deg,
                       "design_condition_number": cond, "nbar_sun_zenith_deg": nbar_sun_zenith_deg,
                       "albedo_sun_zenith_deg": albedo_sun_zenith_deg, "min_alpha": min_alpha,
                       "kernels": "RossThick, LiSparse-R (h/b = 2, b/r = 1); MCD43 ATBD albedo polynomials"}
    return out
