"""Kernel integrals (white-sky, black-sky) against Lucht et al. (2000) and 1-D quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from brfgs.brdf import integrals as I
from brfgs.errors import UserError


def test_white_sky_integrals_match_lucht_table1():
    assert I.white_sky("isotropic") == 1.0
    assert I.white_sky("ross_thick") == pytest.approx(0.189184, abs=1e-3)
    assert I.white_sky("li_sparse_r") == pytest.approx(-1.377622, abs=1e-3)
    # the quadrature is in fact much better than the 1e-3 asked for
    assert I.white_sky("ross") == pytest.approx(0.189184, abs=1e-5)
    assert I.white_sky("li") == pytest.approx(-1.377622, abs=1e-4)


def test_black_sky_at_nadir_sun_matches_1d_quadrature():
    """θ_s = 0: ξ = θ_v and both kernels reduce to 1-D functions of θ_v (written out here)."""

    def ross(t):
        return ((np.pi / 2 - t) * np.cos(t) + np.sin(t)) / (1 + np.cos(t)) - np.pi / 4

    def li(t):
        # θ_i = 0: D = tan θ_v, cos t = 2 tan θ_v / (1 + sec θ_v), ξ' = θ_v
        sec = 1 / np.cos(t)
        ct = min(2 * np.tan(t) / (1 + sec), 1.0)
        tt = np.arccos(ct)
        return (tt - np.sin(tt) * np.cos(tt)) * (1 + sec) / np.pi - 1 - sec + 0.5 * (1 + np.cos(t)) * sec

    for name, fn in (("ross_thick", ross), ("li_sparse_r", li)):
        want = 2 * quad(lambda t: fn(t) * np.cos(t) * np.sin(t), 0, np.pi / 2, limit=200, points=[0.9273])[0]
        assert I.black_sky(name, 0.0) == pytest.approx(want, abs=1e-5)


@pytest.mark.parametrize("sun_zenith_deg", [0.0, 20.0, 40.0, 60.0])
def test_black_sky_close_to_modis_polynomials(sun_zenith_deg):
    """Lucht et al. (2000) Table 1 fits h(θ) = g0 + g1 θ² + g2 θ³ (θ in rad), good to ~0.02."""
    th = math.radians(sun_zenith_deg)
    poly = {"ross_thick": (-0.007574, -0.070987, 0.307588), "li_sparse_r": (-1.284909, -0.166314, 0.041840)}
    for name, (g0, g1, g2) in poly.items():
        assert I.black_sky(name, th) == pytest.approx(g0 + g1 * th**2 + g2 * th**3, abs=0.02)


def test_black_sky_many_and_cache_agree():
    th = np.deg2rad([10.0, 35.0, 50.0])
    many = I.black_sky_many("vol", th)
    assert many.shape == (3,)
    for t, v in zip(th, many):
        assert I.black_sky("ross", float(t)) == pytest.approx(v, rel=1e-12)
    assert I.black_sky("iso", 0.3) == 1.0


def test_white_sky_is_the_cosine_weighted_mean_of_black_sky():
    mu, w = np.polynomial.legendre.leggauss(40)
    mu, w = 0.5 * (mu + 1), 0.5 * w
    h = I.black_sky_many("li_sparse_r", np.arccos(mu))
    assert 2 * np.sum(w * mu * h) == pytest.approx(I.white_sky("li_sparse_r"), abs=1e-4)


def test_cook_torrance_integrals_bounded_and_need_roughness():
    v = I.black_sky("cook_torrance", 0.0, roughness=0.3)
    # same normalisation as the BRF kernels, (1/π)∫K cos θ dω: at normal incidence F ≈ F0 = 0.04
    # over the lobe, whose projected mass is 1/(1 + ρ²) (see test_brdf_kernels)
    assert v == pytest.approx(0.04 / (1 + 0.3**2) / math.pi, rel=0.05)
    assert 0.0 < I.white_sky("cook", roughness=0.3) < 0.1
    with pytest.raises(UserError):
        I.white_sky("cook_torrance")
    with pytest.raises(UserError):
        I.black_sky("cook_torrance", 0.2, roughness=0.0)


def test_bad_names_and_angles_are_user_errors():
    with pytest.raises(UserError):
        I.white_sky("walthall")
    with pytest.raises(UserError):
        I.black_sky("ross", math.pi / 2)
    with pytest.raises(UserError):
        I.black_sky("ross", -0.1)
