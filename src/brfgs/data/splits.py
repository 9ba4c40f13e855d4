"""Train / validation / test splits stratified by view ring and spread over the view directions.

A multi-angle flight images the scene from rings of equal view zenith (AIR-BRF: nadir and
18°, 23°, 38°, 58°). A plain random 6:1 split can leave a whole ring out of the test set (the
project's 128² testsite once had no 58° test view), so every split draws its test views from
every ring in proportion to the ring's size (largest-remainder apportionment, ties by a seeded
permutation). Which views of a ring are held out is the split's rule:

- ``spread`` (the default): farthest-point sampling over the view directions. Each pick is the
  view of a ring with picks left that lies farthest (in angle) from every view already held out,
  ties in a seeded order. The held-out views lie as far apart as the layout allows, so each keeps
  training views around it at the layout's spacing (on the 49-view AIR-BRF layout: every test
  view within 20° of a training view, and no two test views side by side on a ring or one above
  the other): the test measures interpolation between the flight's views, as LLFF's and
  Mip-NeRF 360's every-n-th hold-out does for a camera path. A random choice can hold out
  neighbours and leave a hole twice the spacing (test views 31° from any training view).
- ``random``: a seeded permutation within each ring (models of format 1 that name it).

The validation split takes 1 in 6 of the training views the same way (seed + 1; with ``spread``,
also farthest from the test views); it is what settings are chosen on, never the test views.
"""

from __future__ import annotations

import math

import numpy as np

from brfgs.data.angles import direction_from_angles_deg

RING_TOLERANCE_DEG = 2.5  # view zeniths closer than this belong to one ring
SPLIT_RULES = ("spread", "random")
DEFAULT_SPLIT_RULE = "spread"
SPLIT_RULE_BEFORE = "random"  # the rule of models of format 1 that do not name one
TEST_EVERY = 7  # 6 train : 1 test
VALIDATION_EVERY = 6  # of the training views, 1 in 6 for validation (when asked for)


def split_rule_of(options: dict) -> str:
    """The split rule a model was trained with, from its stored training options: "spread" for
    today's models; models of format 1 name theirs, or predate the option and used "random"."""
    if "format_version" in options:
        return DEFAULT_SPLIT_RULE
    return str(options.get("split_rule", SPLIT_RULE_BEFORE))


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


def ring_groups(candidates: list[int], rings: np.ndarray, n_pick: int,
                rng: np.random.Generator) -> tuple[list[list[int]], list[int]]:
    """The ``candidates`` (indices into ``rings``) grouped by ring, in ascending ring order, and how
    many of ``n_pick`` each group gives (:func:`apportion`, in proportion to the group's size)."""
    labels = sorted({float(rings[i]) for i in candidates})
    groups = [[i for i in candidates if float(rings[i]) == lab] for lab in labels]
    return groups, apportion([len(g) for g in groups], n_pick, rng)


def stratified_pick(candidates: list[int], rings: np.ndarray, n_pick: int, seed: int) -> list[int]:
    """``n_pick`` of ``candidates`` (indices into ``rings``) spread over the rings in proportion
    to how many candidates each ring has; deterministic from ``seed``."""
    rng = np.random.default_rng(seed)
    groups, counts = ring_groups(candidates, rings, n_pick, rng)
    out: list[int] = []
    for g, c in zip(groups, counts):
        if c:
            perm = rng.permutation(len(g))
            out += [g[j] for j in perm[:c]]
    return sorted(out)


def spread_pick(candidates: list[int], rings: np.ndarray, dirs: np.ndarray, n_pick: int, seed: int,
                held: list[int] = ()) -> list[int]:
    """``n_pick`` of ``candidates`` (indices into ``rings`` [F] and the unit view directions
    ``dirs`` [F, 3]), as many per ring as :func:`stratified_pick` takes, each the candidate farthest
    in angle from the views already held out (``held``, then earlier picks): farthest-point sampling,
    ties (to 0.001°) in a seeded order, so the first pick without ``held`` is a seeded random one."""
    rng = np.random.default_rng(seed)
    groups, counts = ring_groups(candidates, rings, n_pick, rng)
    quota = {float(rings[g[0]]): c for g, c in zip(groups, counts)}
    priority = {i: p for i, p in zip(candidates, rng.permutation(len(candidates)))}
    chosen = [int(i) for i in held]
    out: list[int] = []
    for _ in range(sum(quota.values())):
        left = [i for i in candidates if i not in out and quota[float(rings[i])] > 0]
        far = nearest_view_angle_deg(dirs[left], dirs[chosen]) if chosen else np.full(len(left), np.inf)
        best = max(range(len(left)), key=lambda j: (round(float(far[j]), 3), -priority[left[j]]))
        out.append(left[best])
        chosen.append(left[best])
        quota[float(rings[left[best]])] -= 1
    return sorted(out)


