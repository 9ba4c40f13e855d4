"""Equivalent feature count (paper eqs 3–8): each equation against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from brfgs.bands import efc as E


def test_eq4_local_median_window_border_and_nan():
    band = np.arange(49, dtype=float).reshape(7, 7)  # value = 7*row + col
    # centre (x=3, y=3): 5x5 window rows 1..5, cols 1..5 -> median is the centre value 24
    # corner (x=0, y=0): window clipped to rows 0..2, cols 0..2 -> values {0,1,2,7,8,9,14,15,16}, median 8
    out = E.local_median(band, np.array([[3.0, 3.0], [0.0, 0.0], [6.2, 0.4]]))
    # (6.2, 0.4) rounds to pixel (x=6, y=0): rows 0..2, cols 4..6 -> {4,5,6,11,12,13,18,19,20}, median 12
    assert out.tolist() == [24.0, 8.0, 12.0]
    band2 = band.copy()
    band2[1:6, 1:3] = np.nan  # 10 NaN in the centre window; remaining 15 values
    rest = band[1:6, 3:6].ravel()
    assert E.local_median(band2, np.array([[3.0, 3.0]]))[0] == np.median(rest)
    assert np.isnan(E.local_median(np.full((7, 7), np.nan), np.array([[3.0, 3.0]]))[0])


def test_eq5_to_eq8_hand_computed():
    # band A: 3 keypoints on reflectance 0.4 with sigma 0.01 -> S = 40
    # band B: 2 keypoints on reflectance 0.2 with sigma 0.02 -> S = 10
    # band C: 1 keypoint on reflectance -0.01 (noise around zero) -> S = 0
    eps = E.EPS_SIGMA
    sA = E.signal_quality(np.array([0.4, 0.4, 0.4]), 0.01)
    sB = E.signal_quality(np.array([0.2, 0.2]), 0.02)
    sC = E.signal_quality(np.array([-0.01]), 0.03)
    assert sA == pytest.approx(0.4 / (0.01 + eps)) and sC.tolist() == [0.0]
    nA, nB, nC = E.normalise_quality([sA, sB, sC])  # eq. 6: max over all = S_A
    assert nA.tolist() == pytest.approx([1, 1, 1])
    assert nB.tolist() == pytest.approx([(0.2 / (0.02 + eps)) / (0.4 / (0.01 + eps))] * 2)
    efc = [E.equivalent_feature_count(x) for x in (nA, nB, nC)]  # eq. 7
    assert efc == pytest.approx([3.0, 0.5, 0.0], rel=1e-4)
    assert E.top_k_bands(np.array(efc), 2).tolist() == [0, 1]  # eq. 8
    # ties: lower index first; k larger than B returns all
    assert E.top_k_bands(np.array([1.0, 2.0, 2.0, 0.5]), 3).tolist() == [1, 2, 0]
    assert E.top_k_bands(np.array([1.0, 2.0]), 5).tolist() == [1, 0]
    # no positive S anywhere: all zeros, not NaN
    assert E.normalise_quality([np.zeros(2)])[0].tolist() == [0.0, 0.0]


def _blobs(size=64, seed=0):
    """Smooth texture with clear SIFT blobs, values in [0.1, 0.5]."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(float)
    img = np.zeros((size, size))
    for _ in range(25):
        cx, cy = rng.uniform(6, size - 6, 2)
        s = rng.uniform(1.5, 3.5)
        img += rng.choice([-1, 1]) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    img = (img - img.min()) / (img.max() - img.min())
    return 0.1 + 0.4 * img


def test_efc_of_stack_scaling_laws():
    """A band scaled by 1/2 (same noise) or with doubled noise keeps its keypoints (the 8-bit stretch is
    linear) and so has exactly half the EFC; a textureless band has no keypoints and EFC 0."""
    a = _blobs()
    cube = np.stack([a, 0.5 * a, a, np.full_like(a, 0.3)], -1)  # [H, W, 4]
    sigma = np.array([0.01, 0.01, 0.02, 0.01])
    efc, n = E.efc_of_stack(cube, sigma)
    assert n[0] >= 5 and n[0] == n[1] == n[2] and n[3] == 0
    assert efc[1] == pytest.approx(0.5 * efc[0], rel=1e-5)
    assert efc[2] == pytest.approx(0.5 * efc[0], rel=1e-4)
    assert efc[3] == 0.0
    # independent reference for band 0: OpenCV directly + explicit 5x5 medians + the maximum over the stack
    import cv2

    u8 = E.stretch_to_uint8(a)
    kps = cv2.SIFT_create(enable_precise_upscale=True).detect(u8, None)
    meds = []
    for k in kps:
        c, r = int(round(k.pt[0])), int(round(k.pt[1]))
        win = a[max(r - 2, 0): r + 3, max(c - 2, 0): c + 3]
        meds.append(np.median(win))
    s = np.array(meds) / (0.01 + E.EPS_SIGMA)
    assert len(kps) == n[0]
    assert efc[0] == pytest.approx(np.sum(s / s.max()), rel=1e-6)  # band 0 holds the maximum S


def test_stretch_to_uint8():
    band = np.linspace(0, 1, 1000).reshape(10, 100)
    u8 = E.stretch_to_uint8(band)
    assert u8.dtype == np.uint8 and u8.min() == 0 and u8.max() == 255
    band[0, 0] = np.nan
    assert E.stretch_to_uint8(band)[0, 0] == 0
    assert E.stretch_to_uint8(np.full((4, 4), 0.3)).max() == 0  # constant: no texture


def test_keypoint_positions_are_unbiased():
    """Blobs at known sub-pixel positions (first pixel centre at 0) are found within 0.06 px
    (OpenCV's default upscaling would put them 0.25 px off)."""
    y, x = np.mgrid[0:96, 0:96].astype(float)
    for cx, cy, s in ((40.0, 40.0, 3.0), (50.5, 44.25, 3.0), (47.3, 52.8, 6.0)):
        img = np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
        kp = E.detect_keypoints((img * 255).astype(np.uint8), sift=E.make_sift(contrast_threshold=0.001))
        best = kp["xy"][np.argmax(kp["response"])]
        assert np.abs(best - [cx, cy]).max() < 0.06, (cx, cy, best)


def test_top_k_separated():
    from brfgs.bands.efc import top_k_separated

    wl = np.arange(400.0, 500.0, 4.0)  # 25 bands, 4 nm apart
    score = -np.abs(wl - 450.0)  # peak at 450 nm: the plain top-3 are neighbours
    assert top_k_separated(score, wl, 3).tolist() == E.top_k_bands(score, 3).tolist()
    got = top_k_separated(score, wl, 3, min_separation_nm=20.0)
    assert len(got) == 3 and got[0] == int(np.argmax(score))
    assert all(abs(wl[a] - wl[b]) >= 20.0 for a in got for b in got if a != b)
    # order of decreasing score among the allowed bands; fewer only when the range cannot hold k
    assert score[got[1]] >= score[got[2]]
    assert len(top_k_separated(score, wl, 10, min_separation_nm=40.0)) == 3
