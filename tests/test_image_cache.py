"""The training images' cache: least recently used whole frames up to a byte budget, shared by the
stores of a run, windows read for the frames it does not hold; and the dark-frame σ accumulated by row
blocks (no whole frame in float64)."""

import tracemalloc

import numpy as np
import pytest
from scenes import make_scene

from brfgs.data import cube_io, noise, read_scene
from brfgs.data.cube_io import bytes_read
from brfgs.train.images import ByteLRU, ImageStore, TrainImages


def test_byte_lru_evicts_least_recently_used_and_keeps_the_bound():
    lru = ByteLRU(100)
    assert lru.put("a", 1, 40) and lru.put("b", 2, 40)
    assert lru.get("a") == 1                      # a is now the most recently used
    assert lru.put("c", 3, 40)                    # b leaves, not a
    assert lru.keys() == ["a", "c"] and lru.used == 80
    assert not lru.put("d", 4, 101) and "d" not in lru          # larger than the budget: not held
    assert not lru.put("e", 5, 40, keep=lambda k: True) and lru.keys() == ["a", "c"]   # nothing may leave
    assert lru.put("f", 6, 60, keep=lambda k: k == "c") and lru.keys() == ["c", "f"]   # a leaves, c is kept
    assert lru.used == 100 and lru.get("a") is None


def test_store_keeps_what_fits_and_reads_the_rest_by_window(tmp_path):
    """A budget of two frames out of four: the first two windowed frames are held whole, the others
    read by window without evicting them; every value equals the whole frame's."""
    sc = read_scene(make_scene(tmp_path / "s", n_frames=7, n_dark=0, w=24, h=16))
    idx = sc.train_indices[:4]
    frame_bytes = 24 * 16 * (6 * 4 + 1)
    store = ImageStore(sc, idx, cache_gib=2.5 * frame_bytes / 2**30)
    assert not store.cached
    win = (3, 2, 8, 5)
    for i in idx:
        img, valid = store.get_window(i, win)
        whole = sc.load_image(i)
        np.testing.assert_array_equal(img.numpy(), whole[2:7, 3:11])
        assert valid.all()
    assert sorted(store.cache) == sorted(idx[:2]) and store.lru.used == 2 * frame_bytes
    before = bytes_read()
    store.get_window(idx[0], win)                  # held: no read
    assert bytes_read() == before
    store.get_window(idx[3], win)                  # not held: the window only (checked before)
    assert 0 < bytes_read() - before <= 8 * 5 * 6 * 4


def test_stores_share_the_budget_and_a_new_phase_takes_the_old_ones_room(tmp_path):
    sc = read_scene(make_scene(tmp_path / "s", n_frames=4, n_dark=0, w=24, h=16))
    tr = sc.train_indices
    full_bytes = 24 * 16 * (6 * 4 + 1)
    images = TrainImages(sc, [0, 1], [5, 3, 1], [1.0, 1.0, 1.0], cache_gib=len(tr) * full_bytes / 2**30)
    for i in tr:
        images("colors").get_window(i, (0, 0, 4, 4))
    assert sorted(images("colors").cache) == sorted(tr)
    for i in tr:                                   # stage 2: the full cubes push the stage-1 bands out
        images("full").get_window(i, (0, 0, 4, 4))
    assert sorted(images("full").cache) == sorted(tr) and not images("colors").cache
    assert images.cache.used <= images.cache.budget


@pytest.mark.parametrize("cache_gib", [4.0, 0.0])
def test_window_and_whole_targets_agree_cached_or_not(tmp_path, cache_gib):
    """CIR targets (a per-pixel transform) by window equal the whole frame's cropped, held or not."""
    sc = read_scene(make_scene(tmp_path / "s", n_frames=4, n_dark=0))
    images = TrainImages(sc, [0], [5, 3, 1], [0.3, 0.2, 0.25], cache_gib=cache_gib)
    for i in sc.train_indices:
        img, valid = images("cir").get_window(i, (5, 1, 7, 9))
        whole, whole_valid = images("cir").get(i)
        np.testing.assert_array_equal(img.numpy(), whole.numpy()[1:10, 5:12])
        np.testing.assert_array_equal(valid.numpy(), whole_valid.numpy()[1:10, 5:12])
    assert bool(images("cir").cache) == (cache_gib > 0)


def _reference_sigma(paths):
    """σ_b over every finite pixel of the dark frames, all in float64 at once (numpy's std)."""
    import spectral.io.envi as envi
    x = np.concatenate([np.asarray(envi.open(str(p)).load(), np.float64).reshape(-1, 6) for p in paths])
    return x[np.isfinite(x).all(1)].std(0, ddof=1)


def test_dark_sigma_by_blocks_equals_the_whole_frame_formula(tmp_path, monkeypatch):
    """Many row blocks and float64 pieces: σ_b equals the float64 reference within rounding and the
    one-block sums bit for bit; a frame's float64 copy is never held (traced peak well under it)."""
    root = make_scene(tmp_path / "s", n_frames=3, n_dark=3, w=128, h=96, dark_sigma=0.02)
    paths = sorted((root / "calibration").glob("dark_*.hdr"))
    one_block = read_scene(root).dark_sigma
    np.testing.assert_allclose(one_block, _reference_sigma(paths), rtol=1e-10)
    monkeypatch.setattr(cube_io, "CHUNK_BYTES", 128 * 6 * 4 * 5)       # five rows per block
    monkeypatch.setattr(noise, "SUM_PIXELS", 100)
    tracemalloc.start()
    sigma = read_scene(root).dark_sigma
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    np.testing.assert_array_equal(sigma, one_block)
    assert peak < 128 * 96 * 6 * 8 / 2                                   # half a frame in float64


def test_dark_sigma_skips_pixels_that_are_not_finite(tmp_path):
    from brfgs.data.cube_io import write_envi
    root = make_scene(tmp_path / "s", n_frames=3, n_dark=2, w=16, h=8)
    dark = np.random.default_rng(5).normal(0, 0.03, (8, 16, 6)).astype(np.float32)
    dark[2, 3, 1] = np.nan
    write_envi(root / "calibration" / "dark_01.hdr", dark, np.linspace(420.0, 880.0, 6))
    paths = sorted((root / "calibration").glob("dark_*.hdr"))
    np.testing.assert_allclose(read_scene(root).dark_sigma, _reference_sigma(paths), rtol=1e-10)
