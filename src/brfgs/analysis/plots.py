"""Figures and tables of the analysis (matplotlib, Agg backend; PNG + CSV).

- :func:`plot_principal_plane` — Fig. 8: BRF vs signed view zenith per band, observations
  nearest the plane as points, the sun's zenith as a dashed line (hotspot side +).
- :func:`plot_polar` — Fig. 9: polar heatmap over the view hemisphere per band, north up,
  azimuth clockwise, the sun as a red star.
- :func:`plot_polar_truth` — per band: the model's polar map, the simulator's truth on its
  (coarser) grid with the same colour scale, and model − truth on the truth grid.
- :func:`plot_spectra` — Fig. 7: mean reconstructed vs observed (and truth) spectrum with the
  logarithmic error.
- image writers for CIR composites, depth and normal maps, and product maps.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
from numpy.typing import ArrayLike
from PIL import Image

matplotlib.use("Agg", force=False)  # figures are written to files; must precede pyplot
import matplotlib.pyplot as plt  # noqa: E402
from brfgs.data import atomic

__all__ = [
    "PolarGrid",
    "write_csv",
    "save_rgb_png",
    "save_depth_png",
    "save_normal_png",
    "save_map_png",
    "plot_principal_plane",
    "plot_polar",
    "plot_polar_truth",
    "plot_spectra",
]


@dataclass
class PolarGrid:
    """Values [Z, A, nb] at the cell centres of a polar grid: zenith_deg [Z], azimuth_deg [A]."""

    zenith_deg: np.ndarray
    azimuth_deg: np.ndarray
    values: np.ndarray


@dataclass
class _Sky:
    """What every polar panel shares: the largest zenith shown and the sun (degrees)."""

    zmax: float
    sun_zenith_deg: float
    sun_azimuth_deg: float


def write_csv(path: str | Path, header: list[str], rows: Iterable[Sequence]) -> Path:
    """Write rows (iterables) under ``header``; numbers with 6 significant digits, NaN as empty."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic.open_text(path, newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for r in rows:
            w.writerow(["" if (isinstance(v, float) and not np.isfinite(v)) else
                        (f"{v:.6g}" if isinstance(v, (float, np.floating)) else v) for v in r])
    return path


def save_rgb_png(path: str | Path, rgb: np.ndarray) -> Path:
    """RGB [H, W, 3] in [0, 1] (NaN → black) as an 8-bit PNG."""
    a = np.nan_to_num(np.asarray(rgb, float), nan=0.0)
    img = (np.clip(a, 0, 1) * 255 + 0.5).astype(np.uint8)
    path = Path(path)
    with atomic.atomic_path(path) as tmp:
        Image.fromarray(img).save(tmp, format="PNG")
    return path


def save_depth_png(path: str | Path, depth_m: np.ndarray, alpha: np.ndarray | None = None) -> Path:
    """Depth map with the viridis colormap over its 2–98 % range (near = bright); empty = black."""
    d = np.asarray(depth_m, float)
    ok = np.isfinite(d) & (d > 0)
    if alpha is not None:
        ok &= np.asarray(alpha) > 0.5
    rgb = np.zeros(d.shape + (3,))
    if ok.any():
        lo, hi = np.percentile(d[ok], [2, 98])
        t = np.clip((hi - d) / max(hi - lo, 1e-9), 0, 1)
        rgb = plt.get_cmap("viridis")(t)[..., :3]
        rgb[~ok] = 0
    return save_rgb_png(path, rgb)


def save_normal_png(path: str | Path, normal: np.ndarray) -> Path:
    """World normals [H, W, 3] (ENU) as RGB = (n + 1) / 2; zero normals black."""
    n = np.asarray(normal, float)
    rgb = np.where(np.linalg.norm(n, axis=-1, keepdims=True) > 0, 0.5 * (n + 1.0), 0.0)
    return save_rgb_png(path, rgb)


