"""AbsGS's screen-space gradient (``rasterize(..., absgrad=True)``, then ``meta["means2d"].absgrad``;
used by ``--densify-absgrad``): each pixel's gradient of the projected means taken apart and summed
in absolute value. Checked against a brute-force reference (one backward pass per pixel, float64)
on both CPU backends, float32 against float64; the ordinary gradients do not change when it is asked
for; the densification statistics use it when told."""

from __future__ import annotations

from dataclasses import replace

import pytest

import torch

from brfgs.model.densify import DensifyState, accumulate
from brfgs.render import cpu_backend, rasterize, torch_backend
from brfgs.render._common import FAR_PLANE, NEAR_PLANE
from brfgs.render.scenes import random_scene

W, H = 20, 18


def _scene(seed=5, n=40):
    sc = random_scene(n, W, H, 3, seed=seed, behind_fraction=0.0, offscreen=0.1)
    return {k: (v.double() if torch.is_tensor(v) and v.is_floating_point() else v) for k, v in sc.items()}


def _weights(shape, seed):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(shape, generator=g, dtype=torch.float64)


def _reference_absgrad(sc, w_img, w_alpha) -> torch.Tensor:  # [N, 2]
    """Σ_p |∂L_p/∂means2d| with L_p = w_img[p]·image[p] + w_alpha[p]·alpha[p], one autograd pass per
    pixel through the torch backend (independent of the hooks and of the numba kernel)."""
    proj = torch_backend.project(sc["means"], sc["quats"], sc["scales"], sc["opacities"], sc["viewmat"], sc["K"],
                                 W, H, NEAR_PLANE, FAR_PLANE)
    m2d = proj.means2d.detach().requires_grad_(True)
    proj = replace(proj, means2d=m2d)
    image, alpha = torch_backend.raster(proj, sc["opacities"], sc["features"], W, H)
    acc = torch.zeros_like(m2d)
    for y in range(H):
        for x in range(W):
            lp = (image[y, x] * w_img[y, x]).sum() + alpha[y, x] * w_alpha[y, x]
            g, = torch.autograd.grad(lp, m2d, retain_graph=True, allow_unused=True)
            if g is not None:
                acc += g.abs()
    return acc


def _render(sc, backend, w_img, w_alpha, absgrad=True):
    p = {k: sc[k].clone().requires_grad_(True) for k in ("means", "quats", "scales", "opacities", "features")}
    out = rasterize(p["means"], p["quats"], p["scales"], p["opacities"], p["features"], sc["viewmat"], sc["K"], W, H,
                    backend=backend, absgrad=absgrad)
    ((out.image * w_img).sum() + (out.alpha * w_alpha).sum()).backward()
    return out.meta["means2d"], {k: v.grad for k, v in p.items()}


def test_absgrad_matches_per_pixel_reference_on_both_backends():
    sc = _scene()
    w_img, w_alpha = _weights((H, W, 3), 1), _weights((H, W), 2)
    ref = _reference_absgrad(sc, w_img, w_alpha)
    assert ref.abs().max() > 0
    for be in ("torch", "cpu"):
        m2d, _ = _render(sc, be, w_img, w_alpha)
        got = m2d.absgrad
        assert got.shape == ref.shape
        assert torch.allclose(got, ref, rtol=1e-9, atol=1e-12), (be, (got - ref).abs().max())
        # it is a bound on the ordinary gradient, and strictly larger where pixels pull apart
        assert (m2d.grad.abs() <= got + 1e-12).all()
        assert (got - m2d.grad.abs() > 1e-6).any()


def test_absgrad_of_the_cuda_backend_matches_the_reference():
    """gsplat's own absgrad (float32, on the GPU), read from a model kept on the CPU, against the
    per-pixel float64 reference (gsplat clamps alpha at 0.999: a loose tolerance)."""
    from brfgs.render.cuda_backend import available

    if not available():
        pytest.skip("needs a CUDA GPU and gsplat")
    sc = _scene()
    w_img, w_alpha = _weights((H, W, 3), 1), _weights((H, W), 2)
    ref = _reference_absgrad(sc, w_img, w_alpha)
    sc32 = {k: (v.float() if torch.is_tensor(v) and v.is_floating_point() else v) for k, v in sc.items()}
    m2d, grads = _render(sc32, "cuda", w_img.float(), w_alpha.float())
    got = m2d.absgrad
    assert got.device.type == "cpu" and got.shape == ref.shape
    assert (got.double() - ref).abs().max() <= 2e-2 * ref.abs().max()
    assert (m2d.grad.abs() <= got + 1e-5 * got.abs().max()).all()
    assert all(g.device.type == "cpu" for g in grads.values())


