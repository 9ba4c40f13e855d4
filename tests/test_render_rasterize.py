"""Rasterizer: the fast ``cpu`` backend against the ``torch`` reference, and both against
closed-form limit cases. Relative error = max|a − b| / max|b| over a whole tensor."""

from __future__ import annotations

import math

import pytest
import torch

from brfgs.errors import UserError
from brfgs.render import rasterize
from brfgs.render.scenes import ground_scene, random_scene

PARAMS = ("means", "quats", "scales", "opacities", "features", "normals")


def rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return ((a - b).abs().max() / b.abs().max().clamp_min(1e-30)).item()


def render(sc, backend, with_normals=True, seed=0):
    """Render with random loss weights; return outputs, parameter grads and the means2d grad."""
    p = {k: sc[k].clone().requires_grad_(True) for k in PARAMS}
    out = rasterize(p["means"], p["quats"], p["scales"], p["opacities"], p["features"], sc["viewmat"], sc["K"],
                    sc["width"], sc["height"], backend=backend,
                    normals=p["normals"] if with_normals else None)
    g = torch.Generator().manual_seed(seed)  # the same weights on every device (drawn on the CPU)
    loss = (out.image * torch.randn(out.image.shape, generator=g).to(out.image)).sum()
    loss = loss + (out.alpha * torch.randn(out.alpha.shape, generator=g).to(out.alpha)).sum()
    loss = loss + (out.depth * torch.randn(out.depth.shape, generator=g).to(out.depth)).sum()
    if with_normals:
        loss = loss + (out.normal * torch.randn(out.normal.shape, generator=g).to(out.normal)).sum()
    loss.backward()
    grads = {k: p[k].grad for k in PARAMS if p[k].grad is not None}
    return out, grads, out.meta["means2d"].grad


def compare(sc, with_normals=True, tol=1e-4):
    o_ref, g_ref, m_ref = render(sc, "torch", with_normals)
    o_cpu, g_cpu, m_cpu = render(sc, "cpu", with_normals)
    assert torch.equal(o_ref.meta["visible"], o_cpu.meta["visible"])
    assert torch.equal(o_ref.meta["radii"], o_cpu.meta["radii"])
    assert o_ref.meta["visible"].any()
    planes = ["image", "alpha", "depth"] + (["normal"] if with_normals else [])
    for name in planes:
        assert rel(getattr(o_cpu, name), getattr(o_ref, name)) < tol, name
    assert set(g_ref) == set(g_cpu)
    for k in g_ref:
        assert g_ref[k].abs().max() > 0, k
        assert rel(g_cpu[k], g_ref[k]) < tol, k
    assert rel(m_cpu, m_ref) < tol
    return o_ref


@pytest.mark.parametrize("n,channels,width,height,behind,offscreen", [
    (300, 1, 40, 30, 0.1, 0.25),
    (800, 3, 64, 48, 0.2, 0.4),
    (400, 16, 33, 47, 0.0, 0.0),
    (250, 164, 24, 20, 0.1, 0.3),
])
def test_cpu_matches_torch_random_scenes(n, channels, width, height, behind, offscreen):
    sc = random_scene(n, width, height, channels, seed=n + channels, behind_fraction=behind, offscreen=offscreen)
    out = compare(sc)
    vis = out.meta["visible"]
    if behind > 0:  # Gaussians behind the near plane are culled
        z = out.meta["depths"].detach()
        assert not vis[z <= 0.01].any() and (z <= 0.01).any()


def test_cpu_matches_torch_ground_scene():
    sc = ground_scene(1500, 48, 40, 5, seed=3, px_size=1.5)
    compare(sc, with_normals=False)


def test_cpu_matches_torch_opaque_stack_termination_and_clamp():
    """Dense opaque layers: pixels hit the 0.99 clamp and the 1e-4 transmittance stop."""
    sc = random_scene(600, 20, 16, 3, seed=7, behind_fraction=0.0, offscreen=0.0, max_opacity=1.0, px_size=4.0)
    sc["opacities"] = sc["opacities"].clamp_min(0.8)
    out = compare(sc)
    assert out.alpha.max() > 1 - 2e-4  # transmittance reached the stop


