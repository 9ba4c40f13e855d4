"""The training image store: invalid pixels zeroed with a mask, NaN for the autoencoder's sampler, and a
cached store never altered by a caller."""

import numpy as np
import pytest

from brfgs.data.scene import read_scene
from brfgs.train.images import ImageStore
from scenes import make_scene


@pytest.mark.parametrize("cache_gib", [4.0, 0.0])
def test_image_store_masks_invalid_pixels(tmp_path, cache_gib):
    sc = read_scene(make_scene(tmp_path / "s", n_frames=3, n_dark=0))
    raw = sc.load_image(1)
    raw[2, 3, :] = np.nan                                       # an invalid pixel, as a reader reports it
    sc.load_image = lambda i, bands=None: raw.copy() if i == 1 else read_scene(tmp_path / "s").load_image(i)
    store = ImageStore(sc, [0, 1, 2], cache_gib=cache_gib)
    assert store.cached == (cache_gib > 0)
    img, valid = store.get(1)
    assert not bool(valid[2, 3]) and int((~valid).sum()) == 1
    assert float(img[2, 3].abs().sum()) == 0.0
    np.testing.assert_array_equal(img.numpy()[valid.numpy()], raw[valid.numpy()])
    nan = store.get_with_nan(1)
    assert np.isnan(nan[2, 3]).all() and np.isfinite(np.delete(nan.reshape(-1, nan.shape[-1]), 2 * nan.shape[1] + 3, 0)).all()
    again, _ = store.get(1)                                     # the cached tensor is unchanged by get_with_nan
    assert float(again[2, 3].abs().sum()) == 0.0
