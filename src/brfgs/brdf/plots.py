"""Kernel values on a view grid, their CSV, and the reference figure of ``brfgs kernels``.

The figure is the one users know from the BRDF literature (e.g. Lucht et al. 2000,
Wanner et al. 1995): each kernel along the principal plane (signed view zenith, + on the
sun's side/backscatter, − forward) and as a polar map over the view hemisphere (radius =
view zenith, angle = relative azimuth φ = φ_view − φ_sun, φ = 0 at the top, clockwise).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from brfgs.brdf import kernels as K
from brfgs.data import atomic
from brfgs.data.figures import pyplot

__all__ = ["KernelGrid", "kernel_grid", "principal_plane", "write_kernel_csv", "plot_kernels", "CSV_COLUMNS"]

CSV_COLUMNS = ("sun_zenith_deg", "view_zenith_deg", "relative_azimuth_deg", "k_ross", "k_li", "k_cook")


@dataclass
class KernelGrid:
    """Kernels on a polar view grid. Arrays are [n_zenith, n_azimuth] (float64)."""

    sun_zenith_deg: float
    roughness: float
    view_zenith_deg: np.ndarray  # [Z]
    relative_azimuth_deg: np.ndarray  # [A]
    k_ross: np.ndarray  # [Z, A]
    k_li: np.ndarray
    k_cook: np.ndarray


def _eval(sun_zenith_deg: float, view_zenith_deg, rel_az_deg, roughness: float):
    ts = torch.tensor(math.radians(sun_zenith_deg), dtype=torch.float64)
    tv = torch.as_tensor(np.deg2rad(view_zenith_deg), dtype=torch.float64)
    ph = torch.as_tensor(np.deg2rad(rel_az_deg), dtype=torch.float64)
    with torch.no_grad():
        kr = K.ross_thick_angles(ts, tv, ph).numpy()
        kl = K.li_sparse_r_angles(ts, tv, ph).numpy()
        kc = K.cook_torrance_angles(ts, tv, ph, float(roughness)).numpy()
    return kr, kl, kc


def kernel_grid(
    sun_zenith_deg: float, roughness: float = 0.3, step_deg: float = 2.0, max_view_zenith_deg: float = 80.0
) -> KernelGrid:
    """Kernels for view zenith 0..max (step) × relative azimuth 0..360−step (step), degrees.

    K_Cook is for a horizontal facet (n = +z), F0 = 0.04, GGX roughness ``roughness``.
    """
    vz = np.arange(0.0, max_view_zenith_deg + 1e-9, step_deg)
    az = np.arange(0.0, 360.0 - 1e-9, step_deg)
    tv, ph = np.meshgrid(vz, az, indexing="ij")
    kr, kl, kc = _eval(sun_zenith_deg, tv, ph, roughness)
    return KernelGrid(float(sun_zenith_deg), float(roughness), vz, az, kr, kl, kc)


def principal_plane(
    sun_zenith_deg: float,  # deg
    roughness: float = 0.3,  # GGX α of K_Cook (horizontal facet)
    max_view_zenith_deg: float = 80.0,  # deg
    n: int = 641,  # samples
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # signed view zenith [n] deg, K_Ross, K_Li, K_Cook [n]
    """The three kernels (eqs 14–23) along the principal plane (signed view zenith: + on the sun's side)."""
    signed = np.linspace(-max_view_zenith_deg, max_view_zenith_deg, n)
    phi = np.where(signed >= 0, 0.0, 180.0)
    kr, kl, kc = _eval(sun_zenith_deg, np.abs(signed), phi, roughness)
    return signed, kr, kl, kc


def write_kernel_csv(path: str | Path, grid: KernelGrid) -> None:
    """CSV with columns :data:`CSV_COLUMNS`, one row per grid node (zenith-major)."""
    path = Path(path)
    with atomic.open_text(path, newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for i, vz in enumerate(grid.view_zenith_deg):
            for j, az in enumerate(grid.relative_azimuth_deg):
                w.writerow(
                    [
                        f"{grid.sun_zenith_deg:g}",
                        f"{vz:g}",
                        f"{az:g}",
                        repr(float(grid.k_ross[i, j])),
                        repr(float(grid.k_li[i, j])),
                        repr(float(grid.k_cook[i, j])),
                    ]
                )


def plot_kernels(path: str | Path, grid: KernelGrid, dpi: int = 120) -> None:
    """Save the 2×3 reference figure (principal plane on top, polar maps below) as PNG."""
    plt = pyplot()
    ts = grid.sun_zenith_deg
    vmax = float(grid.view_zenith_deg[-1])
    signed, pr, pl, pc = principal_plane(ts, grid.roughness, vmax)
    names = [
        ("RossThick  $K_{vol}$", pr, grid.k_ross, "tab:green"),
        ("LiSparse-R  $K_{geo}$ (h/b=2, b/r=1)", pl, grid.k_li, "tab:brown"),
        (f"Cook–Torrance GGX  $K_{{spec}}$ (ρ={grid.roughness:g}, F0=0.04)", pc, grid.k_cook, "tab:blue"),
    ]
    fig = plt.figure(figsize=(15, 9.5))
    fig.suptitle(f"BRDF kernels, sun zenith {ts:g}° (principal plane and view hemisphere)", fontsize=13)
    # polar grid edges
    az_edges = np.deg2rad(np.append(grid.relative_azimuth_deg, 360.0) - 0.5 * (grid.relative_azimuth_deg[1] - grid.relative_azimuth_deg[0]))
    dz = grid.view_zenith_deg[1] - grid.view_zenith_deg[0] if len(grid.view_zenith_deg) > 1 else 1.0
    zen_edges = np.clip(np.append(grid.view_zenith_deg - 0.5 * dz, grid.view_zenith_deg[-1] + 0.5 * dz), 0, None)
    for col, (title, pp, values, color) in enumerate(names):
        ax = fig.add_subplot(2, 3, col + 1)
        ax.plot(signed, pp, color=color, lw=2)
        ax.axvline(ts, color="orange", ls="--", lw=1, label=f"hotspot (+{ts:g}°)")
        if ts > 0:
            ax.axvline(-ts, color="gray", ls=":", lw=1, label=f"specular (−{ts:g}°)")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlim(-vmax, vmax)
        ax.set_xlabel("view zenith on the principal plane (°)\n← forward scatter   |   backscatter (sun side) →")
        ax.set_ylabel("kernel value")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")

        pax = fig.add_subplot(2, 3, col + 4, projection="polar")
        pax.set_theta_zero_location("N")
        pax.set_theta_direction(-1)
        mesh = pax.pcolormesh(az_edges, zen_edges, values, shading="flat", cmap="viridis")
        try:
            theta_c = np.deg2rad(np.append(grid.relative_azimuth_deg, 360.0))
            vals_c = np.concatenate([values, values[:, :1]], axis=1)
            cs = pax.contour(theta_c, grid.view_zenith_deg, vals_c, levels=8, colors="white", linewidths=0.6)
            pax.clabel(cs, fontsize=6, fmt="%.2f")
        except Exception:  # pragma: no cover - contouring is decoration only
            pass
        pax.plot([0.0], [ts], marker="*", color="orange", ms=14, mec="k", label="sun (hotspot)")
        pax.set_ylim(0, vmax)
        pax.set_yticks([z for z in (20, 40, 60, 80) if z <= vmax])
        pax.set_yticklabels([f"{z}°" for z in (20, 40, 60, 80) if z <= vmax], fontsize=7)
        pax.set_xticks(np.deg2rad([0, 90, 180, 270]))
        pax.set_xticklabels(["φ=0° (back)", "90°", "180° (forward)", "270°"], fontsize=8)
        fig.colorbar(mesh, ax=pax, shrink=0.75, pad=0.1)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    atomic.save_figure(fig, path, dpi=dpi)
    plt.close(fig)