def save_map_png(path: str | Path, band: np.ndarray, title: str, *, diverging: bool = False, label: str = "") -> Path:
    """One band [H, W] as a PNG with a colour bar (diverging: symmetric RdBu_r around 0)."""
    b = np.asarray(band, float)
    ok = np.isfinite(b)
    fig, ax = plt.subplots(figsize=(5.2, 4.4), dpi=100)
    if diverging:
        v = float(np.nanpercentile(np.abs(b[ok]), 99)) if ok.any() else 1.0
        im = ax.imshow(b, cmap="RdBu_r", vmin=-max(v, 1e-9), vmax=max(v, 1e-9))
    else:
        lo, hi = (np.nanpercentile(b[ok], [1, 99]) if ok.any() else (0.0, 1.0))
        im = ax.imshow(b, cmap="viridis", vmin=lo, vmax=max(hi, lo + 1e-9))
    fig.colorbar(im, ax=ax, label=label)
    ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])
    return _finish(fig, path, "")


def plot_principal_plane(path: str | Path, signed_zenith_deg: np.ndarray, values: np.ndarray,
                         wavelengths_nm: np.ndarray, sun_zenith_deg: float, *, title: str = "",
                         obs_signed_zenith_deg: ArrayLike | None = None, obs_values: ArrayLike | None = None,
                         truth_values: ArrayLike | None = None, truth_signed_zenith_deg: ArrayLike | None = None,
                         truth_curve_signed_zenith_deg: ArrayLike | None = None,
                         truth_curve_values: ArrayLike | None = None) -> Path:
    """Fig. 8: one panel per band. values [D, nb]; obs_values [M, nb] (observations nearest the
    plane); truth_values [K, nb] (truth at those frames); truth_curve_values [T, nb] (the
    simulator's truth rendered along the plane)."""
    nb = values.shape[1]
    ncol = min(nb, 4)
    nrow = int(np.ceil(nb / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.0 * nrow), dpi=100, squeeze=False)
    for j in range(nb):
        ax = axes[j // ncol][j % ncol]
        ax.plot(signed_zenith_deg, values[:, j], "-", color="C0", label="BRF-GS")
        if obs_values is not None and len(obs_values):
            ax.plot(obs_signed_zenith_deg, np.asarray(obs_values)[:, j], "o", color="k", ms=4, label="observed")
        if truth_values is not None and len(truth_values):
            ax.plot(truth_signed_zenith_deg, np.asarray(truth_values)[:, j], "x", color="C3", ms=5,
                    label="truth (frames)")
        if truth_curve_values is not None and len(truth_curve_values):
            ax.plot(truth_curve_signed_zenith_deg, np.asarray(truth_curve_values)[:, j], "--", color="C3", lw=1,
                    marker=".", ms=4, label="truth (simulator)")
        ax.axvline(sun_zenith_deg, ls="--", color="orange", lw=1, label="sun zenith")
        ax.axvline(-sun_zenith_deg, ls=":", color="orange", lw=0.8)
        ax.set_title(f"{wavelengths_nm[j]:.0f} nm", fontsize=9)
        ax.set_xlabel("view zenith (°), + = sun side")
        ax.set_ylabel("BRF")
        ax.grid(alpha=0.3)
        if j == 0:
            ax.legend(fontsize=7)
    return _finish(fig, path, title, axes, nb)


def plot_polar(path: str | Path, zenith_deg: np.ndarray, azimuth_deg: np.ndarray, values: np.ndarray,
               wavelengths_nm: np.ndarray, sun_zenith_deg: float, sun_azimuth_deg: float, *, title: str = "",
               max_zenith_deg: float | None = None) -> Path:
    """Fig. 9: polar heatmaps [Z, A, nb] (cell centres), north up, azimuth clockwise; sun = red star."""
    nb = values.shape[2]
    ncol = min(nb, 4)
    nrow = int(np.ceil(nb / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.7 * ncol, 3.5 * nrow), dpi=100, squeeze=False,
                             subplot_kw={"projection": "polar"})
    zmax = max_zenith_deg if max_zenith_deg is not None else float(_polar_edges(zenith_deg, azimuth_deg)[0][-1])
    sky = _Sky(zmax, sun_zenith_deg, sun_azimuth_deg)
    for j in range(nb):
        lo, hi = _robust_range(values[:, :, j])
        _polar_panel(fig, axes[j // ncol][j % ncol], PolarGrid(zenith_deg, azimuth_deg, values[:, :, j]), sky,
                     vmin=lo, vmax=hi, cmap="inferno", title=f"{wavelengths_nm[j]:.0f} nm")
    return _finish(fig, path, title, axes, nb)


def _robust_range(v: np.ndarray) -> tuple[float, float]:
    """(1st, 99th) percentile of the finite values of ``v`` (0, 1 if none), with hi > lo."""
    ok = np.isfinite(v)
    lo, hi = (np.nanpercentile(v[ok], [1, 99]) if ok.any() else (0.0, 1.0))
    return float(lo), float(max(hi, lo + 1e-9))


def _finish(fig, path: str | Path, title: str, axes=None, used: int = 0, **savefig) -> Path:
    """Blank the unused panels of a grid ``axes`` (beyond the first ``used``), add the title, save, close."""
    if axes is not None:
        ncol = len(axes[0])
        for j in range(used, len(axes) * ncol):
            axes[j // ncol][j % ncol].axis("off")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    atomic.save_figure(fig, path, **savefig)
    plt.close(fig)
    return Path(path)


def _polar_edges(zenith_deg: np.ndarray, azimuth_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cell edges (zenith deg, azimuth rad) of a grid given by its cell centres."""
    zenith_deg = np.asarray(zenith_deg, float)
    azimuth_deg = np.asarray(azimuth_deg, float)
    dz = float(zenith_deg[1] - zenith_deg[0]) if len(zenith_deg) > 1 else float(2 * zenith_deg[0])
    da = float(azimuth_deg[1] - azimuth_deg[0]) if len(azimuth_deg) > 1 else 360.0
    z_edges = np.concatenate([[zenith_deg[0] - dz / 2], zenith_deg + dz / 2])
    a_edges = np.deg2rad(np.concatenate([[azimuth_deg[0] - da / 2], azimuth_deg + da / 2]))
    return z_edges, a_edges


def _polar_panel(fig, ax, grid: PolarGrid, sky: _Sky, *, vmin: float, vmax: float, cmap: str, title: str,
                 label: str = "") -> None:
    """One polar heatmap of ``grid.values`` [Z, A] (north up, azimuth clockwise), the sun as a red star."""
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    z_edges, a_edges = _polar_edges(grid.zenith_deg, grid.azimuth_deg)
    pc = ax.pcolormesh(a_edges, z_edges, np.ma.masked_invalid(grid.values), cmap=cmap, vmin=vmin, vmax=vmax,
                       shading="flat")
    if sky.sun_zenith_deg <= sky.zmax:
        ax.plot([np.deg2rad(sky.sun_azimuth_deg)], [sky.sun_zenith_deg], marker="*", color="red", ms=11,
                markeredgecolor="white")
    ax.set_ylim(0, sky.zmax)
    ax.set_title(title, fontsize=8, pad=10)
    ax.tick_params(labelsize=6)
    fig.colorbar(pc, ax=ax, shrink=0.7, pad=0.1, label=label)


def plot_polar_truth(
    path: str | Path,
    model: PolarGrid,  # values [Z, A, nb]
    truth: PolarGrid,  # values [Zt, At, nb]
    model_at_truth: np.ndarray,  # [Zt, At, nb]
    wavelengths_nm: np.ndarray,  # [nb]
    sun_zenith_deg: float,
    sun_azimuth_deg: float,
    *,
    title: str = "",
    max_zenith_deg: float | None = None,
) -> Path:
    """One row per band: the model's polar map | the simulator's truth on its (coarser) grid (same
    colour scale) | model − truth on the truth grid (``model_at_truth``, diverging scale)."""
    nb = model.values.shape[2]
    fig, axes = plt.subplots(nb, 3, figsize=(11.0, 3.4 * nb), dpi=100, squeeze=False,
                             subplot_kw={"projection": "polar"})
    zmax = max_zenith_deg if max_zenith_deg is not None else float(_polar_edges(model.zenith_deg,
                                                                                model.azimuth_deg)[0][-1])
    sky = _Sky(zmax, sun_zenith_deg, sun_azimuth_deg)
    for j in range(nb):
        mv, tv = model.values[:, :, j], truth.values[:, :, j]
        lo, hi = _robust_range(np.concatenate([mv.ravel(), tv.ravel()]))
        wl = f"{wavelengths_nm[j]:.0f} nm"
        _polar_panel(fig, axes[j][0], PolarGrid(model.zenith_deg, model.azimuth_deg, mv), sky, vmin=lo, vmax=hi,
                     cmap="inferno", title=f"BRF-GS, {wl}", label="BRF")
        _polar_panel(fig, axes[j][1], PolarGrid(truth.zenith_deg, truth.azimuth_deg, tv), sky, vmin=lo, vmax=hi,
                     cmap="inferno", title=f"truth (simulator), {wl}", label="BRF")
        d = model_at_truth[:, :, j] - tv
        okd = np.isfinite(d)
        m = float(np.nanmax(np.abs(d[okd]))) if okd.any() else 1.0
        _polar_panel(fig, axes[j][2], PolarGrid(truth.zenith_deg, truth.azimuth_deg, d), sky, vmin=-max(m, 1e-9),
                     vmax=max(m, 1e-9), cmap="RdBu_r", title=f"BRF-GS − truth, {wl}", label="ΔBRF")
    return _finish(fig, path, title)


def plot_spectra(path: str | Path, wavelengths_nm: np.ndarray, reconstructed: np.ndarray,
                 observed: np.ndarray | None, log_err: np.ndarray | None, *, truth: np.ndarray | None = None,
                 title: str = "") -> Path:
    """Fig. 7: mean spectra (top) and logarithmic error ln(rec/obs) (bottom)."""
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(6, 5), dpi=100, sharex=True,
                                 gridspec_kw={"height_ratios": [2, 1]})
    a1.plot(wavelengths_nm, reconstructed, "-", color="C0", label="reconstructed")
    if observed is not None:
        a1.plot(wavelengths_nm, observed, "-", color="k", lw=1, label="observed")
    if truth is not None:
        a1.plot(wavelengths_nm, truth, "--", color="C3", lw=1, label="truth")
    a1.set_ylabel("reflectance")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3)
    if log_err is not None:
        a2.plot(wavelengths_nm, log_err, "-", color="C2")
        a2.axhline(0, color="k", lw=0.6)
    a2.set_ylabel("ln(rec / obs)")
    a2.set_xlabel("wavelength (nm)")
    a2.grid(alpha=0.3)
    if title:
        a1.set_title(title, fontsize=10)
    return _finish(fig, path, "")


def save_cir_comparison(path: str | Path, ref: np.ndarray, pred: np.ndarray, title: str) -> Path:
    """Reference, render (CIR composites [H, W, 3]) and their mean absolute error side by side (PNG)."""
    err = np.abs(np.nan_to_num(pred) - np.nan_to_num(ref)).mean(-1)
    fig, ax = plt.subplots(1, 3, figsize=(10, 3.6))
    ax[0].imshow(np.nan_to_num(np.clip(ref, 0, 1)))
    ax[0].set_title("reference (CIR)")
    ax[1].imshow(np.clip(pred, 0, 1))
    ax[1].set_title("render (CIR)")
    im = ax[2].imshow(err, cmap="magma", vmin=0, vmax=max(float(np.nanpercentile(err, 99)), 1e-3))
    ax[2].set_title("|error| (mean of CIR channels)")
    fig.colorbar(im, ax=ax[2], fraction=0.046)
    for a in ax:
        a.axis("off")
    fig.suptitle(title, fontsize=9)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return _finish(fig, path, "", dpi=100)