def test_absgrad_leaves_the_gradients_unchanged():
    sc = _scene(seed=9, n=60)
    w_img, w_alpha = _weights((H, W, 3), 3), _weights((H, W), 4)
    for be in ("torch", "cpu"):
        m_off, g_off = _render(sc, be, w_img, w_alpha, absgrad=False)
        m_on, g_on = _render(sc, be, w_img, w_alpha, absgrad=True)
        assert getattr(m_off, "absgrad", None) is None
        # the same sums; the compiler may fuse them differently (numba) or sum the per-pixel copy in
        # another order (torch), hence equal to rounding only
        assert torch.allclose(m_on.grad, m_off.grad, rtol=1e-12, atol=1e-15), be
        for k in g_off:
            assert torch.allclose(g_on[k], g_off[k], rtol=1e-12, atol=1e-15), (be, k)


def test_float32_kernel_agrees_with_float64():
    sc = _scene(seed=2)
    w_img, w_alpha = _weights((H, W, 3), 5), _weights((H, W), 6)
    m64, _ = _render(sc, "cpu", w_img, w_alpha)
    sc32 = {k: (v.float() if torch.is_tensor(v) and v.is_floating_point() else v) for k, v in sc.items()}
    m32, _ = _render(sc32, "cpu", w_img.float(), w_alpha.float())
    assert torch.allclose(m32.absgrad.double(), m64.absgrad, rtol=1e-3, atol=1e-5 * m64.absgrad.abs().max())


def test_densify_statistics_use_absgrad_when_asked():
    sc = _scene(seed=7)
    w_img, w_alpha = _weights((H, W, 3), 7), _weights((H, W), 8)
    m2d, _ = _render(sc, "cpu", w_img, w_alpha)
    vis = torch.ones(m2d.shape[0], dtype=torch.bool)
    plain, absolute = DensifyState(m2d.shape[0]), DensifyState(m2d.shape[0])
    accumulate(plain, m2d, vis, W, H)
    accumulate(absolute, m2d, vis, W, H, absgrad=True)
    scale = torch.tensor([W / 2.0, H / 2.0], dtype=m2d.dtype)
    assert torch.allclose(plain.grad2d, (m2d.grad * scale).norm(dim=-1).to(plain.grad2d.dtype))
    assert torch.allclose(absolute.grad2d, (m2d.absgrad * scale).norm(dim=-1).to(absolute.grad2d.dtype))
    assert (absolute.grad2d >= plain.grad2d - 1e-9).all() and (absolute.grad2d > plain.grad2d + 1e-6).any()


def test_cpu_backend_module_exposes_absgrad_on_raster():
    # the numba raster called directly (as the renderer does) fills .absgrad on its means2d
    sc = _scene(seed=11)
    proj = cpu_backend.project(sc["means"], sc["quats"], sc["scales"], sc["opacities"], sc["viewmat"], sc["K"],
                               W, H, NEAR_PLANE, FAR_PLANE)
    feats = sc["features"].clone().requires_grad_(True)
    m2d = proj.means2d.detach().requires_grad_(True)
    image, alpha = cpu_backend.raster(replace(proj, means2d=m2d), sc["opacities"], feats, W, H, absgrad=True)
    (image.sum() + alpha.sum()).backward()
    assert m2d.absgrad.shape == (sc["means"].shape[0], 2) and torch.isfinite(m2d.absgrad).all()


def test_training_renders_and_densifies_with_absgrad_only_when_asked(tmp_path, monkeypatch):
    import brfgs.train.strategy as strategy
    from brfgs.train.presets import preset
    from brfgs.train.trainer import train
    from test_train_scene import make_plane_scene

    torch.set_num_threads(1)
    scene = make_plane_scene(tmp_path / "scene", w=48, h=32, n_bands=12)
    seen = []
    real = strategy.accumulate

    def spy(state, means2d, visible, width, height, grad_scale=1.0, absgrad=False):
        seen.append((absgrad, getattr(means2d, "absgrad", None) is not None))
        real(state, means2d, visible, width, height, grad_scale, absgrad)

    monkeypatch.setattr(strategy, "accumulate", spy)
    for on in (False, True):
        seen.clear()
        cfg = preset("tiny", threads=1, stage1_steps=12, stage2_steps=2, densify=dict(absgrad=on))
        train(scene, tmp_path / f"run_{on}", cfg, progress=False, log=None)
        assert len(seen) >= 12 and set(seen) == {(on, on)}, (on, set(seen))
