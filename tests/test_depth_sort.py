"""The radix depth sort (brfgs.render.depth_sort) against numpy's stable argsort: the same permutation."""

from __future__ import annotations

import numpy as np
import pytest

from brfgs.render.depth_sort import stable_depth_order


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n", [0, 1, 2, 17, 5000])
def test_the_same_permutation_as_a_stable_argsort(dtype, n):
    rng = np.random.default_rng(n)
    depth = (rng.random(n) * 40.0 + 0.2).astype(dtype)
    depth[rng.random(n) < 0.3] = dtype(7.25)                 # many exact ties: input order must be kept
    if n > 4:
        depth[:3] = [-1.5, 3e-8, -2e-30]                     # negative and tiny numbers order too
    np.testing.assert_array_equal(stable_depth_order(depth), np.argsort(depth, kind="stable"))


def test_depths_in_a_narrow_range_and_wide_ones():
    """Keys that share their high bytes (passes skipped) and ones that span the whole float range."""
    rng = np.random.default_rng(3)
    narrow = (30.0 + rng.random(20000) * 1e-3).astype(np.float32)
    wide = np.concatenate([rng.standard_normal(3000) * 10.0 ** rng.integers(-30, 30, 3000), [np.inf, -np.inf, 0.0]])
    for depth in (narrow, wide, wide.astype(np.float32)):
        np.testing.assert_array_equal(stable_depth_order(depth), np.argsort(depth, kind="stable"))
