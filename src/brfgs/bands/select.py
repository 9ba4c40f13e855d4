"""Band statistics over a scene and the band-selection strategies of the paper's Table 2.

:func:`compute_band_stats` runs eqs 3–7 (:mod:`brfgs.bands.efc`) on every band of every
view, with the normalisation of eq. 6 taken over the whole scene (all bands, all views),
and averages the per-view EFC_b over views. :func:`select_bands` applies one strategy:

=============  ================================================================
efc            EFC top-k (eq. 8), k = ``top`` (default 3); the method's choice
efc-top1       EFC top-1
efc-top3       EFC top-3
all            all bands (SfM pools the features of every band, duplicates removed)
rgb            bands nearest 450, 550, 650 nm
cir            bands nearest 850, 650, 550 nm
central        band nearest 675 nm
max-snr        band with the largest SNR (mean reflectance / σ_b^dark)
max-features   band with the most detected features (mean over views)
=============  ================================================================

Images larger than ``detect_max_px`` on their long side are area-downscaled by an integer
factor while they are read (recorded as ``detect_downscale``; no full-resolution cube is held), and
when the views × bands × pixels of these copies exceed ``detect_max_mpx`` million, the statistics
use an evenly spread subset of the views that fits (recorded as ``views``): EFC ranks bands, and a
full-resolution 1886² cube × 164 bands × 49 views would otherwise take the better part of an hour.
Smaller scenes (up to 512² and 600 M band-pixels: a 49-view 256² scene of 164 bands) use every
pixel of every view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from brfgs.bands import efc as E
from brfgs.bands.options import DEFAULT_DETECT_MAX_MPX, DEFAULT_DETECT_MAX_PX, STRATEGIES  # noqa: F401  (re-exported)
from brfgs.data import atomic
from brfgs.data.figures import pyplot
from brfgs.errors import UserError

# The eight strategies of Table 2, in the paper's order.
TABLE2_STRATEGIES = ("all", "rgb", "cir", "central", "max-snr", "max-features", "efc-top1", "efc-top3")
FIXED_WAVELENGTHS_NM = {"rgb": (650.0, 550.0, 450.0), "cir": (850.0, 650.0, 550.0), "central": (675.0,)}
STRATEGY_LABELS = {
    "all": "All bands", "rgb": "RGB bands (650, 550, 450 nm)", "cir": "CIR bands (850, 650, 550 nm)",
    "central": "Central band (675 nm)", "max-snr": "Max SNR band", "max-features": "Max feature points band",
    "efc-top1": "1 geometry-reliable band (EFC)", "efc-top3": "3 geometry-reliable bands (EFC)",
    "efc": "EFC top-k",
}


@dataclass
class BandStats:
    """Per-band statistics of a scene (B bands, V views)."""

    wavelengths_nm: np.ndarray      # [B]
    sigma: np.ndarray               # [B] σ_b^dark
    features: np.ndarray            # [V, B] detected keypoints per view and band (eq. 3, N_b)
    efc: np.ndarray                 # [V, B] EFC_b per view (eq. 7, scene-wide eq. 6 maximum)
    mean_reflectance: np.ndarray    # [B] mean over valid pixels of the views used
    views: list[str]                # [V] frame names
    s_max: float                    # the scene-wide maximum of eq. 6
    detect_downscale: int = 1

    @property
    def efc_mean(self) -> np.ndarray:
        """EFC_b averaged over views [B]."""
        return self.efc.mean(axis=0)

    @property
    def features_mean(self) -> np.ndarray:
        """Detected keypoints per view, averaged over views [B]."""
        return self.features.mean(axis=0)

    @property
    def snr(self) -> np.ndarray:
        """SNR_b = mean reflectance / (σ_b^dark + ε) [B]."""
        return self.mean_reflectance / (self.sigma + E.EPS_SIGMA)


@dataclass
class BandSelection:
    """The result of a band-selection strategy."""

    strategy: str
    selected: list[int]                       # indices into the scene's bands, in priority order
    wavelengths_nm: np.ndarray                # [B] all bands of the scene
    stats: BandStats | None = None
    top: int | None = None
    notes: dict = field(default_factory=dict)

    @property
    def selected_wavelengths_nm(self) -> list[float]:
        return [float(self.wavelengths_nm[i]) for i in self.selected]

    def to_json(self) -> dict:
        """``bands.json`` content (schema in docs/data-format.md, "Machine-readable outputs")."""
        st = self.stats

        def val(arr, i, cast=float):
            return None if arr is None else cast(arr[i])

        efc = st.efc_mean if st else None
        feats = st.features_mean if st else None
        sigma = st.sigma if st else None
        snr = st.snr if st else None
        out = {
            "strategy": self.strategy,
            "top": self.top,
            "selected": [{"index": int(i), "wavelength_nm": float(self.wavelengths_nm[i]), "efc": val(efc, i)}
                         for i in self.selected],
            "bands": [{"index": int(i), "wavelength_nm": float(w), "efc": val(efc, i), "features": val(feats, i),
                       "sigma": val(sigma, i), "snr": val(snr, i)} for i, w in enumerate(self.wavelengths_nm)],
            "definitions": {
                "efc": "paper eq. 7 per view with the eq. 6 maximum over all bands and views of the scene, "
                       "averaged over views",
                "features": "SIFT keypoints per view (OpenCV, 8-bit 0.5-99.5 percentile stretch), mean over views",
                "sigma": "dark-frame noise sigma_b (reflectance)",
                "snr": "mean reflectance over valid pixels / (sigma_b + 1e-6)",
            },
        }
        if st is not None:
            out["views"] = list(st.views)
            out["detect_downscale"] = int(st.detect_downscale)
            out["s_max"] = float(st.s_max)
        out.update(self.notes)
        return out


def _block_mean(cube: np.ndarray, factor: int) -> np.ndarray:
    """Area-average [H, W, B] by an integer factor (NaN propagates)."""
    if factor <= 1:
        return cube
    h, w = cube.shape[0] // factor, cube.shape[1] // factor
    c = cube[: h * factor, : w * factor]
    return c.reshape(h, factor, w, factor, -1).mean(axis=(1, 3))


def detect_downscale_factor(width: int, height: int, detect_max_px: int | None) -> int:
    """Integer factor that brings the long side to at most ``detect_max_px`` (1 when it already is)."""
    if not detect_max_px or max(width, height) <= detect_max_px:
        return 1
    return int(math.ceil(max(width, height) / detect_max_px))


def spread_views(views: list[int], n_max: int) -> list[int]:
    """At most ``n_max`` (>= 1) of ``views``, evenly spread over the list in its order (all when they fit)."""
    if n_max >= len(views):
        return list(views)
    n = max(1, int(n_max))
    pick = np.unique(np.round(np.linspace(0, len(views) - 1, n)).astype(int))
    return [views[k] for k in pick]


def views_within_budget(views: list[int], width: int, height: int, n_bands: int, factor: int,
                        detect_max_mpx: float | None) -> list[int]:
    """The views whose band images (``n_bands`` each, ``width`` x ``height`` downscaled by ``factor``) fit in
    ``detect_max_mpx`` million pixels: all when they do or the budget is 0/None, else an evenly spread subset."""
    if not detect_max_mpx:
        return list(views)
    per_view = (width // factor) * (height // factor) * n_bands
    return spread_views(views, max(1, int(detect_max_mpx * 1e6 // max(per_view, 1))))


def compute_band_stats(scene, views: list[int] | None = None, detect_max_px: int | None = DEFAULT_DETECT_MAX_PX,
                       progress: bool = False, detect_max_mpx: float | None = DEFAULT_DETECT_MAX_MPX) -> BandStats:
    """EFC (eqs 3–7), feature counts and SNR of every band of ``scene``.

    ``views`` are frame indices (default all frames: geometry uses every view), thinned to what
    ``detect_max_mpx`` allows (:func:`views_within_budget`); views larger than ``detect_max_px`` are
    read area-downscaled.
    """
    views = list(range(len(scene.frames))) if views is None else list(views)
    if not views:
        raise UserError("no views to compute band statistics on", field="views")
    sigma = np.asarray(scene.dark_sigma, np.float64)
    n_b = len(scene.wavelengths_nm)
    factor = detect_downscale_factor(scene.width, scene.height, detect_max_px)
    views = views_within_budget(views, scene.width, scene.height, n_b, factor, detect_max_mpx)
    sift = E.make_sift()
    qualities: list[list[np.ndarray]] = []
    counts = np.zeros((len(views), n_b), np.int64)
    refl_sum = np.zeros(n_b)
    n_pix = 0
    it = views
    if progress:
        it = tqdm(views, desc="band statistics (views)", unit="view")
    for v, i in enumerate(it):
        cube = scene.load_image(i) if factor == 1 else scene.load_reduced(i, factor)  # [H, W, B]
        valid = np.isfinite(cube).all(-1)
        q, counts[v] = E.band_quality_of_view(cube, sigma, valid, sift)
        qualities.append(q)
        if valid.any():
            refl_sum += cube[valid].sum(0, dtype=np.float64)
            n_pix += int(valid.sum())
    flat = [q for per_view in qualities for q in per_view]
    finite = [q[np.isfinite(q)] for q in flat]
    s_max = max((float(q.max()) for q in finite if q.size), default=0.0)
    normed = E.normalise_quality(flat)  # eq. 6, scene-wide
    efc = np.array([E.equivalent_feature_count(x) for x in normed]).reshape(len(views), n_b)
    mean_refl = refl_sum / max(n_pix, 1)
    return BandStats(np.asarray(scene.wavelengths_nm, float), sigma, counts, efc, mean_refl,
                     [scene.frames[i].name for i in views], s_max, factor)


def _nearest(wavelengths_nm: np.ndarray, targets_nm, strategy: str) -> list[int]:
    wl = np.asarray(wavelengths_nm, float)
    out = []
    for t in targets_nm:
        i = int(np.argmin(np.abs(wl - t)))
        if abs(wl[i] - t) > 50.0:
            raise UserError(f"strategy '{strategy}' needs a band near {t:g} nm; the nearest band is at "
                            f"{wl[i]:.1f} nm (bands cover {wl.min():.0f}-{wl.max():.0f} nm)", field="strategy")
        if i not in out:
            out.append(i)
    return out


def strategy_needs_stats(strategy: str) -> bool:
    return strategy in ("efc", "efc-top1", "efc-top3", "max-snr", "max-features")


def select_bands(scene, strategy: str = "efc-top3", top: int = 3, stats: BandStats | None = None,
                 detect_max_px: int | None = DEFAULT_DETECT_MAX_PX, progress: bool = False,
                 with_stats: bool = False, min_separation_nm: float = 0.0,
                 detect_max_mpx: float | None = DEFAULT_DETECT_MAX_MPX) -> BandSelection:
    """Choose the geometry bands of ``scene`` with ``strategy`` (see the module table).

    ``min_separation_nm`` (EFC strategies; beyond the paper, default 0 = eq. 8): chosen bands are at
    least this far apart in wavelength (:func:`brfgs.bands.efc.top_k_separated`).

    ``stats`` reuses precomputed :func:`compute_band_stats`; it is computed here when the
    strategy needs it or ``with_stats`` is set. ``top`` is k for ``efc``.
    Returns a :class:`BandSelection` whose ``selected`` are band indices, best first.
    """
    if strategy not in STRATEGIES:
        raise UserError(f"unknown band-selection strategy {strategy!r}; choose one of {', '.join(STRATEGIES)}",
                        field="strategy")
    wl = np.asarray(scene.wavelengths_nm, float)
    n_b = len(wl)
    if strategy == "efc":
        if not isinstance(top, (int, np.integer)) or not 1 <= top <= n_b:
            raise UserError(f"--top must be between 1 and the number of bands ({n_b}), got {top}", field="top")
    if stats is None and (strategy_needs_stats(strategy) or with_stats):
        stats = compute_band_stats(scene, detect_max_px=detect_max_px, progress=progress, detect_max_mpx=detect_max_mpx)
    k = {"efc": top, "efc-top1": 1, "efc-top3": 3}.get(strategy)
    if k is not None:
        k = min(k, n_b)
        selected = [int(i) for i in E.top_k_separated(stats.efc_mean, wl, k, min_separation_nm)]
    elif strategy == "all":
        selected = list(range(n_b))
    elif strategy in FIXED_WAVELENGTHS_NM:
        selected = _nearest(wl, FIXED_WAVELENGTHS_NM[strategy], strategy)
    elif strategy == "max-snr":
        selected = [int(E.top_k_bands(stats.snr, 1)[0])]
    elif strategy == "max-features":
        selected = [int(E.top_k_bands(stats.features_mean, 1)[0])]
    else:  # pragma: no cover - guarded above
        raise AssertionError(strategy)
    notes = {"min_separation_nm": float(min_separation_nm)} if k is not None and min_separation_nm else {}
    return BandSelection(strategy, selected, wl, stats, top=k if k is not None else len(selected), notes=notes)


def plot_band_stats(selection: BandSelection, path) -> None:
    """EFC, feature count and SNR against wavelength with the chosen bands marked (PNG/PDF by suffix)."""
    plt = pyplot()
    st = selection.stats
    if st is None:
        raise ValueError("plot_band_stats needs a selection with statistics")
    wl = st.wavelengths_nm
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    series = [(st.efc_mean, "EFC (eq. 7, mean over views)"), (st.features_mean, "SIFT features per view"),
              (st.snr, "SNR (mean reflectance / sigma_dark)")]
    for ax, (y, label) in zip(axes, series):
        ax.plot(wl, y, "-", color="0.3", lw=1.2)
        for rank, i in enumerate(selection.selected[:10]):
            ax.axvline(wl[i], color="tab:red", lw=0.8, alpha=0.6)
            ax.plot(wl[i], y[i], "o", color="tab:red", ms=5)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_yscale("log")
    axes[-1].set_xlabel("wavelength (nm)")
    chosen = ", ".join(f"{wl[i]:.0f}" for i in selection.selected[:10])
    more = "" if len(selection.selected) <= 10 else f" ... ({len(selection.selected)} bands)"
    axes[0].set_title(f"band selection '{selection.strategy}': {chosen} nm{more}", fontsize=9)
    fig.tight_layout()
    atomic.save_figure(fig, path, dpi=120)
    plt.close(fig)
