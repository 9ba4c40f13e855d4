"""Equivalent feature count (EFC): the paper's geometry-reliable band criterion (section 3.1, eqs 3–8).

Small pure functions on numpy arrays, one per equation, plus the band-image preparation
shared with SfM feature extraction (``stretch_to_uint8``, ``detect_keypoints``):

- eq. 3  ``detect_keypoints``      SIFT keypoints F_b of one band image treated as a grayscale image
- eq. 4  ``local_median``          I_{b,i}: median reflectance of the 5×5 window around each keypoint
- eq. 5  ``signal_quality``        S_{b,i} = I_{b,i} / (σ_b^dark + ε)
- eq. 6  ``normalise_quality``     S̃_{b,i} = S_{b,i} / max_{j,k} S_{j,k}   (scene-wide maximum)
- eq. 7  ``equivalent_feature_count``  EFC_b = Σ_i S̃_{b,i}
- eq. 8  ``top_k_bands``           λ_geo = TOP-k_b (EFC_b)

A band image is turned into an 8-bit grayscale image by a robust linear stretch
(0.5th–99.5th percentile of its valid pixels → 0–255), which is what a SIFT detector on
"the band treated as a grayscale image" sees: a band with little texture gives few
keypoints, a noisy band gives many keypoints on noise whose local signal (eq. 4) is low
relative to its dark noise (eq. 5), so its EFC stays low.
"""

from __future__ import annotations

import cv2
import numpy as np

EPS_SIGMA = 1e-6  # ε of eq. 5 (reflectance units)
WINDOW = 5  # side of the eq. 4 window (pixels)


def stretch_to_uint8(band: np.ndarray, valid: np.ndarray | None = None,
                     lo_pct: float = 0.5, hi_pct: float = 99.5) -> np.ndarray:
    """Linear 8-bit stretch of one band image [H, W] (reflectance) → uint8 [H, W].

    The ``lo_pct``/``hi_pct`` percentiles of the valid (finite, ``valid``) pixels map to 0/255;
    invalid pixels become 0. A constant image maps to 0 everywhere.
    """
    return stretch_cube_to_uint8(np.asarray(band)[:, :, None], valid, lo_pct, hi_pct)[:, :, 0]


def stretch_cube_to_uint8(cube: np.ndarray, valid: np.ndarray | None = None,
                          lo_pct: float = 0.5, hi_pct: float = 99.5) -> np.ndarray:
    """:func:`stretch_to_uint8` of every band of ``cube`` [H, W, B] at once → uint8 [H, W, B]."""
    cube = np.asarray(cube, dtype=np.float32)
    ok = np.isfinite(cube).all(-1)
    if valid is not None:
        ok &= valid
    out = np.zeros(cube.shape, np.uint8)
    if not ok.any():
        return out
    lo, hi = np.percentile(cube[ok], [lo_pct, hi_pct], axis=0)  # [B] each
    span = hi - lo
    good = span > 0
    gain = np.where(good, 255.0 / np.where(good, span, 1.0), 0.0).astype(np.float32)
    scaled = (cube - lo.astype(np.float32)) * gain
    scaled[~ok] = 0.0
    np.clip(np.rint(scaled), 0, 255, out=scaled)
    out[:] = scaled.astype(np.uint8)
    return out


def make_sift(max_features: int = 0, contrast_threshold: float = 0.04, edge_threshold: float = 10.0):
    """An OpenCV SIFT detector (Lowe's defaults, unbiased upscaling; ``max_features`` 0 = unlimited)."""
    return cv2.SIFT_create(nfeatures=int(max_features), contrastThreshold=float(contrast_threshold),
                           edgeThreshold=float(edge_threshold), enable_precise_upscale=True)


