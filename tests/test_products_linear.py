"""Kernel products of a model with a linear spectral basis: each Gaussian's BRF is the kernel model with
its own per-band weights, and the MCD43 maps rendered from those weights equal the least-squares fit
over 75 directions where that fit is exact (no specular term, no background)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from brfgs.brdf.head import hybrid_kernels, roughness_from_raw
from brfgs.brdf.mcd43 import DirectionGrid
from brfgs.data.angles import direction_from_angles_deg
from brfgs.errors import UserError
from brfgs.model import camera_from_intrinsics
from brfgs.products import maps as P
from brfgs.products.mcd43_maps import render_mcd43
from brfgs.spectral.linear_basis import LinearBasis
from test_analysis_helpers import carpet_model


def linear_carpet(components=("iso", "vol", "geo"), n_bands: int = 6, d: int = 3, seed: int = 0):
    """A carpet of Gaussians (tests/test_analysis_helpers.py) with random latents z_iso, z_vol, z_geo
    (z_spec) and a random linear basis W [B, d], b [B]; no background."""
    tm = carpet_model(half_m=6.0, n_bands=d, components=components)
    g = torch.Generator().manual_seed(seed)
    n = tm.n_gaussians
    basis = LinearBasis(n_bands, d)
    with torch.no_grad():
        basis.weight.copy_(0.2 * torch.randn(n_bands, d, generator=g))
        basis.bias.copy_(0.1 + 0.05 * torch.rand(n_bands, generator=g))
    for c in components:
        scale = 1.0 if c == "iso" else 0.3
        tm.gaussians.params[f"z_{c}"] = scale * torch.randn(n, d, generator=g) + (0.5 if c == "iso" else 0.0)
    tm.decoder = basis.requires_grad_(False)
    tm.scene["wavelengths_nm"] = np.linspace(480.0, 860.0, n_bands).tolist()
    tm.meta["cir_indices"] = [n_bands - 1, n_bands // 2, 0]
    return tm


def test_each_gaussians_brf_is_the_kernel_model_with_its_own_weights():
    """decode(z_k(ω_i, ω_o)) = f_iso + f_vol K_Ross + f_geo K_Li + f_spec K_Cook, the kernels evaluated
    independently by brfgs.brdf.head.hybrid_kernels."""
    tm = linear_carpet(("iso", "vol", "geo", "spec"))
    w = P.gaussian_kernel_weights(tm)
    assert sorted(w) == ["f_geo", "f_iso", "f_spec", "f_vol"]
    rng = np.random.default_rng(0)
    n = tm.n_gaussians
    omega_o = torch.as_tensor(direction_from_angles_deg(rng.uniform(0, 60, n), rng.uniform(0, 360, n)),
                              dtype=torch.float32)
    for sun in (20.0, 50.0):
        omega_i = tm.sun_direction(sun)
        brf = torch.as_tensor(tm.decode(tm.gaussian_latent(omega_i, omega_o)))
        p = tm.head_params()
        k = hybrid_kernels(tm.head_normals(omega_o), omega_i, omega_o, roughness_from_raw(p["rho_raw"], tm.head_cfg.rho_min))
        model = w["f_iso"] + sum(k[c][:, None] * w[f"f_{c}"] for c in ("vol", "geo", "spec"))
        np.testing.assert_allclose(brf.numpy(), model.numpy(), atol=2e-6)


def test_exact_weights_equal_the_fit_where_the_fit_is_exact():
    tm = linear_carpet()
    c2w, intr = P.nadir_camera(tm, size=12, half_extent_m=4.0)
    cam = camera_from_intrinsics(c2w, intr)
    kw = dict(nbar_sun_zenith_deg=30.0, albedo_sun_zenith_deg=45.0, backend="torch")
    exact = render_mcd43(tm, cam, **kw)
    fit = render_mcd43(tm, cam, method="fit", **kw)
    assert exact["settings"]["method"] == "exact" and fit["settings"]["method"] == "fit"
    ok = exact["alpha"] >= 0.5
    assert ok.mean() > 0.9 and "f_spec" not in exact
    for name in ("f_iso", "f_vol", "f_geo", "nbar_mcd43", "bsa_mcd43", "wsa_mcd43"):
        np.testing.assert_allclose(exact[name][ok], fit[name][ok], atol=1e-4)
        assert np.isnan(exact[name][~ok]).all() and np.isnan(fit[name][~ok]).all()
    assert np.abs(exact["f_vol"][ok]).max() > 0.01 and np.abs(exact["f_geo"][ok]).max() > 0.01
    assert fit["fit_rmse"][ok].max() < 1e-4 and (exact["fit_rmse"][ok] == 0).all()
    assert exact["settings"]["design_condition_number"] == pytest.approx(fit["settings"]["design_condition_number"])


def test_with_a_specular_term_the_exact_weights_leave_the_lobe_out():
    """f_spec is W Z_spec rendered; fit_rmse the lobe's RMS over the grid; f_iso/f_vol/f_geo the
    model's own weights (the fit absorbs part of the lobe instead)."""
    tm = linear_carpet(("iso", "vol", "geo", "spec"))
    c2w, intr = P.nadir_camera(tm, size=8, half_extent_m=4.0)
    cam = camera_from_intrinsics(c2w, intr)
    grid = DirectionGrid(sun_zeniths_deg=(30.0,), view_zeniths_deg=(0.0, 30.0), rel_azimuths_deg=(0.0, 180.0))
    exact = render_mcd43(tm, cam, nbar_sun_zenith_deg=30.0, albedo_sun_zenith_deg=30.0, backend="torch", grid=grid)
    no_spec = linear_carpet(("iso", "vol", "geo"))  # the same weights (same generator draws) without the lobe
    base = render_mcd43(no_spec, cam, nbar_sun_zenith_deg=30.0, albedo_sun_zenith_deg=30.0, backend="torch")
    ok = exact["alpha"] >= 0.5
    for name in ("f_iso", "f_vol", "f_geo"):
        np.testing.assert_allclose(exact[name][ok], base[name][ok], atol=1e-6)
    assert exact["fit_rmse"][ok].min() > 0 and np.isfinite(exact["f_spec"][ok]).all()


def test_exact_weights_need_a_linear_basis():
    tm = carpet_model(half_m=3.0)
    with pytest.raises(UserError):
        P.gaussian_kernel_weights(tm)
    c2w, intr = P.nadir_camera(tm, size=4)
    with pytest.raises(ValueError):
        render_mcd43(tm, camera_from_intrinsics(c2w, intr), nbar_sun_zenith_deg=30.0, albedo_sun_zenith_deg=30.0,
                     method="exact")
