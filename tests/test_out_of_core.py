"""Cubes read by window: a training patch's values equal the whole cube's read then cropped, for every
ENVI interleave, data type and byte order and for TIFF strips and tiles, and a training step reads
a window's bytes, not the cube's."""

import json
from types import SimpleNamespace

import numpy as np
import pytest
import tifffile

from brfgs.data import cube_io, read_scene
from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.data.cube_io import ENVI_DATA_TYPES, bytes_read, write_envi
from brfgs.errors import UserError
from brfgs.model.camera import camera_from_c2w
from brfgs.train.images import TrainImages
from brfgs.train.phases import Phase
from brfgs.train.step import make_batch

H, W, B = 10, 12, 4
WL = np.linspace(450.0, 850.0, B)


def _scene_json(root, files, w=W, h=H, extra=None):
    intr = Intrinsics.from_fov(35.0, w, h)
    frames = [{"file_path": f, "transform_matrix": pose_from_view_angles(0.0 if k == 0 else 30.0, 90.0 * k, 100.0).tolist()}
              for k, f in enumerate(files)]
    for k, fr in enumerate(frames):
        fr.update((extra or {}).get(k, {}))
    meta = {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": w, "h": h,
            "wavelengths_nm": WL.tolist(), "sun_zenith_deg": 35.0, "sun_azimuth_deg": 150.0,
            "dark_sigma": [0.01] * B, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(meta))


def _stored(dtype: np.dtype, rng) -> tuple[np.ndarray, float]:
    """Stored values [H, W, B] of ``dtype`` and the reflectance scale factor that makes them 0..~2."""
    if dtype.kind == "f":
        v = rng.uniform(-0.2, 2.0, (H, W, B))
        v[1, 2, 0], v[3, 4, 2], v[5, 5, 1] = np.nan, -0.7, 12.0   # no data, below the range (masked), a glint
        return v.astype(dtype), 1.0
    top = min(np.iinfo(dtype).max, 20000)
    return rng.integers(0, top, (H, W, B)).astype(dtype), top / 2.0


def _write_raw_envi(path_hdr, stored: np.ndarray, code: str, interleave: str, byte_order: int, offset: int,
                    scale: float, ignore: int | None):
    order = ">" if byte_order else "<"
    arr = stored.astype(stored.dtype.newbyteorder(order))
    layout = {"bip": arr, "bil": arr.transpose(0, 2, 1), "bsq": arr.transpose(2, 0, 1)}[interleave]
    hdr = (f"ENVI\nsamples = {W}\nlines = {H}\nbands = {B}\nheader offset = {offset}\ndata type = {code}\n"
           f"interleave = {interleave}\nbyte order = {byte_order}\nreflectance scale factor = {scale}\n"
           f"wavelength = {{{', '.join(f'{w:.4f}' for w in WL)}}}\n")
    if ignore is not None:
        hdr += f"data ignore value = {ignore}\n"
    path_hdr.write_text(hdr)
    path_hdr.with_suffix(".img").write_bytes(b"\x07" * offset + np.ascontiguousarray(layout).tobytes())