def detect_keypoints(gray_u8: np.ndarray, valid: np.ndarray | None = None, sift=None,
                     with_descriptors: bool = False):
    """SIFT keypoints of an 8-bit image (paper eq. 3).

    Returns ``xy`` [N, 2] float32 pixel coordinates (x right, y down) with the centre of the first
    pixel at (0, 0), ``response`` [N], ``size`` [N], ``angle`` [N] and, when ``with_descriptors``,
    ``desc`` [N, 128] uint8 (L2-normalised SIFT × 512, clipped: the layout COLMAP uses).
    Use :func:`make_sift`: OpenCV's default SIFT reports positions 0.25 px too large (its ×2
    upsampled first octave maps pixel k to k/2 instead of k/2 − 0.25); ``enable_precise_upscale``
    removes that bias (checked with Gaussian blobs at known sub-pixel positions in the tests).
    Keypoints inside invalid pixels are never returned (the detector gets an eroded mask).
    """
    sift = make_sift() if sift is None else sift
    mask = None
    if valid is not None and not valid.all():
        mask = cv2.erode(valid.astype(np.uint8) * 255, np.ones((5, 5), np.uint8))
    if with_descriptors:
        kps, desc = sift.detectAndCompute(gray_u8, mask)
    else:
        kps, desc = sift.detect(gray_u8, mask), None
    n = len(kps)
    out = {
        "xy": np.array([k.pt for k in kps], np.float32).reshape(n, 2),
        "response": np.array([k.response for k in kps], np.float32),
        "size": np.array([k.size for k in kps], np.float32),
        "angle": np.array([k.angle for k in kps], np.float32),
    }
    if with_descriptors:
        if desc is None:
            desc = np.zeros((0, 128), np.float32)
        out["desc"] = np.clip(np.rint(desc), 0, 255).astype(np.uint8)
    return out


