"""What grows with the image and what does not: the Gaussian cap follows the pixel count unless it is
given (60,000 up to 128², as before), and band selection stays the full EFC on small scenes and is
bounded (a downscaled copy of each view, an evenly spread subset of the views) on large ones."""

import cv2
import numpy as np
import pytest
from scenes import make_scene

from brfgs.bands import compute_band_stats, select_bands
from brfgs.bands.options import DEFAULT_DETECT_MAX_MPX, DEFAULT_DETECT_MAX_PX
from brfgs.bands.select import detect_downscale_factor, spread_views, views_within_budget
from brfgs.data import read_scene
from brfgs.data.cube_io import write_envi
from brfgs.errors import UserError
from brfgs.train.config import TrainConfig, auto_max_gaussians, with_gaussian_cap
from brfgs.train.trainer import Trainer


def test_gaussian_cap_is_60000_up_to_128px_and_grows_above():
    assert TrainConfig().max_gaussians == 0                        # the default follows the image
    assert auto_max_gaussians(64, 64) == auto_max_gaussians(128, 128) == auto_max_gaussians(24, 16) == 60_000
    assert auto_max_gaussians(256, 256) == 240_000 and auto_max_gaussians(512, 384) == 720_000
    assert auto_max_gaussians(1886, 1886) == 3_000_000             # the memory cap
    assert with_gaussian_cap(TrainConfig(), 256, 256).max_gaussians == 240_000
    assert with_gaussian_cap(TrainConfig(max_gaussians=777), 1886, 1886).max_gaussians == 777   # given: kept
    with pytest.raises(UserError, match="max_gaussians"):
        TrainConfig(max_gaussians=-1).validate()


def test_trainer_resolves_the_cap_from_its_scene(tmp_path):
    """The run trains with 60,000 on a small scene, as before; config.json keeps the option as given."""
    root = make_scene(tmp_path / "s", n_frames=7, n_dark=0)
    tr = Trainer(root, tmp_path / "run", TrainConfig(), progress=False, log=None)
    tr.scene = read_scene(root)
    tr._scale_schedule()
    assert tr.cfg.max_gaussians == 60_000 and tr.state.cfg.max_gaussians == 60_000
    tr = Trainer(root, tmp_path / "run2", TrainConfig(max_gaussians=1234), progress=False, log=None)
    tr.scene = read_scene(root)
    tr._scale_schedule()
    assert tr.cfg.max_gaussians == 1234


def test_small_scenes_keep_full_efc():
    """64² and 128² flights (49 views, 164 bands) and a 49-view 256² scene use every pixel of every view."""
    for size in (64, 128, 256):
        factor = detect_downscale_factor(size, size, DEFAULT_DETECT_MAX_PX)
        assert factor == 1
        assert views_within_budget(list(range(49)), size, size, 164, factor, DEFAULT_DETECT_MAX_MPX) == list(range(49))


def test_large_scenes_are_bounded():
    assert detect_downscale_factor(1886, 1886, DEFAULT_DETECT_MAX_PX) == 4
    views = views_within_budget(list(range(49)), 1886, 1886, 164, 4, DEFAULT_DETECT_MAX_MPX)
    assert 10 <= len(views) <= 20 and views[0] == 0 and views[-1] == 48
    assert len(views) * (1886 // 4) ** 2 * 164 <= DEFAULT_DETECT_MAX_MPX * 1e6
    gaps = np.diff(views)
    assert gaps.max() - gaps.min() <= 1                            # evenly spread over the frames
    assert spread_views([5, 7, 9], 10) == [5, 7, 9] and spread_views([5, 7, 9], 1) == [5]


def test_default_stats_of_a_small_scene_equal_the_unbounded_ones(tmp_path):
    sc = read_scene(make_scene(tmp_path / "s", n_frames=7, n_dark=2))
    a = compute_band_stats(sc)
    b = compute_band_stats(sc, detect_max_px=None, detect_max_mpx=None)
    assert a.views == b.views and len(a.views) == 7
    np.testing.assert_array_equal(a.efc, b.efc)
    np.testing.assert_array_equal(a.features, b.features)


def _textured_scene(root, size=64, factor=4, n_views=6, n_bands=8):
    """Smooth textures whose contrast and brightness differ by band (some bands dim and flat), upsampled by
    ``factor`` as scripts/make_big_scene.py does: the bands full EFC ranks first are clear."""
    import json
    from brfgs.data.cameras import Intrinsics, pose_from_view_angles
    rng = np.random.default_rng(2)
    wl = np.linspace(450.0, 900.0, n_bands)
    gain = np.array([0.05, 0.4, 1.0, 0.2, 0.9, 0.1, 0.6, 0.02])[:n_bands]
    big = size * factor
    frames = []
    for k in range(n_views):
        tex = cv2.GaussianBlur(rng.random((size, size)).astype(np.float32), (0, 0), 1.5)
        tex = (tex - tex.mean()) / tex.std()
        cube = np.stack([0.05 + g * 0.3 + 0.06 * g * tex for g in gain], -1).astype(np.float32)
        cube = cv2.resize(cube, (big, big), interpolation=cv2.INTER_LINEAR).reshape(big, big, n_bands)
        write_envi(root / "images" / f"v{k}.hdr", cube, wl)
        frames.append({"file_path": f"images/v{k}.hdr", "transform_matrix": pose_from_view_angles(
            0.0 if k == 0 else 30.0, 60.0 * k, 100.0).tolist()})
    intr = Intrinsics.from_fov(35.0, big, big)
    (root / "transforms.json").write_text(json.dumps({
        "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": big, "h": big,
        "wavelengths_nm": wl.tolist(), "sun_zenith_deg": 35.0, "sun_azimuth_deg": 150.0,
        "dark_sigma": [0.002] * n_bands, "frames": frames}))
    return read_scene(root)


def test_bounded_selection_chooses_the_full_efc_bands_on_an_upsampled_scene(tmp_path):
    """256² views: a copy downscaled to 128² and half the views choose the bands that every pixel of
    every view chooses."""
    sc = _textured_scene(tmp_path / "big")
    full = select_bands(sc, "efc-top3", detect_max_px=None, detect_max_mpx=None)
    bounded = select_bands(sc, "efc-top3", detect_max_px=128, detect_max_mpx=3 * 128 * 128 * 8 / 1e6)
    assert bounded.stats.detect_downscale == 2 and len(bounded.stats.views) == 3 and len(full.stats.views) == 6
    assert bounded.selected == full.selected


def test_reduced_read_is_the_area_average(tmp_path):
    sc = read_scene(make_scene(tmp_path / "s", n_frames=3, n_dark=0, w=24, h=16))
    whole = sc.load_image(1)
    ref = whole.reshape(4, 4, 6, 4, 6).mean(axis=(1, 3), dtype=np.float64)
    np.testing.assert_allclose(sc.load_reduced(1, 4), ref, rtol=1e-6)
    assert sc.load_reduced(1, 4).shape == (4, 6, 6)
