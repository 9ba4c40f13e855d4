"""Kernel products: NBAR, albedos (against published integrals and brute-force quadrature), ANIX."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from brfgs.products import maps as P
from brfgs.model import camera_from_intrinsics
from test_analysis_helpers import carpet_model

Z = np.array([0.45, 0.30, 0.12, 0.60])


@pytest.mark.parametrize("components", [("iso",), ("iso", "vol", "geo", "spec")])
def test_iso_only_gaussians_have_nbar_and_albedo_equal_to_z_iso(components):
    """With only z_iso (other coefficients zero or absent) NBAR and both albedos are z_iso exactly."""
    bm = carpet_model(half_m=2.0, z_left=Z, z_right=Z * 0.5, components=components)
    z_iso = bm.gaussians.params["z_iso"].detach()
    for sz in (0.0, 30.0, 60.0):
        assert torch.equal(P.nbar_latent(bm, sz), z_iso)
        assert torch.equal(P.albedo_latent(bm, "black", sz), z_iso)
    assert torch.equal(P.albedo_latent(bm, "white"), z_iso)


def test_rendered_products_of_an_isotropic_surface():
    bm = carpet_model(half_m=12.0, z_left=Z, z_right=Z, components=("iso", "vol", "geo", "spec"))
    c2w, intr = P.nadir_camera(bm, size=16, half_extent_m=6.0)
    out = P.render_products(bm, camera_from_intrinsics(c2w, intr), nbar_sun_zenith_deg=20.0, albedo_sun_zenith_deg=50.0, backend="cpu")
    alpha = out["alpha"]
    assert alpha.min() > 0.995
    for name in ("iso", "total", "nbar", "bsa", "wsa"):
        np.testing.assert_allclose(out[name], alpha[..., None] * Z, rtol=1e-5, atol=1e-6)
    for name in ("vol", "geo", "spec"):
        np.testing.assert_allclose(out[name], 0.0, atol=1e-6)
    np.testing.assert_allclose(out["anix"], 1.0, atol=1e-5)


def test_white_sky_albedo_uses_the_published_kernel_integrals():
    """α_ws = z_iso + 0.189184 z_vol − 1.377622 z_geo (Lucht et al. 2000, Table 1)."""
    bm = carpet_model(half_m=1.0, z_left=Z, z_right=Z, vol=0.4, geo=0.05, components=("iso", "vol", "geo"))
    got = P.albedo_latent(bm, "white")[0].numpy()
    ref = Z * (1.0 + 0.4 * 0.189184 - 0.05 * 1.377622)
    np.testing.assert_allclose(got, ref, rtol=2e-4)


def test_black_sky_albedo_matches_quadrature_of_the_brf():
    """Identity decoder: the latent-space black-sky albedo must equal (1/π)∫ BRF cos θ_v dω_v of the
    model's own BRF (brute-force Gauss–Legendre quadrature over the view hemisphere)."""
    bm = carpet_model(half_m=1.0, z_left=Z, z_right=Z, vol=0.5, geo=0.1, spec=0.8, roughness=0.3)
    for sz in (20.0, 50.0):
        chk = P.decoder_nonlinearity(bm, sz, n_gaussians=2, n_mu=48, n_phi=96)
        assert chk["max_abs_diff"] < 2e-3 * chk["mean_albedo"]


def test_spec_integral_table_matches_direct_integrals():
    from brfgs.brdf import integrals as I

    rho = np.array([0.07, 0.23, 0.55])
    got = P.spec_integrals(rho, "black", 40.0)
    ref = [I.black_sky("cook_torrance", math.radians(40.0), roughness=float(r)) for r in rho]
    np.testing.assert_allclose(got, ref, rtol=0.01)


def test_contributions_add_up_and_anix_of_a_hotspot_surface():
    bm = carpet_model(half_m=12.0, z_left=Z, z_right=Z, vol=0.3, geo=0.15, components=("iso", "vol", "geo"))
    c2w, intr = P.nadir_camera(bm, size=12, half_extent_m=5.0)
    out = P.render_products(bm, camera_from_intrinsics(c2w, intr), which=("contributions", "anix"), backend="cpu")
    np.testing.assert_allclose(out["iso"] + out["vol"] + out["geo"], out["total"], atol=1e-6)
    assert (out["anix"] > 1.05).all()


def test_products_refuse_non_kernel_models():
    from brfgs.brdf.head import HeadConfig
    from brfgs.errors import UserError

    bm = carpet_model(half_m=1.0)
    bm.head_cfg = HeadConfig(kind="sh", sh_degree=1)
    with pytest.raises(UserError, match="hybrid"):
        P.require_hybrid(bm)