def test_single_gaussian_closed_form():
    """An isotropic Gaussian on the optical axis: image = f·o·exp(−r²/2s²), s² = (f_px·σ/z)² + 0.3."""
    z, sigma_m, f_px, o = 5.0, 0.02, 100.0, 0.7
    W = H = 16
    K = torch.tensor([[f_px, 0, 8.0], [0, f_px, 8.0], [0, 0, 1.0]], dtype=torch.float64)
    for backend in ("torch", "cpu"):
        out = rasterize(torch.tensor([[0.0, 0.0, z]], dtype=torch.float64),
                        torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64),
                        torch.full((1, 3), sigma_m, dtype=torch.float64), torch.tensor([o], dtype=torch.float64),
                        torch.tensor([[2.0]], dtype=torch.float64), torch.eye(4, dtype=torch.float64), K, W, H,
                        backend=backend)
        s2 = (f_px * sigma_m / z) ** 2 + 0.3
        ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
        r2 = (xs - 8.0) ** 2 + (ys - 8.0) ** 2
        a = o * torch.exp(-0.5 * r2 / s2)
        a = torch.where(a >= 1 / 255, a, torch.zeros_like(a)).double()
        assert torch.allclose(out.image[..., 0], 2.0 * a, atol=1e-12), backend
        assert torch.allclose(out.alpha, a, atol=1e-12)
        assert torch.allclose(out.depth[a > 0], torch.full_like(out.depth[a > 0], z))
        assert out.meta["visible"].all()


def test_two_gaussians_depth_order():
    """Front-to-back order follows depth, not input order: C = α1 f1 + (1 − α1) α2 f2."""
    K = torch.tensor([[50.0, 0, 4.0], [0, 50.0, 4.0], [0, 0, 1.0]])
    means = torch.tensor([[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]])  # second is nearer
    for backend in ("torch", "cpu"):
        out = rasterize(means, torch.tensor([[1.0, 0, 0, 0]] * 2), torch.full((2, 3), 0.05),
                        torch.tensor([0.5, 0.6]), torch.tensor([[1.0, 0.0], [0.0, 1.0]]), torch.eye(4), K, 8, 8,
                        backend=backend)
        c = out.image[4, 4]
        s2n, s2f = (50 * 0.05 / 2.0) ** 2 + 0.3, (50 * 0.05 / 3.0) ** 2 + 0.3
        an, af = 0.6 * math.exp(-0.5 * 0.5 / s2n), 0.5 * math.exp(-0.5 * 0.5 / s2f)  # pixel centre 0.5 px off
        assert c[1].item() == pytest.approx(an, rel=1e-5)
        assert c[0].item() == pytest.approx((1 - an) * af, rel=1e-5)
        assert out.depth[4, 4].item() == pytest.approx((an * 2.0 + (1 - an) * af * 3.0) / (an + (1 - an) * af), rel=1e-5)


def test_torch_backend_gradcheck_float64():
    sc = random_scene(6, 10, 8, 2, seed=11, dtype=torch.float64, behind_fraction=0.0, offscreen=0.0, px_size=3.0)

    def f(means, quats, scales, opacities, features, normals):
        out = rasterize(means, quats, scales, opacities, features, sc["viewmat"], sc["K"], 10, 8,
                        backend="torch", normals=normals)
        return out.image, out.alpha, out.depth, out.normal

    inputs = tuple(sc[k].clone().requires_grad_(True) for k in PARAMS)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


def test_cpu_backward_finite_differences_float64():
    sc = random_scene(8, 12, 9, 3, seed=5, dtype=torch.float64, behind_fraction=0.0, offscreen=0.1, px_size=3.0)

    def f(means, quats, scales, opacities, features, normals):
        out = rasterize(means, quats, scales, opacities, features, sc["viewmat"], sc["K"], 12, 9,
                        backend="cpu", normals=normals)
        return out.image, out.alpha, out.depth, out.normal

    inputs = tuple(sc[k].clone().requires_grad_(True) for k in PARAMS)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


def test_cpu_is_deterministic_and_meta():
    sc = ground_scene(2000, 40, 32, 3, seed=2, px_size=1.0)
    o1, g1, m1 = render(sc, "cpu")
    o2, g2, m2 = render(sc, "cpu")
    assert torch.equal(o1.image, o2.image) and torch.equal(m1, m2)
    for k in g1:
        assert torch.equal(g1[k], g2[k])
    meta = o1.meta
    assert meta["means2d"].shape == (2000, 2) and meta["radii"].shape == (2000,)
    assert meta["visible"].dtype == torch.bool
    assert (meta["radii"][~meta["visible"]] == 0).all() and (meta["radii"][meta["visible"]] > 0).all()
    # screen-space gradient is zero exactly for invisible Gaussians
    assert (m1[~meta["visible"]] == 0).all()


def test_bad_inputs_raise_user_error():
    sc = random_scene(10, 8, 8, 3, seed=0)
    args = [sc[k] for k in ("means", "quats", "scales", "opacities", "features")]
    with pytest.raises(UserError, match="quats"):
        rasterize(args[0], args[1][:, :3], *args[2:], sc["viewmat"], sc["K"], 8, 8, backend="torch")
    with pytest.raises(UserError, match="backend"):
        rasterize(*args, sc["viewmat"], sc["K"], 8, 8, backend="metal")
    if not torch.cuda.is_available():
        with pytest.raises(UserError, match="cuda"):
            rasterize(*args, sc["viewmat"], sc["K"], 8, 8, backend="cuda")


