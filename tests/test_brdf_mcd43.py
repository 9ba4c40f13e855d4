"""MCD43-style kernel weights: kernels against the ATBD formulas (float64 numpy, written here), the
ATBD albedo polynomials against quadrature, the least-squares fit, and the per-pixel maps of a flat
model built with known kernel weights."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brfgs.brdf import integrals as I
from brfgs.brdf import mcd43 as M


def _atbd_kernels(ts_deg, tv_deg, phi_deg):
    """RossThick and LiSparse-R (h/b = 2, b/r = 1) as written in the MODIS BRDF/Albedo ATBD (float64)."""
    ts, tv, phi = np.radians(ts_deg), np.radians(tv_deg), np.radians(phi_deg)
    cos_xi = np.cos(ts) * np.cos(tv) + np.sin(ts) * np.sin(tv) * np.cos(phi)
    xi = np.arccos(np.clip(cos_xi, -1, 1))
    ross = ((np.pi / 2 - xi) * cos_xi + np.sin(xi)) / (np.cos(ts) + np.cos(tv)) - np.pi / 4
    br, hb = 1.0, 2.0
    tsp, tvp = np.arctan(br * np.tan(ts)), np.arctan(br * np.tan(tv))
    d2 = np.tan(tsp) ** 2 + np.tan(tvp) ** 2 - 2 * np.tan(tsp) * np.tan(tvp) * np.cos(phi)
    sec = 1 / np.cos(tsp) + 1 / np.cos(tvp)
    cos_t = np.clip(hb * np.sqrt(d2 + (np.tan(tsp) * np.tan(tvp) * np.sin(phi)) ** 2) / sec, -1, 1)
    t = np.arccos(cos_t)
    overlap = (t - np.sin(t) * cos_t) * sec / np.pi
    cos_xip = np.cos(tsp) * np.cos(tvp) + np.sin(tsp) * np.sin(tvp) * np.cos(phi)
    li = overlap - sec + 0.5 * (1 + cos_xip) / (np.cos(tsp) * np.cos(tvp))
    return ross, li


def test_design_matrix_matches_the_atbd_kernel_formulas():
    rng = np.random.default_rng(0)
    ts, tv, phi = rng.uniform(0, 70, 500), rng.uniform(0, 70, 500), rng.uniform(0, 360, 500)
    a = M.design_matrix(ts, tv, phi)
    ross, li = _atbd_kernels(ts, tv, phi)
    np.testing.assert_array_equal(a[:, 0], 1.0)
    np.testing.assert_allclose(a[:, 1], ross, atol=1e-9)
    np.testing.assert_allclose(a[:, 2], li, atol=1e-9)
    # limit case: both kernels are zero for sun and view at nadir
    np.testing.assert_allclose(M.design_matrix(0.0, 0.0, 0.0), [[1.0, 0.0, 0.0]], atol=1e-12)


@pytest.mark.parametrize("sun_zenith_deg", [0.0, 20.0, 40.0, 60.0])
def test_black_sky_polynomial_matches_quadrature(sun_zenith_deg):
    """The ATBD polynomial is a fit to the kernels' directional-hemispherical integrals: within 0.02 (RossThick)
    and 0.007 (LiSparse-R) of float64 quadrature over 0–60° (a wrong coefficient or sign is off by far more)."""
    f = np.eye(3)
    poly = M.black_sky_albedo(f, sun_zenith_deg)
    t = math.radians(sun_zenith_deg)
    quad = [1.0, I.black_sky("ross_thick", t), I.black_sky("li_sparse_r", t)]
    assert poly[0] == 1.0
    assert abs(poly[1] - quad[1]) < 0.02 and abs(poly[2] - quad[2]) < 0.007


def test_white_sky_integrals_are_the_published_values_and_match_quadrature():
    np.testing.assert_allclose(M.white_sky_albedo(np.eye(3)), [1.0, 0.189184, -1.377622], rtol=0, atol=0)
    np.testing.assert_allclose(M.WSA_INTEGRALS[1:], [I.white_sky("ross_thick"), I.white_sky("li_sparse_r")], atol=2e-4)


def test_nbar_is_the_brf_at_nadir_view():
    f = np.array([0.2, 0.1, 0.03])
    ross, li = _atbd_kernels(35.0, 0.0, 0.0)
    assert M.nbar(f, 35.0) == pytest.approx(0.2 + 0.1 * ross + 0.03 * li, abs=1e-12)


def test_fit_recovers_known_weights_and_reports_the_noise_as_rmse():
    sz, vz, ra = M.direction_grid()
    a = M.design_matrix(sz, vz, ra)
    rng = np.random.default_rng(1)
    f_true = np.stack([rng.uniform(0.05, 0.5, (6, 4)), rng.uniform(0, 0.2, (6, 4)), rng.uniform(0, 0.08, (6, 4))], -1)
    brf = f_true @ a.T                                            # [6, 4, G]
    f, rmse = M.fit_kernel_weights(brf, a)
    np.testing.assert_allclose(f, f_true, atol=1e-12)
    assert rmse.max() < 1e-12
    noisy = brf + rng.normal(0, 0.01, brf.shape)
    f_n, rmse_n = M.fit_kernel_weights(noisy, a)
    np.testing.assert_allclose(rmse_n, 0.01, rtol=0.2)             # ≈ σ·sqrt((G − 3)/G)
    # the streaming accumulator gives the same answer as the direct solve
    acc = M.KernelFitAccumulator()
    for g in range(0, a.shape[0], 7):                               # batches of 7 directions
        acc.add(np.moveaxis(noisy[..., g:g + 7], -1, 0), a[g:g + 7])
    f_s, rmse_s, cond = acc.solve()
    np.testing.assert_allclose(f_s, f_n, atol=1e-9)
    np.testing.assert_allclose(rmse_s, rmse_n, atol=1e-9)
    assert 1 < cond < 1e4


def test_fit_needs_three_directions():
    acc = M.KernelFitAccumulator()
    acc.add(np.ones((2, 5)), [[1.0, 0.0, 0.0], [1.0, 0.1, -1.0]])
    with pytest.raises(ValueError, match="three"):
        acc.solve()


def test_flat_model_with_known_kernel_weights_is_fitted_within_one_percent():
    """Issue 16: f_iso/f_vol/f_geo fitted on a flat model built with known kernel weights match them within 1 %."""
    from brfgs.products import maps as P
    from brfgs.products.mcd43_maps import render_mcd43
    from brfgs.model import camera_from_intrinsics
    from test_analysis_helpers import carpet_model

    z_left, z_right = np.array([0.45, 0.30, 0.12, 0.60]), np.array([0.05, 0.20, 0.35, 0.25])
    vol, geo = 0.4, 0.08
    bm = carpet_model(half_m=12.0, z_left=z_left, z_right=z_right, vol=vol, geo=geo, components=("iso", "vol", "geo"))
    c2w, intr = P.nadir_camera(bm, size=20, half_extent_m=5.0)        # 0.5 m pixels
    cam = camera_from_intrinsics(c2w, intr)
    out = render_mcd43(bm, cam, nbar_sun_zenith_deg=30.0, albedo_sun_zenith_deg=45.0, backend="cpu")
    alpha = out["alpha"][..., None]
    assert alpha.min() > 0.99
    for cols, z in ((slice(0, 4), z_left), (slice(16, 20), z_right)):   # > 3 m from the seam at x = 0
        for name, w in (("f_iso", 1.0), ("f_vol", vol), ("f_geo", geo)):
            got = (out[name] / alpha)[:, cols]
            np.testing.assert_allclose(got, np.broadcast_to(w * z, got.shape), rtol=0.01)
    assert np.nanmax(out["fit_rmse"][:, :4]) < 1e-4 and np.nanmax(out["fit_rmse"][:, 16:]) < 1e-4
    # products computed from the weights agree with the model's own latent-space NBAR
    ref = P.render_products(bm, cam, nbar_sun_zenith_deg=30.0, which=("nbar",), backend="cpu")
    np.testing.assert_allclose(out["nbar_mcd43"], ref["nbar"], atol=2e-4)
    assert out["settings"]["grid"]["n_directions"] == len(M.direction_grid()[0])
