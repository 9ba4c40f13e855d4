"""Kernels of brfgs.brdf against an independent float64 numpy version and published facts."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from brfgs.brdf import kernels as K


# ----------------------------------------------------------------------------------------
# Independent numpy reference, written from Lucht, Schaaf & Strahler (2000),
# IEEE TGRS 38(2), eqs 38–44, and Walter et al. (2007) / Schlick (1994) for the specular.
# ----------------------------------------------------------------------------------------
def np_ross_thick(ti, tv, phi):
    """Lucht eq. 38: K_vol = ((π/2 − ξ) cos ξ + sin ξ)/(cos θi + cos θv) − π/4, ξ from eq. 43."""
    cos_xi = np.cos(ti) * np.cos(tv) + np.sin(ti) * np.sin(tv) * np.cos(phi)
    xi = np.arccos(np.clip(cos_xi, -1.0, 1.0))
    return ((np.pi / 2 - xi) * np.cos(xi) + np.sin(xi)) / (np.cos(ti) + np.cos(tv)) - np.pi / 4


def np_li_sparse_r(ti, tv, phi, hb=2.0, br=1.0):
    """Lucht eqs 39–44 on primed angles θ' = atan((b/r) tan θ)."""
    tip = np.arctan(br * np.tan(ti))  # eq. 44
    tvp = np.arctan(br * np.tan(tv))
    cos_xip = np.cos(tip) * np.cos(tvp) + np.sin(tip) * np.sin(tvp) * np.cos(phi)  # eq. 43
    d2 = np.tan(tip) ** 2 + np.tan(tvp) ** 2 - 2 * np.tan(tip) * np.tan(tvp) * np.cos(phi)  # eq. 42
    d = np.sqrt(np.maximum(d2, 0.0))
    sec_i, sec_v = 1 / np.cos(tip), 1 / np.cos(tvp)
    cos_t = hb * np.sqrt(d**2 + (np.tan(tip) * np.tan(tvp) * np.sin(phi)) ** 2) / (sec_i + sec_v)  # eq. 41
    t = np.arccos(np.clip(cos_t, -1.0, 1.0))
    o = (t - np.sin(t) * np.cos(t)) * (sec_i + sec_v) / np.pi  # eq. 40
    return o - sec_i - sec_v + 0.5 * (1 + cos_xip) * sec_i * sec_v  # eq. 39


def np_dir(theta, az):
    return np.stack([np.sin(theta) * np.sin(az), np.sin(theta) * np.cos(az), np.cos(theta)], -1)


def np_cook(wi, wo, n, rho, f0=0.04):
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    nh = np.sum(n * h, -1)
    d = rho**2 / (np.pi * (nh**2 * (rho**2 - 1) + 1) ** 2)
    f = f0 + (1 - f0) * (1 - np.sum(h * wo, -1)) ** 5
    return d * f / (4 * np.sum(n * wo, -1) * np.sum(n * wi, -1))


