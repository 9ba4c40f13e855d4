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


def test_backprojection_by_windows_equals_the_whole_views(tmp_path, monkeypatch):
    """Set-up's per-Gaussian targets of frames the cache cannot hold, computed window by window (7 px
    squares), equal those of whole views within float32 rounding (a window camera's shifted principal point); so does the lit surface's reflectance."""
    import torch
    from brfgs.model import init_from_points
    from brfgs.model.camera import cameras_from_description, scene_description
    from brfgs.train import images as images_mod
    from brfgs.train.targets import backprojected_reflectance, backprojected_targets

    sc = read_scene(make_scene(tmp_path / "s", w=20, h=14, n_bands=5, n_dark=0))
    rng = np.random.default_rng(0)
    pts = rng.uniform(-8, 8, (300, 3)).astype(np.float32)
    pts[:, 2] = 0.0
    gm = init_from_points(pts, np.full((300, 3), 0.3, np.float32), latent_dim=4)
    cams = cameras_from_description(scene_description(sc, np.stack([f.c2w for f in sc.frames])))
    idx = sc.train_indices
    held, windowed = ImageStore(sc, idx), ImageStore(sc, idx, cache_gib=0.0)
    monkeypatch.setattr(images_mod, "TILE_PX", 7)
    pieces = list(windowed.tiles(idx[0], cams[idx[0]]))
    assert len(pieces) == 6 and pieces[-1][0].width == 6 and pieces[-1][1].shape == (7, 6, 5)
    whole = backprojected_targets(gm, held, cams, idx, backend="torch")
    tiled = backprojected_targets(gm, windowed, cams, idx, backend="torch")
    np.testing.assert_allclose(tiled.numpy(), whole.numpy(), rtol=1e-4, atol=1e-6)   # float32 pixel coordinates
    light = torch.tensor([0.5, 1.0, 2.0, 0.25, 1.5])
    lit = [backprojected_reflectance(gm, s, cams, idx, lambda i, cam: light.expand(cam.height, cam.width, 5),
                                     backend="torch") for s in (held, windowed)]
    np.testing.assert_allclose(lit[1].numpy(), lit[0].numpy(), rtol=1e-4, atol=1e-6)
    assert not windowed.cache


def test_autoencoder_pixels_by_row_blocks_equal_the_whole_frames(tmp_path):
    """The decoder's training pixels drawn from frames read by row blocks (valid mask, then the chosen
    pixels) are those drawn from whole cubes, NaN pixels skipped alike."""
    from brfgs.data.pixels import FramePixels
    from brfgs.spectral.autoencoder import sample_pixels

    root = make_scene(tmp_path / "s", n_frames=4, n_dark=0, w=24, h=16)
    sc = read_scene(root)
    whole = [sc.load_image(i) for i in range(4)]
    whole[1][3, 4, 2] = np.nan
    sc.load_image = lambda i, bands=None: whole[i].copy()     # the reader's NaN pixel, for both paths
    sc.scan_image = lambda i, bands=None, visit=None: [visit(r, r + 5, whole[i][r:r + 5]) for r in range(0, 16, 5)]
    a = sample_pixels([lambda i=i: sc.load_image(i) for i in range(4)], 300, seed=4)
    b = sample_pixels([lambda i=i: FramePixels(sc, i) for i in range(4)], 300, seed=4)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (4 * 75, 6) and np.isfinite(a).all()
    store = ImageStore(sc, [0, 1, 2, 3], cache_gib=0.0)
    assert isinstance(store.for_sampling(2), FramePixels)
    assert isinstance(ImageStore(sc, [0, 1]).for_sampling(1), np.ndarray)
