"""Train / validation / test splits stratified by view ring.

A multi-angle flight images the scene from rings of equal view zenith (AIR-BRF: nadir and
18°, 23°, 38°, 58°). A plain random 6:1 split can leave a whole ring out of the test set (the
project's 128² testsite once had no 58° test view), so the default split draws its test views
from every ring in proportion to the ring's size (largest-remainder apportionment, ties and
the choice within a ring by a seeded permutation). The validation split takes 1 in 6 of the
training views the same way (seed + 1); it is what settings are chosen on, never the test views.
"""

from __future__ import annotations

import math

import numpy as np

RING_TOLERANCE_DEG = 2.5  # view zeniths closer than this belong to one ring


def view_rings(zenith_deg: np.ndarray | list[float], tol_deg: float = RING_TOLERANCE_DEG) -> np.ndarray:
    """Ring label [N] (degrees, the ring's mean zenith rounded to 0.1°) of each view zenith [N].

    Zeniths are sorted and split wherever two neighbours differ by more than ``tol_deg``."""
    z = np.asarray(zenith_deg, dtype=np.float64)
    if z.size == 0:
        return z
    order = np.argsort(z, kind="stable")
    labels = np.empty_like(z)
    start = 0
    for k in range(1, len(z) + 1):
        if k == len(z) or z[order[k]] - z[order[k - 1]] > tol_deg:
            members = order[start:k]
            labels[members] = round(float(z[members].mean()), 1)
            start = k
    return labels


def ring_name(label_deg: float) -> str:
    """Key of a ring in metrics files: "0", "18", "58", "37.5" (integer degrees when whole)."""
    r = round(float(label_deg))
    return str(r) if abs(r - label_deg) < 0.05 else f"{label_deg:.1f}"


def apportion(sizes: list[int], total: int, rng: np.random.Generator) -> list[int]:
    """Split ``total`` picks over groups of ``sizes`` in proportion (largest remainder; ties in
    a seeded order); no group gets more than its size."""
    n = sum(sizes)
    if n == 0 or total <= 0:
        return [0] * len(sizes)
    quota = [total * s / n for s in sizes]
    picks = [min(s, math.floor(q)) for s, q in zip(sizes, quota)]
    tiebreak = rng.permutation(len(sizes))
    order = sorted(range(len(sizes)), key=lambda g: (-(quota[g] - math.floor(quota[g])), tiebreak[g]))
    left = min(total, n) - sum(picks)
    while left > 0:
        for g in order:
            if left > 0 and picks[g] < sizes[g]:
                picks[g] += 1
                left -= 1
    return picks


def stratified_pick(candidates: list[int], rings: np.ndarray, n_pick: int, seed: int) -> list[int]:
    """``n_pick`` of ``candidates`` (indices into ``rings``) spread over the rings in proportion
    to how many candidates each ring has; deterministic from ``seed``."""
    rng = np.random.default_rng(seed)
    labels = sorted({float(rings[i]) for i in candidates})
    groups = [[i for i in candidates if float(rings[i]) == lab] for lab in labels]
    counts = apportion([len(g) for g in groups], n_pick, rng)
    out: list[int] = []
    for g, c in zip(groups, counts):
        if c:
            perm = rng.permutation(len(g))
            out += [g[j] for j in perm[:c]]
    return sorted(out)


def nearest_view_angle_deg(held_dirs: np.ndarray, train_dirs: np.ndarray) -> np.ndarray:
    """Angle (degrees) from each held-out view direction [M, 3] to the nearest training view
    direction [N, 3] (unit vectors, scene to camera) -> [M].

    How far a held-out view is from what training saw: a model interpolates near-nadir views 5-9°
    from a training view and extrapolates oblique views 25-31° from one (docs/results.md, Sessions
    16 and 29), so a split's metrics depend on it.
    """
    held = np.asarray(held_dirs, dtype=np.float64).reshape(-1, 3)
    train = np.asarray(train_dirs, dtype=np.float64).reshape(-1, 3)
    if len(held) == 0 or len(train) == 0:
        return np.full(len(held), np.nan)
    cos = np.clip(held @ train.T, -1.0, 1.0)                       # [M, N]
    return np.degrees(np.arccos(cos.max(axis=1)))