def test_cuda_backend_matches_torch():
    from brfgs.render.cuda_backend import available

    if not available():
        pytest.skip("needs a CUDA GPU and gsplat")
    sc = random_scene(500, 48, 40, 4, seed=9, max_opacity=0.9)
    dev = torch.device("cuda")
    o_ref, g_ref, _ = render(sc, "torch")
    sc_gpu = {k: (v.to(dev) if isinstance(v, torch.Tensor) else v) for k, v in sc.items()}
    o_gpu, g_gpu, m_gpu = render(sc_gpu, "auto")
    assert o_gpu.meta["backend"] == "cuda"
    # gsplat clamps alpha at 0.999 and bins by 3σ: compare at a looser tolerance
    for name in ("image", "alpha", "depth", "normal"):
        assert rel(getattr(o_gpu, name).cpu(), getattr(o_ref, name)) < 2e-2, name
    for k in g_ref:
        assert rel(g_gpu[k].cpu(), g_ref[k]) < 5e-2, k
    assert m_gpu is not None and m_gpu.shape == (500, 2)


def test_cuda_backend_with_a_model_on_the_cpu():
    """An explicit backend="cuda" on CPU tensors (a model kept on the CPU, `brfgs train --backend
    cuda`): only the rasterization runs on the GPU; outputs, meta and gradients come back to the
    CPU and match the torch reference."""
    from brfgs.render.cuda_backend import available

    if not available():
        pytest.skip("needs a CUDA GPU and gsplat")
    sc = random_scene(500, 48, 40, 4, seed=9, max_opacity=0.9)
    o_ref, g_ref, m_ref = render(sc, "torch")
    o_cpu, g_cpu, m_cpu = render(sc, "cuda")
    assert o_cpu.meta["backend"] == "cuda"
    for name in ("image", "alpha", "depth", "normal"):
        t = getattr(o_cpu, name)
        assert t.device.type == "cpu", name
        assert rel(t, getattr(o_ref, name)) < 2e-2, name
    for k in ("radii", "visible", "means2d"):
        assert o_cpu.meta[k].device.type == "cpu", k
    assert (o_cpu.meta["visible"] == o_ref.meta["visible"]).float().mean() > 0.95
    for k in g_ref:
        assert g_cpu[k].device.type == "cpu" and rel(g_cpu[k], g_ref[k]) < 5e-2, k
    assert m_cpu is not None and m_cpu.device.type == "cpu" and rel(m_cpu, m_ref) < 5e-2


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_empty_and_all_culled(backend):
    sc = random_scene(5, 8, 6, 2, seed=1, behind_fraction=0.0)
    K, vm = sc["K"], sc["viewmat"]
    z = torch.zeros
    out = rasterize(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, 2), vm, K, 8, 6, backend=backend)
    assert out.image.shape == (6, 8, 2) and (out.image == 0).all() and (out.alpha == 0).all()
    means = sc["means"].clone().requires_grad_(True)
    behind = rasterize(means, sc["quats"], sc["scales"], sc["opacities"], sc["features"],
                       torch.diag(torch.tensor([1.0, 1.0, -1.0, 1.0], dtype=vm.dtype)) @ vm, K, 8, 6, backend=backend)
    assert not behind.meta["visible"].any() and (behind.image == 0).all()
    behind.image.sum().backward()
    assert (means.grad == 0).all()


def test_bench_cli_writes_json(tmp_path):
    import json

    from brfgs.cli import main

    path = tmp_path / "bench.json"
    rc = main(["bench", "render", "--sizes", "32", "--gaussians", "300", "--channels", "3", "--repeats", "1",
               "--json", str(path)])
    assert rc == 0
    rows = json.loads(path.read_text())["rows"]
    assert {(r["backend"], r["pass"]) for r in rows} == {(b, p) for b in ("torch", "cpu")
                                                         for p in ("forward", "forward+backward")}
    for r in rows:
        assert {"backend", "width", "height", "n_gaussians", "channels", "pass", "ms_median",
                "ratio_vs_torch"} <= set(r)
        assert r["ms_median"] > 0 and r["ratio_vs_torch"] > 0 and r["n_gaussians"] == 300
    assert main(["bench", "render", "--sizes", "x"]) == 2


def test_configure_threads_sets_both_pools():
    import numba

    from brfgs.render import configure_threads

    before_torch, before_numba = torch.get_num_threads(), numba.get_num_threads()
    try:
        assert configure_threads(1) == 1
        assert torch.get_num_threads() == 1 and numba.get_num_threads() == 1
    finally:
        torch.set_num_threads(before_torch)
        numba.set_num_threads(before_numba)
