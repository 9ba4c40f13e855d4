"""Hybrid head (eq. 12), its baselines, Gaussian normals and SH."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import torch

from brfgs.brdf import kernels as K
from brfgs.brdf.geometry import gaussian_normals, quat_to_rotmat, sun_direction, view_directions
from brfgs.brdf.head import (
    COMPONENTS,
    HeadConfig,
    evaluate_head,
    head_param_shapes,
    hybrid_latent,
    init_head_params,
    raw_from_roughness,
    roughness_from_raw,
)
from brfgs.brdf.reference import hybrid_latent_ref
from brfgs.brdf.sh import eval_sh, sh_basis
from brfgs.errors import UserError


BACKENDS = ["torch", "fused"]  # pure torch ops (CUDA path) and the numba-fused CPU path


def unit(x):
    return x / x.norm(dim=-1, keepdim=True)


def hl(backend):
    return functools.partial(hybrid_latent, backend=backend)


def make_inputs(n=300, d=5, seed=0, dtype=torch.float64, max_view_deg=75.0):
    g = torch.Generator().manual_seed(seed)
    z = [torch.randn(n, d, generator=g, dtype=dtype) for _ in range(4)]
    rho = 0.05 + 0.9 * torch.rand(n, generator=g, dtype=dtype)
    tz = torch.deg2rad(torch.rand(n, generator=g, dtype=dtype) * max_view_deg)
    az = torch.rand(n, generator=g, dtype=dtype) * 2 * math.pi
    wo = torch.stack([tz.sin() * az.sin(), tz.sin() * az.cos(), tz.cos()], -1)
    wi = sun_direction(35.0, 140.0, dtype=dtype)
    nrm = unit(torch.randn(n, 3, generator=g, dtype=dtype) * 0.4 + torch.tensor([0, 0, 1.0], dtype=dtype))
    return z, rho, nrm, wi, wo


@pytest.mark.parametrize("backend", BACKENDS)
def test_hybrid_matches_naive_reference(backend):
    z, rho, nrm, wi, wo = make_inputs()
    # keep the facets seeing the sun and sensor (the naive reference has no safe branches)
    nrm = torch.where(((nrm * wo).sum(-1, keepdim=True) < 0), -nrm, nrm)
    ok = (nrm @ wi > 0.05) & ((nrm * wo).sum(-1) > 0.05)
    got = hl(backend)(*z, rho, nrm, wi, wo)
    ref = hybrid_latent_ref(*z, rho, nrm, wi, wo)
    assert ok.sum() > 150
    torch.testing.assert_close(got[ok], ref[ok], rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("backend", BACKENDS)
def test_components_are_the_published_kernels_and_can_be_switched_off(backend):
    z, rho, nrm, wi, wo = make_inputs(seed=1)
    nrm = torch.where(((nrm * wo).sum(-1, keepdim=True) < 0), -nrm, nrm)
    kr = K.ross_thick(wi, wo)
    kl = K.li_sparse_r(wi, wo)
    kc = K.cook_torrance(wi, wo, nrm, rho)
    terms = {"iso": z[0], "vol": z[1] * kr[:, None], "geo": z[2] * kl[:, None], "spec": z[3] * kc[:, None]}
    import itertools

    for r in range(1, 5):
        for comps in itertools.combinations(COMPONENTS, r):
            got = hl(backend)(*z, rho, nrm, wi, wo, components=comps)
            want = sum(terms[c] for c in comps)
            torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    # disabled components may be passed as None
    got = hl(backend)(z[0], None, z[2], None, None, None, wi, wo, components=("iso", "geo"))
    torch.testing.assert_close(got, terms["iso"] + terms["geo"])


@pytest.mark.parametrize("backend", BACKENDS)
def test_normal_frame_uses_the_gaussian_normal_as_vertical(backend):
    z, rho, nrm, wi, wo = make_inputs(seed=2)
    nrm = torch.where(((nrm * wo).sum(-1, keepdim=True) < 0), -nrm, nrm)
    got = hl(backend)(*z, rho, nrm, wi, wo, components=("vol", "geo"), normal_frame=True)
    want = z[1] * K.ross_thick(wi, wo, nrm)[:, None] + z[2] * K.li_sparse_r(wi, wo, nrm)[:, None]
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    flat = hl(backend)(*z, rho, nrm, wi, wo, components=("vol", "geo"))
    assert not torch.allclose(got, flat)
    # a horizontal normal gives back the vertical-frame kernels
    up = torch.zeros_like(nrm)
    up[:, 2] = 1
    torch.testing.assert_close(
        hl(backend)(*z, rho, up, wi, wo, normal_frame=True), hl(backend)(*z, rho, up, wi, wo)
    )


@pytest.mark.parametrize("backend", BACKENDS)
def test_normals_are_flipped_toward_the_view_inside_the_head(backend):
    z, rho, nrm, wi, wo = make_inputs(seed=3)
    a = hl(backend)(*z, rho, nrm, wi, wo, normal_frame=True)
    b = hl(backend)(*z, rho, -nrm, wi, wo, normal_frame=True)
    torch.testing.assert_close(a, b)


@pytest.mark.parametrize("backend", BACKENDS)
def test_per_gaussian_sun_equals_broadcast_sun(backend):
    z, rho, nrm, wi, wo = make_inputs(seed=4)
    a = hl(backend)(*z, rho, nrm, wi, wo)
    b = hl(backend)(*z, rho, nrm, wi.expand(len(wo), 3).clone(), wo)
    torch.testing.assert_close(a, b)


@pytest.mark.parametrize("backend", BACKENDS)
def test_float32_head_close_to_float64(backend):
    z, rho, nrm, wi, wo = make_inputs(seed=5)
    a64 = hl(backend)(*z, rho, nrm, wi, wo)
    a32 = hl(backend)(*(t.float() for t in z), rho.float(), nrm.float(), wi.float(), wo.float())
    assert a32.dtype == torch.float32
    torch.testing.assert_close(a32.double(), a64, rtol=1e-4, atol=1e-4 * a64.abs().max().item())


def _edge_batch(dtype=torch.float64):
    """Directions at nadir, hotspot, mirror, 89° and back-facing normals."""
    d = lambda zen, az: torch.tensor(  # noqa: E731
        [math.sin(math.radians(zen)) * math.sin(math.radians(az)),
         math.sin(math.radians(zen)) * math.cos(math.radians(az)), math.cos(math.radians(zen))], dtype=dtype)
    # (θ_i = θ_v = 30°, φ = 180° would sit exactly on Li's C¹ "crowns stop overlapping" kink,
    # cos t = 2 sin θ = 1, where central differences are off by ~sqrt(eps); 35° avoids it.)
    sun = d(35.0, 0.0)
    wo = torch.stack([d(0, 0), d(35, 0), d(35, 180), d(89, 90), d(89, 0), d(60, 270), d(45, 200), d(10, 10)])
    nrm = torch.stack([d(0, 0), d(0, 0), d(0, 0), d(0, 0), d(30, 0), d(120, 30), d(100, 180), d(70, 10)])
    return sun, wo, nrm


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("normal_frame", [False, True])
def test_head_gradcheck_float64_including_edges(normal_frame, backend):
    sun, wo_e, nrm_e = _edge_batch()
    z, rho, nrm, wi, wo = make_inputs(n=10, d=2, seed=6)
    wo = torch.cat([wo_e, wo])
    nrm = torch.cat([nrm_e, nrm])
    n = len(wo)
    g = torch.Generator().manual_seed(61)
    z = [torch.cat([torch.randn(n - 10, 2, dtype=torch.float64, generator=g), t]) for t in z]
    rho = torch.cat([torch.full((n - 10,), 0.3, dtype=torch.float64), rho])
    raw = raw_from_roughness(rho).double()
    inputs = [t.clone().requires_grad_(True) for t in (*z, raw, nrm, sun, wo)]

    def f(zi, zv, zg, zs, r, nn, si, so):
        return hl(backend)(zi, zv, zg, zs, roughness_from_raw(r), unit(nn), unit(si), unit(so),
                             normal_frame=normal_frame)

    out = f(*inputs)
    assert torch.isfinite(out).all()
    out.sum().backward()
    assert all(torch.isfinite(t.grad).all() for t in inputs)
    assert torch.autograd.gradcheck(f, tuple(t.detach().clone().requires_grad_(True) for t in inputs))


@pytest.mark.parametrize("backend", BACKENDS)
def test_head_finite_for_random_and_degenerate_directions(backend):
    g = torch.Generator().manual_seed(7)
    n = 4000
    for dtype in (torch.float32, torch.float64):
        wo = unit(torch.randn(n, 3, generator=g, dtype=dtype))  # half of them below the horizon
        nrm = unit(torch.randn(n, 3, generator=g, dtype=dtype))
        wi = unit(torch.randn(n, 3, generator=g, dtype=dtype))
        wi[:10] = wo[:10]  # hotspot
        wi[10:20] = -wo[10:20]  # opposite
        nrm[20:30] = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)
        wo[20:30] = torch.tensor([1.0, 0.0, 0.0], dtype=dtype)  # exactly in the facet plane
        z = [torch.randn(n, 4, generator=g, dtype=dtype).requires_grad_(True) for _ in range(4)]
        rho = torch.full((n,), 0.02, dtype=dtype, requires_grad=True)
        for nf in (False, True):
            wo_ = wo.clone().requires_grad_(True)
            nrm_ = nrm.clone().requires_grad_(True)
            out = hl(backend)(*z, rho, nrm_, wi, wo_, normal_frame=nf)
            assert torch.isfinite(out).all()
            out.square().mean().backward()
            for t in (*z, rho, wo_, nrm_):
                assert torch.isfinite(t.grad).all()


# ----------------------------------------------------------------------------------------
# HeadConfig / params / evaluate_head
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "cfg",
    [
        HeadConfig(),
        HeadConfig(components=("iso", "vol", "geo")),
        HeadConfig(components=("vol", "geo", "spec")),
        HeadConfig(normal_frame=True),
        HeadConfig(kind="sh", sh_degree=0),
        HeadConfig(kind="sh", sh_degree=3),
        HeadConfig(kind="color"),
    ],
)
def test_evaluate_head_all_kinds(cfg):
    n, d = 50, 6
    z, rho, nrm, wi, wo = make_inputs(n=n, d=d, seed=8, dtype=torch.float32)
    z0 = torch.randn(n, d, generator=torch.Generator().manual_seed(19))
    params = init_head_params(cfg, n, d, z_init=z0)
    shapes = head_param_shapes(cfg, n, d)
    assert {k: tuple(v.shape) for k, v in params.items()} == shapes
    assert all(v.shape[0] == n for v in params.values())
    out = evaluate_head(cfg, params, nrm, wi, wo)
    assert out.shape == (n, d) and out.dtype == torch.float32
    # a fresh head is view independent and reproduces z_init when it has a Lambertian term
    if cfg.kind != "hybrid" or "iso" in cfg.components:
        torch.testing.assert_close(out, z0)
    else:
        assert torch.count_nonzero(out) == 0
    # gradients reach every parameter once the view-dependent terms are non-zero
    leaves = {k: torch.nn.Parameter(v + 0.1) for k, v in params.items()}
    evaluate_head(cfg, leaves, nrm, wi, wo).square().sum().backward()
    for k, v in leaves.items():
        assert v.grad is not None and torch.isfinite(v.grad).all(), k
        if cfg.kind != "sh" or k != "sh":
            assert v.grad.abs().sum() > 0, k
    # to_dict / from_dict round trip (what a checkpoint stores)
    assert HeadConfig.from_dict(cfg.to_dict()) == cfg


def test_evaluate_head_hybrid_uses_sigmoid_roughness():
    cfg = HeadConfig(components=("spec",), rho_min=0.05)
    n, d = 40, 3
    z, rho, nrm, wi, wo = make_inputs(n=n, d=d, seed=9, dtype=torch.float64)
    params = {"z_spec": z[3], "rho_raw": torch.linspace(-6, 6, n, dtype=torch.float64)}
    rho_mapped = roughness_from_raw(params["rho_raw"], 0.05)
    assert float(rho_mapped.min()) > 0.05 and float(rho_mapped.max()) < 1.0
    want = hybrid_latent(None, None, None, z[3], rho_mapped, nrm, wi, wo, components=("spec",))
    torch.testing.assert_close(evaluate_head(cfg, params, nrm, wi, wo), want)
    torch.testing.assert_close(raw_from_roughness(rho_mapped, 0.05).double(), params["rho_raw"], atol=1e-6, rtol=1e-6)


def test_head_config_rejects_bad_options():
    for kw in (dict(kind="mlp"), dict(components=("iso", "glint")), dict(components=("iso", "iso")),
               dict(sh_degree=4), dict(rho_min=0.0), dict(rho_init=1.5), dict(kind="hybrid", components=())):
        with pytest.raises(UserError):
            HeadConfig(**kw)


def test_sh_head_matches_eval_sh():
    cfg = HeadConfig(kind="sh", sh_degree=2)
    n, d = 30, 4
    z, rho, nrm, wi, wo = make_inputs(n=n, d=d, seed=10, dtype=torch.float64)
    params = {"sh": torch.randn(n, 9, d, dtype=torch.float64, generator=torch.Generator().manual_seed(20))}
    out = evaluate_head(cfg, params, None, wi, wo)
    want = torch.einsum("nk,nkd->nd", sh_basis(2, wo), params["sh"])
    torch.testing.assert_close(out, want)


# ----------------------------------------------------------------------------------------
# Spherical harmonics
# ----------------------------------------------------------------------------------------
def test_sh_basis_is_orthonormal_on_the_sphere():
    mu, w_mu = np.polynomial.legendre.leggauss(24)
    phi = np.arange(48) * 2 * np.pi / 48
    m, p = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(1 - m**2)
    dirs = torch.tensor(np.stack([st * np.sin(p), st * np.cos(p), m], -1).reshape(-1, 3))
    w = torch.tensor((w_mu[:, None] * np.full_like(p, 2 * np.pi / 48)).reshape(-1))
    y = sh_basis(3, dirs)  # [M, 16]
    gram = (y * w[:, None]).T @ y
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=1e-12, rtol=0)
    # parity: Y_lm(−d) = (−1)^l Y_lm(d)
    sign = torch.tensor([1.0] + [-1.0] * 3 + [1.0] * 5 + [-1.0] * 7, dtype=torch.float64)
    torch.testing.assert_close(sh_basis(3, -dirs), y * sign)


def test_eval_sh_degrees_and_gradcheck():
    g = torch.Generator().manual_seed(11)
    dirs = unit(torch.randn(20, 3, generator=g, dtype=torch.float64))
    for deg in range(4):
        c = torch.randn(20, (deg + 1) ** 2, 3, generator=g, dtype=torch.float64, requires_grad=True)
        out = eval_sh(deg, c, dirs)
        torch.testing.assert_close(out, torch.einsum("nk,nkd->nd", sh_basis(deg, dirs), c))
        dd = dirs.clone().requires_grad_(True)
        assert torch.autograd.gradcheck(lambda cc, ddd: eval_sh(deg, cc, ddd), (c, dd))


# ----------------------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------------------
def test_quat_to_rotmat_matches_scipy():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(12)
    q = rng.normal(size=(200, 4))  # w x y z, not normalised
    want = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    torch.testing.assert_close(quat_to_rotmat(torch.tensor(q)), torch.tensor(want), atol=1e-12, rtol=0)


def test_gaussian_normals_smallest_axis_facing_view():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(13)
    n = 500
    q = rng.normal(size=(n, 4))
    scales = rng.uniform(0.01, 1.0, size=(n, 3))
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    axis = rot[np.arange(n), :, np.argmin(scales, axis=1)]
    want = axis * np.where(np.sum(axis * wo, 1) < 0, -1, 1)[:, None]
    got = gaussian_normals(torch.tensor(q), torch.tensor(scales), torch.tensor(wo))
    torch.testing.assert_close(got, torch.tensor(want), atol=1e-12, rtol=0)
    assert ((got * torch.tensor(wo)).sum(-1) >= 0).all()
    # log-scales give the same axis
    torch.testing.assert_close(gaussian_normals(torch.tensor(q), torch.tensor(np.log(scales)), torch.tensor(wo)), got)
    # gradients reach the quaternions
    qt = torch.tensor(q[:10], requires_grad=True)
    wo_t = torch.tensor(wo[:10])
    assert torch.autograd.gradcheck(lambda qq: gaussian_normals(qq, torch.tensor(scales[:10]), wo_t), (qt,))


def test_view_directions_point_to_camera():
    means = torch.tensor([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    cam = torch.tensor([0.0, 0.0, 10.0])
    wo = view_directions(means, cam)
    torch.testing.assert_close(wo[0], torch.tensor([0.0, 0.0, 1.0]))
    torch.testing.assert_close(wo[1], unit(torch.tensor([-1.0, -2.0, 7.0])))
    s = sun_direction(30.0, 90.0, dtype=torch.float64)  # sun in the east
    torch.testing.assert_close(s, torch.tensor([0.5, 0.0, math.sqrt(3) / 2], dtype=torch.float64))


# ----------------------------------------------------------------------------------------
# Fused CPU path against the torch path (values and every gradient)
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("normal_frame", [False, True])
@pytest.mark.parametrize("components", [COMPONENTS, ("vol",), ("geo",), ("spec",), ("iso", "geo", "spec")])
def test_fused_equals_torch_values_and_gradients(dtype, normal_frame, components):
    g = torch.Generator().manual_seed(17)
    n, d = 400, 3
    sun, wo_e, nrm_e = _edge_batch(dtype)
    wo = torch.cat([wo_e, unit(torch.randn(n, 3, generator=g, dtype=dtype) + torch.tensor([0, 0, 0.8], dtype=dtype))])
    nrm = torch.cat([nrm_e, unit(torch.randn(n, 3, generator=g, dtype=dtype))])
    wi = torch.cat([sun.expand(len(wo_e), 3),
                    unit(torch.randn(n, 3, generator=g, dtype=dtype) + torch.tensor([0, 0, 1.0], dtype=dtype))])
    wi[1] = wo[1]  # hotspot
    n = len(wo)
    z = [torch.randn(n, d, generator=g, dtype=dtype) for _ in range(4)]
    rho = 0.02 + 0.98 * torch.rand(n, generator=g, dtype=dtype)
    proj = torch.randn(n, d, generator=g, dtype=dtype)
    for sun_per_gaussian in (False, True):
        wi_ = wi if sun_per_gaussian else sun
        res = {}
        for be in ("torch", "fused"):
            ins = [t.clone().requires_grad_(True) for t in (*z, rho, nrm, wi_, wo)]
            out = hybrid_latent(*ins[:4], ins[4], ins[5], ins[6], ins[7], components, normal_frame, backend=be)
            (out * proj).sum().backward()
            res[be] = [out.detach()] + [t.grad if t.grad is not None else torch.zeros_like(t) for t in ins]
        tol = dict(rtol=1e-9, atol=1e-9) if dtype == torch.float64 else dict(rtol=2e-3, atol=2e-3)
        for name, a, b in zip(["out", "z_iso", "z_vol", "z_geo", "z_spec", "rho", "normals", "omega_i", "omega_o"],
                              res["torch"], res["fused"]):
            scale = max(1.0, float(a.abs().max()))
            torch.testing.assert_close(b / scale, a / scale, **tol, msg=lambda m: f"{name}: {m}")


def test_fused_is_the_default_on_cpu_and_torch_backend_supports_double_backward():
    z, rho, nrm, wi, wo = make_inputs(n=20, d=2, seed=18)
    from brfgs.brdf import fused

    assert fused.available()
    wo_ = wo.clone().requires_grad_(True)
    out = hybrid_latent(*z, rho, nrm, wi, wo_, backend="torch")
    (g,) = torch.autograd.grad(out.sum(), wo_, create_graph=True)
    assert g.requires_grad
    torch.autograd.grad(g.sum(), wo_)  # second order through the torch path works
    # the fused path is first-order only and says so instead of returning wrong 2nd derivatives
    wo2 = wo.clone().requires_grad_(True)
    out = hybrid_latent(*z, rho, nrm, wi, wo2, backend="fused")
    (g2,) = torch.autograd.grad(out.sum(), wo2, create_graph=True)
    torch.testing.assert_close(g2.detach(), g.detach())
    with pytest.raises(RuntimeError):
        torch.autograd.grad(g2.sum(), wo2)
    with pytest.raises(ValueError):
        hybrid_latent(*z, rho, nrm, wi, wo, backend="cuda-please")
