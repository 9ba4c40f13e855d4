"""``brfgs kernels``: CSV columns and values, PNG, option errors."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from brfgs.cli import main


def _read(path):
    with open(path, newline="") as f:
        r = csv.reader(f)
        head = next(r)
        rows = np.array([[float(x) for x in row] for row in r])
    return head, rows


def test_kernels_csv_and_png(tmp_path):
    png = tmp_path / "fig" / "k.png"
    out_csv = tmp_path / "k.csv"
    rc = main(["kernels", "--sun-zenith", "35", "--roughness", "0.25", "--png", str(png), "--csv", str(out_csv),
               "--step", "5", "--max-view-zenith", "75"])
    assert rc == 0
    assert png.exists() and png.stat().st_size > 20_000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    head, rows = _read(out_csv)
    assert head == ["sun_zenith_deg", "view_zenith_deg", "relative_azimuth_deg", "k_ross", "k_li", "k_cook"]
    assert rows.shape == (16 * 72, 6)
    assert np.all(rows[:, 0] == 35.0)
    assert set(np.unique(rows[:, 1])) == set(np.arange(0, 76, 5.0))
    assert set(np.unique(rows[:, 2])) == set(np.arange(0, 360, 5.0))
    # values agree with the independent numpy reference of the kernel tests
    from test_brdf_kernels import np_cook, np_dir, np_li_sparse_r, np_ross_thick  # tests/ is on sys.path (conftest)

    ts = math.radians(35.0)
    tv, ph = np.deg2rad(rows[:, 1]), np.deg2rad(rows[:, 2])
    np.testing.assert_allclose(rows[:, 3], np_ross_thick(ts, tv, ph), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rows[:, 4], np_li_sparse_r(ts, tv, ph), rtol=1e-9, atol=1e-12)
    wi = np.broadcast_to(np_dir(np.array(ts), np.array(0.0)), (len(rows), 3))
    wo = np_dir(tv, ph)
    up = np.broadcast_to([0.0, 0.0, 1.0], wo.shape)
    np.testing.assert_allclose(rows[:, 5], np_cook(wi, wo, up, 0.25), rtol=1e-9, atol=1e-12)
    # hotspot row (θ_v = θ_s, φ = 0) is the Li maximum of the backscatter plane
    back = rows[rows[:, 2] == 0.0]
    assert back[np.argmax(back[:, 4]), 1] == 35.0


def test_kernels_default_png_in_out_dir_and_no_overwrite(tmp_path):
    assert main(["kernels", "--sun-zenith", "0", "--out", str(tmp_path), "--step", "10"]) == 0
    png = tmp_path / "kernels_sun0.png"
    assert png.exists()
    before = png.read_bytes()
    # an existing file is never replaced silently
    assert main(["kernels", "--sun-zenith", "0", "--out", str(tmp_path), "--step", "10"]) == 2
    assert png.read_bytes() == before
    assert main(["kernels", "--sun-zenith", "0", "--out", str(tmp_path), "--step", "10", "--overwrite"]) == 0


@pytest.mark.parametrize(
    "args",
    [
        ["--sun-zenith", "90"],
        ["--sun-zenith", "-1"],
        ["--sun-zenith", "nan"],
        ["--roughness", "0"],
        ["--roughness", "1.5"],
        ["--step", "0"],
        ["--max-view-zenith", "95"],
        ["--png", "figure.jpg"],
        ["--no-plot"],
    ],
)
def test_kernels_bad_options_exit_2(tmp_path, args, capsys):
    rc = main(["kernels", "--out", str(tmp_path), *args])
    assert rc == 2
    assert "brfgs: error" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