def _assert_windows_match(sc, i, bands=None):
    whole = sc.load_image(i, bands=bands)
    w, h = sc.width, sc.height
    for win in [(0, 0, w, h), (1, 2, w // 2, h // 2), (w - 3, h - 2, 3, 2), (w // 2, 0, 1, 1)]:
        x0, y0, w, h = win
        got = sc.load_window(i, win, bands=bands)
        assert got.dtype == np.float32 and got.shape == (h, w, whole.shape[2])
        np.testing.assert_array_equal(got, whole[y0:y0 + h, x0:x0 + w])   # NaN where NaN, bit for bit


@pytest.mark.parametrize("byte_order", [0, 1])
@pytest.mark.parametrize("interleave", ["bsq", "bil", "bip"])
def test_envi_window_equals_whole_read_cropped(tmp_path, interleave, byte_order):
    """Every ENVI data type (one frame each), with a header offset, a no-data value and a scale factor;
    also band subsets, a downscaled ROI and a frame with an irradiance scale."""
    rng = np.random.default_rng(3)
    (tmp_path / "images").mkdir()
    files = []
    for k, (code, name) in enumerate(ENVI_DATA_TYPES.items()):
        stored, scale = _stored(np.dtype(name), rng)
        ignore = int(stored[0, 0, 1]) if stored.dtype.kind != "f" else None
        _write_raw_envi(tmp_path / "images" / f"v{k}.hdr", stored, code, interleave, byte_order, 3 * k, scale, ignore)
        files.append(f"images/v{k}.hdr")
    _scene_json(tmp_path, files, extra={2: {"irradiance_scale": 1.3}})
    sc = read_scene(tmp_path, value_range=(-0.5, 10.0))
    for i in range(len(files)):
        _assert_windows_match(sc, i)
        _assert_windows_match(sc, i, bands=[1, 3])
    small = read_scene(tmp_path, downscale=2, roi=(2, 1, 10, 8), value_range=(-1.0, 20.0))
    for i in range(len(files)):
        _assert_windows_match(small, i)


@pytest.mark.parametrize("planar", ["contig", "separate"])
@pytest.mark.parametrize("layout", [dict(compression="zlib", rowsperstrip=3), dict(compression="zlib", tile=(16, 16)),
                                    dict(rowsperstrip=4), dict()])
@pytest.mark.parametrize("byteorder", ["<", ">"])
def test_tiff_window_equals_whole_read_cropped(tmp_path, planar, layout, byteorder):
    """TIFF cubes of strips or tiles, compressed or not, big or little endian: the window decodes only
    the segments it touches and gives the whole read's values."""
    h, w = 40, 36
    rng = np.random.default_rng(1)
    cube = rng.uniform(0.0, 1.0, (h, w, B)).astype(np.float32)
    (tmp_path / "images").mkdir()
    files = []
    for k in range(3):
        data = np.moveaxis(cube + k, -1, 0) if planar == "separate" else cube + k
        tifffile.imwrite(tmp_path / "images" / f"v{k}.tif", data, photometric="minisblack", planarconfig=planar,
                         byteorder=byteorder, **layout)
        files.append(f"images/v{k}.tif")
    _scene_json(tmp_path, files, w=w, h=h)
    sc = read_scene(tmp_path)
    before = bytes_read()
    _assert_windows_match(sc, 1)
    _assert_windows_match(sc, 2, bands=[0, 2])
    assert bytes_read() > before
    if layout.get("tile") or layout.get("rowsperstrip"):   # segmented: a small window reads few segments
        before = bytes_read()
        sc.load_window(0, (0, 0, 4, 4))
        assert bytes_read() - before < cube.nbytes / 2


def _big_scene(root, h=256, w=256, b=16, n=3):
    rng = np.random.default_rng(0)
    wl = np.linspace(450.0, 850.0, b)
    for k in range(n):
        write_envi(root / "images" / f"v{k}.hdr", rng.uniform(0.05, 0.5, (h, w, b)).astype(np.float32), wl)
    intr = Intrinsics.from_fov(35.0, w, h)
    frames = [{"file_path": f"images/v{k}.hdr",
               "transform_matrix": pose_from_view_angles(0.0 if k == 0 else 30.0, 120.0 * k, 100.0).tolist()}
              for k in range(n)]
    (root / "transforms.json").write_text(json.dumps({
        "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": w, "h": h,
        "wavelengths_nm": wl.tolist(), "sun_zenith_deg": 35.0, "sun_azimuth_deg": 150.0,
        "dark_sigma": [0.01] * b, "frames": frames}))
    return read_scene(root)


def test_training_step_reads_a_window_not_the_cube(tmp_path):
    """256 x 256 x 16 cubes, no cache, a 32² patch: after the frame's one-time whole-frame check (read a
    row block at a time), a stage-2 step's batch reads the patch's bytes only."""
    sc = _big_scene(tmp_path)
    cube_bytes = 256 * 256 * 16 * 4
    patch_bytes = 32 * 32 * 16 * 4
    intr = sc.intrinsics
    cams = [camera_from_c2w(f.name, f.c2w, intr.K(), intr.w, intr.h)
            for f in sc.frames]
    state = SimpleNamespace(cameras=cams)
    images = TrainImages(sc, [0, 1, 2], [0, 1, 2], [1.0, 1.0, 1.0], cache_gib=0.0)
    i = sc.train_indices[0]
    before = bytes_read()
    make_batch(state, images, Phase.STAGE2, i, (40, 100, 32, 32))
    first = bytes_read() - before
    assert cube_bytes <= first <= cube_bytes + 2 * patch_bytes    # the frame's check, then the patch
    before = bytes_read()
    batch = make_batch(state, images, Phase.STAGE2, i, (200, 7, 32, 32))
    assert 0 < bytes_read() - before <= 2 * patch_bytes
    whole = sc.load_image(i)
    np.testing.assert_array_equal(batch.target.numpy(), whole[7:39, 200:232])
    assert batch.cam.width == 32 and batch.valid.all() and not images("full").cache


def test_window_of_a_frame_out_of_range_is_refused(tmp_path):
    """The frame-level range check holds for windowed reads: a frame with 10 % of its pixels above the
    range is refused at its first window, though the window itself is clean."""
    sc = _big_scene(tmp_path, h=40, w=40, b=4)
    bad = np.asarray(sc.load_image(1)).copy()
    bad[:4] = 50.0
    write_envi(tmp_path / "images" / "v1.hdr", bad, np.linspace(450.0, 850.0, 4))
    images = TrainImages(read_scene(tmp_path), [0, 1], [0, 1, 2], [1.0] * 3, cache_gib=0.0)
    with pytest.raises(UserError, match="outside the plausible reflectance range"):
        images("full").get_window(1, (0, 30, 8, 8))


def test_row_blocks_keep_values(tmp_path, monkeypatch):
    """Reading in many small row blocks gives the values of one block (the block size is not a result)."""
    sc = _big_scene(tmp_path, h=40, w=24, b=4)
    whole = sc.load_image(0)
    monkeypatch.setattr(cube_io, "CHUNK_BYTES", 24 * 4 * 4 * 3)   # three rows per block
    np.testing.assert_array_equal(read_scene(tmp_path).load_image(0), whole)
    np.testing.assert_array_equal(read_scene(tmp_path, downscale=2).load_window(0, (1, 3, 6, 9)),
                                  read_scene(tmp_path, downscale=2).load_image(0)[3:12, 1:7])