def random_triples(n, seed, max_zen_deg=89.0):
    rng = np.random.default_rng(seed)
    ti = np.deg2rad(rng.uniform(0, max_zen_deg, n))
    tv = np.deg2rad(rng.uniform(0, max_zen_deg, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    return ti, tv, phi


def t64(a):
    return torch.as_tensor(a, dtype=torch.float64)


# ----------------------------------------------------------------------------------------
# Agreement with the independent reference
# ----------------------------------------------------------------------------------------
def test_ross_thick_matches_lucht_float64():
    ti, tv, phi = random_triples(5000, 1)
    got = K.ross_thick_angles(t64(ti), t64(tv), t64(phi)).numpy()
    np.testing.assert_allclose(got, np_ross_thick(ti, tv, phi), rtol=1e-6, atol=1e-12)


def test_li_sparse_r_matches_lucht_float64():
    ti, tv, phi = random_triples(5000, 2)
    got = K.li_sparse_r_angles(t64(ti), t64(tv), t64(phi)).numpy()
    np.testing.assert_allclose(got, np_li_sparse_r(ti, tv, phi), rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("hb,br", [(2.0, 1.0), (1.5, 2.5), (2.5, 0.75)])
def test_li_sparse_general_crown_shape_matches_lucht(hb, br):
    ti, tv, phi = random_triples(3000, 3, max_zen_deg=85.0)
    got = K.li_sparse_r_angles(t64(ti), t64(tv), t64(phi), hb=hb, br=br).numpy()
    np.testing.assert_allclose(got, np_li_sparse_r(ti, tv, phi, hb, br), rtol=1e-6, atol=1e-12)


def test_cook_torrance_matches_reference_float64():
    rng = np.random.default_rng(4)
    n = 4000
    wi = np_dir(np.deg2rad(rng.uniform(0, 80, n)), rng.uniform(0, 2 * np.pi, n))
    wo = np_dir(np.deg2rad(rng.uniform(0, 80, n)), rng.uniform(0, 2 * np.pi, n))
    # tilted normals that see both directions
    nrm = wi + wo + np_dir(np.deg2rad(rng.uniform(0, 30, n)), rng.uniform(0, 2 * np.pi, n))
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    ok = (np.sum(nrm * wi, -1) > 0.05) & (np.sum(nrm * wo, -1) > 0.05)
    wi, wo, nrm = wi[ok], wo[ok], nrm[ok]
    rho = rng.uniform(0.05, 1.0, len(wi))
    got = K.cook_torrance(t64(wi), t64(wo), t64(nrm), t64(rho)).numpy()
    np.testing.assert_allclose(got, np_cook(wi, wo, nrm, rho), rtol=1e-6, atol=1e-12)
    assert len(wi) > 1000


def test_vector_and_angle_api_agree_with_arbitrary_sun_azimuth():
    """Kernels depend on the relative azimuth only: rotate both directions about +z."""
    ti, tv, phi = random_triples(500, 5, 80.0)
    sun_az = np.random.default_rng(6).uniform(0, 2 * np.pi, 500)
    wi = t64(np_dir(ti, sun_az))
    wo = t64(np_dir(tv, sun_az + phi))
    np.testing.assert_allclose(K.ross_thick(wi, wo).numpy(), np_ross_thick(ti, tv, phi), rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(K.li_sparse_r(wi, wo).numpy(), np_li_sparse_r(ti, tv, phi), rtol=1e-6, atol=1e-12)


def test_normal_frame_equals_rotated_vertical_frame():
    """Ross/Li with up = n equal the vertical-frame kernels of the rotated directions."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    rot = Rotation.random(300, random_state=8)
    ti, tv, phi = random_triples(300, 9, 80.0)
    az = rng.uniform(0, 2 * np.pi, 300)
    wi_l, wo_l = np_dir(ti, az), np_dir(tv, az + phi)  # local frame, up = z
    wi = rot.apply(wi_l)
    wo = rot.apply(wo_l)
    up = rot.apply(np.tile([0.0, 0.0, 1.0], (300, 1)))
    np.testing.assert_allclose(
        K.ross_thick(t64(wi), t64(wo), t64(up)).numpy(), np_ross_thick(ti, tv, phi), rtol=1e-6, atol=1e-10
    )
    np.testing.assert_allclose(
        K.li_sparse_r(t64(wi), t64(wo), t64(up)).numpy(), np_li_sparse_r(ti, tv, phi), rtol=1e-6, atol=1e-10
    )


def test_float32_close_to_float64():
    ti, tv, phi = random_triples(2000, 10, 75.0)
    for fn in (K.ross_thick_angles, K.li_sparse_r_angles):
        a32 = fn(torch.tensor(ti, dtype=torch.float32), torch.tensor(tv, dtype=torch.float32),
                 torch.tensor(phi, dtype=torch.float32))
        a64 = fn(t64(ti), t64(tv), t64(phi))
        assert a32.dtype == torch.float32
        np.testing.assert_allclose(a32.double().numpy(), a64.numpy(), atol=2e-4 * np.abs(a64.numpy()).max())


# ----------------------------------------------------------------------------------------
# Published facts and limit cases
# ----------------------------------------------------------------------------------------
def test_kernels_zero_at_nadir():
    z = t64(0.0)
    assert abs(float(K.ross_thick_angles(z, z, z))) < 1e-15
    assert abs(float(K.li_sparse_r_angles(z, z, z))) < 1e-15
    z32 = torch.tensor(0.0)
    assert abs(float(K.ross_thick_angles(z32, z32, z32))) < 1e-6
    assert abs(float(K.li_sparse_r_angles(z32, z32, z32))) < 1e-6


def test_reciprocity():
    ti, tv, phi = random_triples(3000, 11)
    for fn in (K.ross_thick_angles, K.li_sparse_r_angles):
        a = fn(t64(ti), t64(tv), t64(phi)).numpy()
        b = fn(t64(tv), t64(ti), t64(phi)).numpy()
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)
    # Cook–Torrance is reciprocal too up to the Fresnel factor (h·ω_o = h·ω_i): exact
    rough = t64(np.random.default_rng(12).uniform(0.05, 1, 3000))
    ti, tv, phi = random_triples(3000, 13, 80.0)
    a = K.cook_torrance_angles(t64(ti), t64(tv), t64(phi), rough).numpy()
    b = K.cook_torrance_angles(t64(tv), t64(ti), t64(phi), rough).numpy()
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("sun_zenith_deg", [15.0, 30.0, 45.0])
def test_li_sparse_r_max_at_hotspot_on_principal_plane(sun_zenith_deg):
    """Over the usual view range (|θ_v| ≤ 60°) the hotspot is the maximum of K_Li.

    (At extreme zeniths the reciprocal term sec θ_i sec θ_v makes K_Li grow again, e.g.
    θ_s = 60°, θ_v = 85° backscatter; that is the published kernel, see the numpy reference.)
    """
    ts = math.radians(sun_zenith_deg)
    # signed view zenith on the principal plane: + backscatter (φ = 0), − forward (φ = 180°)
    signed = np.linspace(-60, 60, 2401)  # 0.05° steps, contains ±sun_zenith exactly
    tv = np.deg2rad(np.abs(signed))
    phi = np.where(signed >= 0, 0.0, np.pi)
    k = K.li_sparse_r_angles(t64(ts), t64(tv), t64(phi)).numpy()
    assert signed[np.argmax(k)] == pytest.approx(sun_zenith_deg, abs=1e-9)
    np.testing.assert_allclose(k, np_li_sparse_r(ts, tv, phi), rtol=1e-6, atol=1e-12)
    # and over the hemisphere up to 60°, nothing exceeds the hotspot value
    tv2, phi2 = np.meshgrid(np.deg2rad(np.linspace(0, 60, 121)), np.deg2rad(np.arange(0, 360, 2.0)))
    k2 = K.li_sparse_r_angles(t64(ts), t64(tv2), t64(phi2)).numpy()
    k_hot = float(K.li_sparse_r_angles(t64(ts), t64(ts), t64(0.0)))
    assert k2.max() <= k_hot + 1e-12


@pytest.mark.parametrize("sun_zenith_deg", [10.0, 30.0, 45.0])
def test_li_sparse_r_hotspot_is_a_cusp_maximum(sun_zenith_deg):
    """The hotspot is a strict local maximum (a cusp) in every direction around it
    (for sun zeniths up to ~50°; beyond, K_Li keeps rising along the backscatter plane)."""
    ts = math.radians(sun_zenith_deg)
    k_hot = float(K.li_sparse_r_angles(t64(ts), t64(ts), t64(0.0)))
    step = math.radians(0.2)
    ang = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    # points on a small ring around the hotspot direction
    wi = np_dir(np.array(ts), np.array(0.0))
    e1 = np.array([0.0, math.cos(ts), -math.sin(ts)])  # along the principal plane
    e2 = np.array([1.0, 0.0, 0.0])
    ring = wi[None] * math.cos(step) + math.sin(step) * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)
    k = K.li_sparse_r(t64(wi), t64(ring)).numpy()
    assert (k < k_hot).all()


@pytest.mark.parametrize("rough", [0.1, 0.3, 0.6])
@pytest.mark.parametrize("sun_zenith_deg", [0.0, 20.0, 40.0])
def test_ggx_lobe_peaks_at_mirror_direction(rough, sun_zenith_deg):
    ts = math.radians(sun_zenith_deg)
    tv, phi = np.meshgrid(np.deg2rad(np.linspace(0, 85, 341)), np.deg2rad(np.arange(0, 360, 1.0)))
    # F0 = 1 so that F ≡ 1 and the lobe is pure D / (4 μi μo): peak exactly at the mirror
    k = K.cook_torrance_angles(t64(ts), t64(tv), t64(phi), rough, f0=1.0).numpy()
    i = np.unravel_index(np.argmax(k * np.cos(tv)), k.shape)  # the cosine-weighted lobe peaks at mirror
    assert math.degrees(tv[i]) == pytest.approx(sun_zenith_deg, abs=0.3)
    if sun_zenith_deg > 0:
        assert math.degrees(phi[i]) == pytest.approx(180.0, abs=1e-9)
    # the D term alone is maximal exactly at the mirror direction: n·h = 1 there
    k_mirror = float(K.cook_torrance_angles(t64(ts), t64(ts), t64(math.pi), rough, f0=1.0))
    d_max = 1.0 / (math.pi * rough**2)
    assert k_mirror == pytest.approx(d_max / (4 * math.cos(ts) ** 2), rel=1e-12)


@pytest.mark.parametrize("rough", [0.1, 0.4, 1.0])
@pytest.mark.parametrize("sun_zenith_deg", [0.0, 40.0])
def test_ggx_cosine_weighted_integral_at_most_one(rough, sun_zenith_deg):
    """∫ K_Cook(F=1) cos θ_o dω_o ≤ 1 (energy; without masking G it is exactly the
    projected-D integral over the visible half-vectors)."""
    ts = math.radians(sun_zenith_deg)
    mu, wmu = np.polynomial.legendre.leggauss(400)
    mu, wmu = 0.5 * (mu + 1), 0.5 * wmu
    ph, wph = np.polynomial.legendre.leggauss(400)
    ph, wph = np.pi * (ph + 1), np.pi * wph
    # min_cos tiny: no grazing ramp, the exact eq. 20 over the whole hemisphere
    k = K.cook_torrance_angles(t64(ts), t64(np.arccos(mu))[:, None], t64(ph)[None, :], rough, f0=1.0,
                               min_cos=1e-12).numpy()
    total = float(np.sum(k * mu[:, None] * wmu[:, None] * wph[None, :]))
    assert 0.3 < total <= 1.0 + 1e-6
    if sun_zenith_deg == 0.0:
        # at normal incidence it is ∫_{θh<45°} D cos θh dω_h; GGX: the projected-D mass
        # inside θh is u with tan²θh = ρ² u/(1 − u); θh = 45° ⇒ u = 1/(1 + ρ²)
        assert total == pytest.approx(1.0 / (1.0 + rough**2), rel=1e-3)


# ----------------------------------------------------------------------------------------
# Finiteness and gradients at the edge angles
# ----------------------------------------------------------------------------------------
EDGE_DEG = [
    (0.0, 0.0, 0.0),  # sun and view at nadir
    (0.0, 30.0, 90.0),  # sun at nadir
    (30.0, 0.0, 45.0),  # view at nadir
    (89.0, 60.0, 0.0),  # grazing sun
    (40.0, 89.0, 180.0),  # grazing view, forward
    (89.0, 89.0, 0.0),  # both grazing at the hotspot
    (89.0, 89.0, 180.0),  # both grazing, specular
    (35.0, 35.0, 0.0),  # hotspot θi = θv, φ = 0
    (35.0, 35.0, 180.0),  # mirror θi = θv, φ = 180°
    (25.0, 50.0, 0.0),  # principal plane backscatter
    (25.0, 50.0, 180.0),  # principal plane forward
    (50.0, 50.0, 90.0),  # θi = θv cross plane
    (60.0, 20.0, 300.0),
]


def _edge_inputs():
    a = torch.tensor(EDGE_DEG, dtype=torch.float64).deg2rad()
    return a[:, 0].clone(), a[:, 1].clone(), a[:, 2].clone()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_finite_values_and_gradients_at_edges(dtype):
    ti, tv, phi = (x.to(dtype).requires_grad_(True) for x in _edge_inputs())
    rough = torch.full_like(ti, 0.2).requires_grad_(True)
    total = 0.0
    for k in (
        K.ross_thick_angles(ti, tv, phi),
        K.li_sparse_r_angles(ti, tv, phi),
        K.cook_torrance_angles(ti, tv, phi, rough),
    ):
        assert torch.isfinite(k).all()
        total = total + k.sum()
    total.backward()
    for x in (ti, tv, phi, rough):
        assert torch.isfinite(x.grad).all()


def test_back_facing_and_below_horizon_are_finite():
    rng = np.random.default_rng(14)
    wi = torch.tensor(rng.normal(size=(2000, 3)))
    wo = torch.tensor(rng.normal(size=(2000, 3)))
    n = torch.tensor(rng.normal(size=(2000, 3)))
    extra = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    wi = torch.cat([wi, extra, extra[[0]], extra[[1]]])
    wo = torch.cat([wo, -extra, extra[[1]], extra[[0]]])  # includes ω_i = −ω_o and horizon
    n = torch.cat([n, extra, extra[[2]], extra[[0]]])
    wi, wo, n = (x / x.norm(dim=-1, keepdim=True) for x in (wi, wo, n))
    for dtype in (torch.float32, torch.float64):
        a, b, c = (x.to(dtype).clone().requires_grad_(True) for x in (wi, wo, n))
        rough = torch.full((len(a),), 0.05, dtype=dtype, requires_grad=True)
        vals = [K.ross_thick(a, b), K.li_sparse_r(a, b), K.ross_thick(a, b, c), K.li_sparse_r(a, b, c),
                K.cook_torrance(a, b, c, rough)]
        for v in vals:
            assert torch.isfinite(v).all()
        sum(v.sum() for v in vals).backward()
        for x in (a, b, c, rough):
            assert torch.isfinite(x.grad).all()
        back = (c * a).sum(-1) <= 0
        assert (vals[-1][back.detach()] == 0).all()  # sun behind the facet: no specular


def test_gradcheck_kernels_float64_angles_including_edges():
    ti, tv, phi = _edge_inputs()
    rng = np.random.default_rng(15)
    m = 20
    ti = torch.cat([ti, t64(np.deg2rad(rng.uniform(1, 80, m)))]).requires_grad_(True)
    tv = torch.cat([tv, t64(np.deg2rad(rng.uniform(1, 80, m)))]).requires_grad_(True)
    phi = torch.cat([phi, t64(rng.uniform(0, 2 * np.pi, m))]).requires_grad_(True)
    rough = t64(rng.uniform(0.1, 0.9, len(ti))).requires_grad_(True)
    assert torch.autograd.gradcheck(K.ross_thick_angles, (ti, tv, phi))
    assert torch.autograd.gradcheck(K.li_sparse_r_angles, (ti, tv, phi))
    assert torch.autograd.gradcheck(lambda a, b, c: K.li_sparse_r_angles(a, b, c, hb=1.5, br=2.0), (ti, tv, phi))
    # Cook: avoid the grazing rows where the safe-denominator ramp has its kinks (μ = min_cos)
    keep = torch.ones(len(ti), dtype=torch.bool)
    keep[:len(EDGE_DEG)] = torch.tensor([max(a, b) < 89.0 for a, b, _ in EDGE_DEG])
    args = tuple(x.detach()[keep].clone().requires_grad_(True) for x in (ti, tv, phi, rough))
    assert torch.autograd.gradcheck(K.cook_torrance_angles, args)


def test_gradcheck_kernels_float64_vectors_and_normal_frame():
    rng = np.random.default_rng(16)
    m = 24

    def unit(x):
        return x / x.norm(dim=-1, keepdim=True)

    wi = unit(t64(rng.normal(size=(m, 3)) + [0, 0, 2.5]))
    wo = unit(t64(rng.normal(size=(m, 3)) + [0, 0, 2.5]))
    wo[0] = wi[0]  # hotspot in the vertical frame
    wi[1] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)  # nadir sun
    wo[1] = wi[1]
    up = unit(t64(rng.normal(size=(m, 3)) * 0.3 + [0, 0, 1]))
    wi.requires_grad_(True)
    wo.requires_grad_(True)
    up.requires_grad_(True)
    rough = t64(rng.uniform(0.1, 0.9, m)).requires_grad_(True)
    # wrap with normalisation so finite differences stay on the unit sphere
    assert torch.autograd.gradcheck(lambda a, b: K.ross_thick(unit(a), unit(b)), (wi, wo))
    assert torch.autograd.gradcheck(lambda a, b: K.li_sparse_r(unit(a), unit(b)), (wi, wo))
    assert torch.autograd.gradcheck(lambda a, b, n: K.ross_thick(unit(a), unit(b), unit(n)), (wi, wo, up))
    assert torch.autograd.gradcheck(lambda a, b, n: K.li_sparse_r(unit(a), unit(b), unit(n)), (wi, wo, up))
    assert torch.autograd.gradcheck(
        lambda a, b, n, r: K.cook_torrance(unit(a), unit(b), unit(n), r), (wi, wo, up, rough)
    )