def assign_split(frames: list, seed: int, rule: str = DEFAULT_SPLIT_RULE, validation: bool = False) -> None:
    """Set each frame's ``split`` (frames with ``split_given`` keep theirs): a deterministic 6:1
    train:test split stratified by view ring, the held-out views chosen by ``rule`` (SPLIT_RULES);
    with ``validation``, 1 in 6 of the training frames become "validation" (seed + 1)."""
    n = len(frames)
    rings = view_rings([f.view_zenith_deg for f in frames])
    dirs = np.stack([direction_from_angles_deg(f.view_zenith_deg, f.view_azimuth_deg) for f in frames])
    given_test = [i for i, f in enumerate(frames) if f.split_given and f.split == "test"]

    def pick(cands: list[int], k: int, s: int, held: list[int]) -> list[int]:
        if rule == "random":
            return stratified_pick(cands, rings, k, s)
        return spread_pick(cands, rings, dirs, k, s, held)

    n_test_target = max(1, round(n / TEST_EVERY))
    free = [i for i, f in enumerate(frames) if not f.split_given]
    n_test_free = min(max(0, n_test_target - len(given_test)), max(0, len(free) - 1))
    test = set(pick(free, n_test_free, seed, given_test))
    for i in free:
        frames[i].split = "test" if i in test else "train"
    if validation:
        train = [i for i, f in enumerate(frames) if f.split == "train"]
        n_val = min(max(1, round(len(train) / VALIDATION_EVERY)), len(train) - 1)
        held = [i for i, f in enumerate(frames) if f.split == "test"]
        for i in pick(train, n_val, seed + 1, held):
            frames[i].split = "validation"


def nearest_view_angle_deg(held_dirs: np.ndarray, train_dirs: np.ndarray) -> np.ndarray:
    """Angle (degrees) from each held-out view direction [M, 3] to the nearest training view
    direction [N, 3] (unit vectors, scene to camera) -> [M].

    How far a held-out view is from what training saw: a model interpolates near-nadir views 5-9°
    from a training view and extrapolates oblique views 25-31° from one (docs/results.md), so a
    split's metrics depend on it.
    """
    held = np.asarray(held_dirs, dtype=np.float64).reshape(-1, 3)
    train = np.asarray(train_dirs, dtype=np.float64).reshape(-1, 3)
    if len(held) == 0 or len(train) == 0:
        return np.full(len(held), np.nan)
    return _nearest_angle_deg(held, train, skip_self=False)


def _nearest_angle_deg(held: np.ndarray, train: np.ndarray, skip_self: bool) -> np.ndarray:
    """Angle (deg) from each of ``held`` [M, 3] to the nearest of ``train`` [N, 3] -> [M], in blocks of
    1,024 rows (a flight of 10^4 frames needs no 10^4 x 10^4 matrix); ``skip_self``: ``held`` is
    ``train`` and row i does not count view i."""
    best = np.empty(len(held))
    for start in range(0, len(held), 1024):
        cos = held[start:start + 1024] @ train.T                   # [<=1024, N]
        if skip_self:
            cos[np.arange(len(cos)), np.arange(start, start + len(cos))] = -1.0
        best[start:start + len(cos)] = cos.max(axis=1)
    return np.degrees(np.arccos(np.clip(best, -1.0, 1.0)))


def view_spacing_deg(dirs: np.ndarray) -> np.ndarray:
    """Angle (degrees) from each view direction [F, 3] (unit, scene to camera) to the nearest other
    view's -> [F] (NaN for a single view).

    The layout's angular sampling: when such a view is held out, no training view is nearer than
    this, whatever the split. On the AIR-BRF layout the 58° views are 20° from any other view (the
    38° view below) and, held out, score 6.4 dB below the 18° ring (5°) on the 64² testsite; 24
    azimuths per ring (12.7°) make it 3.1-3.4 dB, a 53° ring (5°) 2.7-2.9 dB (docs/results.md).
    """
    d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    if len(d) < 2:
        return np.full(len(d), np.nan)
    return _nearest_angle_deg(d, d, skip_self=True)