def local_median(band: np.ndarray, xy: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """Paper eq. 4: I_{b,i} = median of ``band`` [H, W] in the ``window``×``window`` window around each keypoint.

    ``xy`` [N, 2] are OpenCV keypoint coordinates (x, y); the window is centred on the pixel
    containing the keypoint (rounded), clipped at the image border; NaN pixels are ignored.
    Returns [N] (NaN where the whole window is invalid).
    """
    band = np.asarray(band, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) == 0:
        return np.zeros(0)
    h, w = band.shape
    r = window // 2
    padded = np.pad(band, r, mode="constant", constant_values=np.nan)  # [H+2r, W+2r]
    col = np.clip(np.rint(xy[:, 0]).astype(int), 0, w - 1)
    row = np.clip(np.rint(xy[:, 1]).astype(int), 0, h - 1)
    off = np.arange(-r, r + 1)
    rows = row[:, None, None] + r + off[None, :, None]  # [N, win, 1]
    cols = col[:, None, None] + r + off[None, None, :]  # [N, 1, win]
    patches = np.sort(padded[rows, cols].reshape(len(xy), -1), axis=1)  # [N, win*win], NaN last
    n_ok = np.isfinite(patches).sum(1)  # [N]
    lo = np.take_along_axis(patches, np.maximum((n_ok - 1) // 2, 0)[:, None], 1)[:, 0]
    hi = np.take_along_axis(patches, np.maximum(n_ok // 2, 0)[:, None], 1)[:, 0]
    return np.where(n_ok > 0, 0.5 * (lo + hi), np.nan)


def signal_quality(intensity: np.ndarray, sigma_dark: float, eps: float = EPS_SIGMA) -> np.ndarray:
    """Paper eq. 5: S_{b,i} = I_{b,i} / (σ_b^dark + ε) for the keypoints [N] of one band.

    Reflectance is non-negative; a negative window median (pure noise around zero) counts as 0.
    """
    return np.maximum(np.asarray(intensity, np.float64), 0.0) / (float(sigma_dark) + eps)


def normalise_quality(quality: list[np.ndarray]) -> list[np.ndarray]:
    """Paper eq. 6: divide every S_{b,i} by the maximum over all bands and keypoints.

    ``quality`` is a list of [N_b] arrays (any number of bands, and of views when the
    maximum is scene-wide). Non-finite values are dropped (NaN windows); a scene without
    a positive S gives all zeros.
    """
    finite = [q[np.isfinite(q)] for q in quality]
    s_max = max((float(q.max()) for q in finite if q.size), default=0.0)
    if not s_max > 0:
        return [np.zeros_like(q) for q in finite]
    return [q / s_max for q in finite]


def equivalent_feature_count(normalised_quality: np.ndarray) -> float:
    """Paper eq. 7: EFC_b = Σ_i S̃_{b,i} over the keypoints of one band."""
    return float(np.sum(normalised_quality))


def top_k_bands(efc: np.ndarray, k: int = 3) -> np.ndarray:
    """Paper eq. 8: indices of the ``k`` bands with the largest EFC, best first (ties: lower index first)."""
    efc = np.asarray(efc, np.float64)
    order = np.lexsort((np.arange(len(efc)), -efc))  # primary key -efc, then index
    return order[: int(k)]


def top_k_separated(score: np.ndarray, wavelengths_nm: np.ndarray, k: int = 3,
                    min_separation_nm: float = 0.0) -> np.ndarray:
    """Eq. 8 with a minimum spectral distance (beyond the paper, opt-in): bands in order of decreasing
    ``score``, skipping any band closer than ``min_separation_nm`` to one already chosen. Adjacent bands of
    a hyperspectral sensor are nearly the same image, so the paper's top-3 often are three neighbours;
    a separation gives SfM differently textured images to pool. 0 is eq. 8 exactly. Fewer than ``k``
    bands come back only when the range cannot hold ``k`` separated bands."""
    order = top_k_bands(score, len(score))
    if not min_separation_nm or min_separation_nm <= 0:
        return order[: int(k)]
    wl = np.asarray(wavelengths_nm, np.float64)
    chosen: list[int] = []
    for i in order:
        if all(abs(wl[i] - wl[j]) >= min_separation_nm for j in chosen):
            chosen.append(int(i))
            if len(chosen) == k:
                break
    return np.asarray(chosen, np.int64)


def efc_of_stack(cube: np.ndarray, sigma_dark: np.ndarray, valid: np.ndarray | None = None, sift=None):
    """EFC of every band of one view: eqs 3–7 with the maximum of eq. 6 taken over this view.

    ``cube`` [H, W, B] reflectance, ``sigma_dark`` [B]. Returns (efc [B], n_features [B]).
    (:func:`brfgs.bands.compute_band_stats` takes the maximum over the whole scene instead.)
    """
    q, n = band_quality_of_view(cube, sigma_dark, valid, sift)
    qn = normalise_quality(q)
    return np.array([equivalent_feature_count(x) for x in qn]), n


def band_quality_of_view(cube: np.ndarray, sigma_dark: np.ndarray, valid: np.ndarray | None = None,
                         sift=None, bands: np.ndarray | None = None):
    """Eqs 3–5 for each band of one view: (list of S_{b,i} arrays [N_b], n_features [B']).

    ``cube`` [H, W, B] reflectance, ``sigma_dark`` [B]; ``bands`` restricts to a subset.
    """
    sift = make_sift() if sift is None else sift
    cube = np.asarray(cube)
    if valid is None:
        valid = np.all(np.isfinite(cube), axis=-1)
    idx = np.arange(cube.shape[-1]) if bands is None else np.asarray(bands)
    quality, counts = [], np.zeros(len(idx), np.int64)
    gray = stretch_cube_to_uint8(cube[:, :, idx], valid)  # [H, W, B']
    masked = np.where(valid[:, :, None], cube[:, :, idx], np.nan)
    for j, b in enumerate(idx):
        kp = detect_keypoints(np.ascontiguousarray(gray[:, :, j]), valid, sift)
        counts[j] = len(kp["xy"])
        intensity = local_median(masked[:, :, j], kp["xy"])
        quality.append(signal_quality(intensity, sigma_dark[b]))
    return quality, counts
