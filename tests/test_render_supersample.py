"""Supersampled pixels (``--supersample s``, :mod:`brfgs.render.supersample`): each pixel is the mean
of s × s sub-pixel samples. Checked against an independent float64 numpy evaluation of a projected
Gaussian's alpha (EWA projection written out here) averaged over each pixel's sub-pixel centres, on
both CPU backends; gradients by finite differences; the depth of a block; the densification
statistic in the coarse grid's units; and that a model trained with it renders with it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from brfgs.errors import UserError
from brfgs.model.camera import Camera
from brfgs.model.densify import DensifyState
from brfgs.model.densify_config import ADCConfig
from brfgs.model.rendering import rasterize_splats
from brfgs.render._common import ALPHA_MAX, ALPHA_MIN, EPS2D
from brfgs.render.supersample import box_downsample, box_mean, fine_intrinsics
from brfgs.train.strategy import ADCStrategy

W, H = 14, 11
FX, FY, CX, CY = 9.0, 8.5, 6.8, 5.3


def _camera(dtype=torch.float64) -> Camera:
    K = torch.tensor([[FX, 0, CX], [0, FY, CY], [0, 0, 1]], dtype=dtype)
    return Camera("cam", torch.eye(4, dtype=dtype), K, W, H, torch.zeros(3, dtype=dtype))


def _gaussian(dtype=torch.float64):
    means = torch.tensor([[0.07, -0.04, 5.0]], dtype=dtype)
    quats = torch.tensor([[0.9, 0.2, -0.3, 0.25]], dtype=dtype)
    scales = torch.tensor([[0.35, 0.12, 0.2]], dtype=dtype)
    opac = torch.tensor([0.8], dtype=dtype)
    return means, quats, scales, opac


def _reference_alpha(s: int) -> np.ndarray:  # [H, W]
    """Mean over each pixel's s × s sub-pixel centres of min(0.99, o·exp(-½ dᵀ Σ⁻¹ d)) (0 below 1/255),
    Σ = J R S² Rᵀ Jᵀ + 0.3 I on the s-times finer grid: EWA splatting written out in float64."""
    m, q, sc, o = (t.numpy()[0] for t in _gaussian())
    w, x, y, z = q / np.linalg.norm(q)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    cov3 = R @ np.diag(sc ** 2) @ R.T
    fx, fy, cx, cy = FX * s, FY * s, CX * s, CY * s
    J = np.array([[fx / m[2], 0, -fx * m[0] / m[2] ** 2], [0, fy / m[2], -fy * m[1] / m[2] ** 2]])
    cov2 = J @ cov3 @ J.T + EPS2D * np.eye(2)
    mu = np.array([fx * m[0] / m[2] + cx, fy * m[1] / m[2] + cy])
    ys, xs = np.mgrid[0:H * s, 0:W * s] + 0.5
    d = np.stack([xs - mu[0], ys - mu[1]], -1)
    sigma = 0.5 * np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov2), d)
    a = np.minimum(ALPHA_MAX, o * np.exp(-sigma))
    a[a < ALPHA_MIN] = 0.0
    return a.reshape(H, s, W, s).mean(axis=(1, 3))


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_supersampled_pixel_is_the_mean_of_its_subpixel_samples(backend):
    means, quats, scales, opac = _gaussian()
    feats = torch.ones(1, 1, dtype=torch.float64)
    got = {}
    for s in (1, 2, 3):
        out = rasterize_splats(means, quats, scales, opac, feats, _camera(), backend, supersample=s)
        ref = _reference_alpha(s)
        assert out.image.shape == (H, W, 1) and out.alpha.shape == (H, W)
        assert np.allclose(out.alpha.numpy(), ref, atol=1e-10), (s, np.abs(out.alpha.numpy() - ref).max())
        assert np.allclose(out.image[..., 0].numpy(), ref, atol=1e-10)
        got[s] = ref
    # the box integral is not the point sample: a half-sub-pixel misalignment or s = 1 would fail above
    assert np.abs(got[2] - got[1]).max() > 0.02 and np.abs(got[3] - got[2]).max() > 0.005


def test_depth_of_a_block_is_its_alpha_weighted_mean():
    # two fronto-parallel discs at 4 m and 6 m, the far one showing past the near one's edge
    dt = torch.float64
    means = torch.tensor([[-0.25, 0.0, 4.0], [0.3, 0.0, 6.0]], dtype=dt)
    quats = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0]], dtype=dt)
    scales = torch.tensor([[0.3, 0.6, 1e-4], [0.5, 0.6, 1e-4]], dtype=dt)
    opac = torch.tensor([0.9, 0.9], dtype=dt)
    feats = torch.eye(2, dtype=dt)
    cam = _camera()
    out = rasterize_splats(means, quats, scales, opac, feats, cam, "torch", supersample=2)
    fine = rasterize_splats(means, quats, scales, opac, feats,
                            Camera("f", cam.viewmat, fine_intrinsics(cam.K, 2), 2 * W, 2 * H, cam.centre), "torch")
    acc = box_mean(fine.depth * fine.alpha, 2)
    a = box_mean(fine.alpha, 2)
    hit = a > 1e-3
    assert torch.allclose(out.depth[hit], (acc / a)[hit], rtol=1e-12)
    assert ((out.depth[hit] >= 4.0 - 1e-9) & (out.depth[hit] <= 6.0 + 1e-9)).all()
    mixed = hit & (out.image[..., 0] > 0.05) & (out.image[..., 1] > 0.05)
    assert mixed.any() and ((out.depth[mixed] > 4.05) & (out.depth[mixed] < 5.95)).any()
    assert (out.depth[~hit & (a == 0)] == 0).all()


def test_gradients_by_finite_differences():
    dt = torch.float64
    gen = torch.Generator().manual_seed(3)
    n = 4
    means = torch.cat([torch.rand(n, 2, generator=gen, dtype=dt) - 0.5, 4 + torch.rand(n, 1, generator=gen, dtype=dt)], 1)
    quats = torch.randn(n, 4, generator=gen, dtype=dt)
    log_s = torch.log(0.1 + 0.2 * torch.rand(n, 3, generator=gen, dtype=dt))
    logit_o = torch.randn(n, generator=gen, dtype=dt)
    feats = torch.rand(n, 2, generator=gen, dtype=dt)
    w = torch.randn(H, W, 2, generator=gen, dtype=dt)
    cam = _camera()

    def f(m, ls, lo, c):
        out = rasterize_splats(m, quats, torch.exp(ls), torch.sigmoid(lo), c, cam, "torch", supersample=2)
        return (out.image * w).sum() + (out.alpha * w[..., 0]).sum()

    args = tuple(t.clone().requires_grad_(True) for t in (means, log_s, logit_o, feats))
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_densification_statistic_is_in_coarse_pixels():
    # a Gaussian much larger than a pixel: its NDC gradient is (nearly) the same however finely
    # the pixel is sampled; without the conversion the supersampled one would be half as large
    dt = torch.float32
    means = torch.tensor([[0.1, 0.05, 5.0]], dtype=dt)
    quats = torch.tensor([[1.0, 0, 0, 0]], dtype=dt)
    scales = torch.tensor([[1.6, 1.2, 0.5]], dtype=dt)
    opac = torch.tensor([0.7], dtype=dt)
    feats = torch.ones(1, 1, dtype=dt)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=dt), torch.arange(W, dtype=dt), indexing="ij")
    target = (xs / W)[..., None]
    strat = ADCStrategy(60_000, 0.0, W, H, 1.0, cfg=ADCConfig())
    stats = {}
    for s in (1, 2):
        out = rasterize_splats(means.clone().requires_grad_(True), quats, scales, opac, feats,
                               _camera(dt), "cpu", supersample=s)
        strat.before_backward(out)
        ((out.image - target) ** 2).sum().backward()
        st = DensifyState(1)
        strat.after_backward(st, out, W, H)
        stats[s] = float(st.grad2d[0])
        assert out.meta.get("supersample", 1) == s
    assert stats[1] > 0
    assert abs(stats[2] / stats[1] - 1) < 0.05, stats


def test_factor_one_is_the_plain_render():
    means, quats, scales, opac = _gaussian()
    out = rasterize_splats(means, quats, scales, opac, torch.ones(1, 1, dtype=torch.float64), _camera(), "torch")
    assert box_downsample(out, 1) is out and "supersample" not in out.meta


def test_trained_model_renders_with_its_supersample(tmp_path):
    from brfgs.model import RenderSettings, TrainedModel, render
    from brfgs.train.presets import preset
    from brfgs.train.trainer import train
    from test_train_scene import make_plane_scene

    torch.set_num_threads(1)
    scene = make_plane_scene(tmp_path / "scene", w=48, h=32, n_bands=12)
    cfg = preset("tiny", threads=1, stage1_steps=6, stage2_steps=2, supersample=2)
    lm = TrainedModel.load(train(scene, tmp_path / "run", cfg, progress=False, log=None))
    assert lm.render_settings.supersample == 2
    cam = lm.cameras[0]
    r2 = render(lm, cam)
    lm.render_settings = RenderSettings(decode_order=lm.render_settings.decode_order, supersample=1)
    r1 = render(lm, cam)
    assert r2.cube.shape == r1.cube.shape == (32, 48, 12)
    assert np.abs(r2.cube - r1.cube).max() > 1e-4


@pytest.mark.parametrize("bad", [0, 5])
def test_supersample_out_of_range_names_the_field(bad):
    from brfgs.train.presets import preset

    with pytest.raises(UserError) as e:
        preset("tiny", supersample=bad)
    assert e.value.field == "supersample"
