"""Scene reader: formats, downscale/ROI/band subset, poses from angles, dark σ, split, CIR."""

import json

import numpy as np
import pytest
from scenes import make_scene

from brfgs.data import read_scene
from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.cameras import GL_TO_CV, Intrinsics, project_points, viewmat_from_c2w
from brfgs.data.cir import cir_band_indices, cir_composite, cir_scale
from brfgs.data.cube_io import write_envi


def _raw(scene_root, name):
    import spectral.io.envi as envi

    return np.asarray(envi.open(str(scene_root / "images" / f"{name}.hdr")).load())


def test_reads_envi_scene(tmp_path):
    root = make_scene(tmp_path / "s")
    sc = read_scene(root)
    assert sc.n_bands == 6 and len(sc.frames) == 7
    assert (sc.width, sc.height) == (24, 16)
    img = sc.load_image(3)
    np.testing.assert_array_equal(img, _raw(root, sc.frames[3].name))
    assert img.dtype == np.float32


def test_downscale_is_area_average_and_roi_band_subset(tmp_path):
    root = make_scene(tmp_path / "s", w=24, h=16)
    raw = _raw(root, "view_02")
    sc = read_scene(root, downscale=4, bands=[1, 4], roi=(4, 0, 16, 12))
    img = sc.load_image(2)
    ref = raw[0:12, 4:20][:, :, [1, 4]].reshape(3, 4, 4, 4, 2).mean(axis=(1, 3))
    np.testing.assert_allclose(img, ref, rtol=1e-6)
    assert img.shape == (3, 4, 2)
    np.testing.assert_allclose(sc.wavelengths_nm, np.linspace(420, 880, 6)[[1, 4]])
    # intrinsics follow crop then scale: a world point projects to the same content
    full = Intrinsics(**{k: getattr(sc.full_intrinsics, k) for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")})
    pts = np.array([[1.0, -2.0, 0.5]])
    uv_full, _ = project_points(pts, sc.frames[2].c2w, full)
    uv_small, _ = project_points(pts, sc.frames[2].c2w, sc.intrinsics)
    np.testing.assert_allclose(uv_small, (uv_full - [4, 0]) / 4, atol=1e-9)


@pytest.mark.parametrize("compression", [None, "lzw", "deflate", "zstd"])
def test_npy_and_geotiff_cubes(tmp_path, compression):
    """Band-first GeoTIFF cubes, uncompressed and with the usual compressions (imagecodecs), tiled for zstd."""
    import tifffile

    root = make_scene(tmp_path / "s", fmt="npy")
    sc = read_scene(root)
    ref = np.load(root / "images" / "view_01.npy")
    np.testing.assert_array_equal(sc.load_image(1), ref)
    # the same scene as band-first GeoTIFF
    meta = json.loads((root / "transforms.json").read_text())
    for fr in meta["frames"]:
        cube = np.load(root / fr["file_path"])
        tif = fr["file_path"].replace(".npy", ".tif")
        tifffile.imwrite(root / tif, np.moveaxis(cube, -1, 0), photometric="minisblack", planarconfig="separate",
                         compression=compression, tile=(16, 16) if compression == "zstd" else None)
        fr["file_path"] = tif
    (root / "transforms.json").write_text(json.dumps(meta))
    sc2 = read_scene(root, downscale=2)
    np.testing.assert_allclose(sc2.load_image(1), ref.reshape(8, 2, 12, 2, 6).mean(axis=(1, 3)), rtol=1e-6)


def test_pose_from_view_angles_follows_conventions(tmp_path):
    root = make_scene(tmp_path / "s", angles_only=True)
    sc = read_scene(root)
    for f in sc.frames:
        c = f.c2w[:3, 3]
        np.testing.assert_allclose(np.linalg.norm(c), 100.0)
        np.testing.assert_allclose(c / 100.0, direction_from_angles_deg(f.view_zenith_deg, f.view_azimuth_deg),
                                   atol=1e-12)
        # looks at the scene centre: the origin projects to the principal point
        uv, depth = project_points(np.zeros((1, 3)), f.c2w, sc.intrinsics)
        np.testing.assert_allclose(uv[0], [sc.intrinsics.cx, sc.intrinsics.cy], atol=1e-9)
        assert depth[0] == pytest.approx(100.0)
        cam_up = f.c2w[:3, 1]  # OpenGL +Y = image up
        if f.view_zenith_deg == 0:
            np.testing.assert_allclose(cam_up, [0, 1, 0], atol=1e-12)  # north up for nadir
        else:
            assert cam_up[2] > 0  # image-up toward +z
    # OpenCV viewmat: +z forward
    vm = viewmat_from_c2w(sc.frames[0].c2w)
    assert vm[2, :3] @ np.array([0, 0, -1.0]) == pytest.approx(1.0)
    assert GL_TO_CV.shape == (4, 4)


def test_dark_sigma_from_dark_frames_and_fallbacks(tmp_path):
    sc = read_scene(make_scene(tmp_path / "a", n_dark=4, dark_sigma=0.02, w=40, h=30))
    assert sc.dark_sigma_source == "dark_frames"
    np.testing.assert_allclose(sc.dark_sigma, 0.02, rtol=0.05)
    sc = read_scene(make_scene(tmp_path / "b", n_dark=0, dark_sigma=0.003))
    assert sc.dark_sigma_source == "transforms.json"
    np.testing.assert_allclose(sc.dark_sigma, 0.003)
    # no dark information: estimated from the images (i.i.d. noise of known σ on a smooth image)
    root = make_scene(tmp_path / "c", n_dark=0)
    meta = json.loads((root / "transforms.json").read_text())
    del meta["dark_sigma"]
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:64, 0:64]
    for fr in meta["frames"]:
        smooth = 0.3 + 0.1 * np.sin(xx / 9.0)[..., None] * np.ones(6)
        write_envi(root / fr["file_path"], (smooth + rng.normal(0, 0.01, (64, 64, 6))).astype("f4"), meta["wavelengths_nm"])
    meta.update(w=64, h=64, cx=32.0, cy=32.0)
    (root / "transforms.json").write_text(json.dumps(meta))
    sc = read_scene(root)
    assert sc.dark_sigma_source == "estimated"
    np.testing.assert_allclose(sc.dark_sigma, 0.01, rtol=0.15)


def test_split_is_deterministic_six_to_one_and_honours_frame_split(tmp_path):
    root = make_scene(tmp_path / "s", n_frames=49, w=8, h=8, n_dark=0)
    a, b = read_scene(root, split_seed=3), read_scene(root, split_seed=3)
    assert a.test_indices == b.test_indices
    assert len(a.test_indices) == 7 and len(a.train_indices) == 42
    assert read_scene(root, split_seed=4).test_indices != a.test_indices
    meta = json.loads((root / "transforms.json").read_text())
    meta["frames"][0]["split"] = "test"
    forced_train = a.test_indices[0]
    meta["frames"][forced_train]["split"] = "train"
    (root / "transforms.json").write_text(json.dumps(meta))
    c = read_scene(root, split_seed=3)
    assert 0 in c.test_indices and forced_train in c.train_indices
    assert len(c.test_indices) == 7


def test_cir_composite_scaling(tmp_path):
    root = make_scene(tmp_path / "s", n_bands=8)
    sc = read_scene(root)
    wl = sc.wavelengths_nm
    idx = cir_band_indices(wl)
    assert [wl[i] for i in idx] == [wl[np.argmin(abs(wl - t))] for t in (850, 650, 550)]
    scale = cir_scale(sc)
    ref = [np.percentile(np.concatenate([sc.load_image(i)[..., b].ravel() for i in sc.train_indices]), 99)
           for b in idx]
    np.testing.assert_allclose(scale, ref, rtol=1e-6)
    rgb = cir_composite(sc.load_image(0), idx, scale)
    assert rgb.shape == (16, 24, 3) and rgb.min() >= 0 and rgb.max() <= 1
    np.testing.assert_allclose(rgb[..., 0], np.clip(sc.load_image(0)[..., idx[0]] / scale[0], 0, 1), rtol=1e-6)


def test_nan_pixels_are_masked_and_counted(tmp_path):
    root = make_scene(tmp_path / "s")
    sc = read_scene(root)
    cube = sc.load_image(2)
    cube[3, 4, 1] = np.nan
    cube[5, 6, :] = np.inf
    write_envi(sc.frames[2].path, cube, sc.wavelengths_nm)
    sc = read_scene(root)
    img = sc.load_image(2)
    mask = sc.valid_mask(2, img)
    assert not mask[3, 4] and not mask[5, 6] and mask.sum() == mask.size - 2
    assert np.isnan(img[5, 6]).all()
    assert sc.invalid_counts[sc.frames[2].name] == 2


def test_truth_cubes_follow_band_subset_roi_and_downscale(tmp_path):
    root = make_scene(tmp_path / "s", w=24, h=16)
    rng = np.random.default_rng(5)
    clean = rng.random((16, 24, 6)).astype(np.float32)
    write_envi(root / "truth" / "images" / "view_01.hdr", clean, np.linspace(420, 880, 6))
    sc = read_scene(root, downscale=2, bands=[0, 5], roi=(2, 2, 20, 12))
    t = sc.load_truth(1)
    np.testing.assert_allclose(t, clean[2:14, 2:22][:, :, [0, 5]].reshape(6, 2, 10, 2, 2).mean(axis=(1, 3)), rtol=1e-6)
    assert sc.load_truth(2) is None  # no truth for that frame
    assert read_scene(make_scene(tmp_path / "n")).load_truth(0) is None  # no truth/ folder
