"""Mip-Splatting's 3D smoothing filter (``--filter-3d``, brfgs.model.filter3d): the filter's
variance against a float64 numpy reference, the covariance/opacity rule against its definition
(the Gaussian's integral α·sqrt(det Σ) is kept; large Gaussians are untouched), its gradients, the
bake (a baked model renders as the filtered one), and a training run that resumes bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from brfgs.model import DensifyConfig, GaussianModel
from brfgs.model.camera import Camera
from brfgs.model.filter3d import FILTER_S, bake_filter, filter_variance_m2, filtered_scales_opacities
from brfgs.model.io import load
from brfgs.model.rendering import rasterize_features
from brfgs.train.presets import preset
from brfgs.train.trainer import train
from test_train_scene import make_plane_scene


def _look_down(x: float, y: float, z: float, f: float, w: int = 40, h: int = 30) -> Camera:
    """A camera at (x, y, z) looking straight down (OpenCV axes: x east, y south, z down)."""
    R = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # world -> camera rotation
    t = -R @ np.array([x, y, z])
    vm = np.eye(4)
    vm[:3, :3], vm[:3, 3] = R, t
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    return Camera("c", torch.tensor(vm, dtype=torch.float32), torch.tensor(K, dtype=torch.float32), w, h,
                  torch.tensor([x, y, z], dtype=torch.float32))


def _numpy_variance(means, cams, s=FILTER_S):
    """float64 loop: s·(min depth / f)² over the cameras whose image, grown by 15 %, holds the point."""
    out = []
    for p in means:
        best = np.inf
        for c in cams:
            vm, K = c.viewmat.double().numpy(), c.K.double().numpy()
            q = vm[:3, :3] @ p + vm[:3, 3]
            if q[2] <= 0.01:
                continue
            u, v = K[0, 0] * q[0] / q[2] + K[0, 2], K[1, 1] * q[1] / q[2] + K[1, 2]
            mu, mv = 0.15 * c.width / 2, 0.15 * c.height / 2
            if -mu <= u <= c.width + mu and -mv <= v <= c.height + mv:
                best = min(best, q[2] / K[0, 0])
        out.append(best)
    out = np.array(out)
    out[~np.isfinite(out)] = out[np.isfinite(out)].max()
    return s * out**2


def test_variance_matches_numpy_reference():
    g = torch.Generator().manual_seed(0)
    means = torch.cat([torch.rand(200, 3, generator=g) * torch.tensor([30.0, 30.0, 2.0]) - torch.tensor([15.0, 15, 0]),
                       torch.tensor([[500.0, 0.0, 0.0]])])  # the last one: in no view
    cams = [_look_down(0, 0, 20, 30.0), _look_down(8, -3, 35, 50.0), _look_down(-10, 5, 12, 25.0)]
    got = filter_variance_m2(means, cams).double().numpy()
    ref = _numpy_variance(means.double().numpy(), cams)
    np.testing.assert_allclose(got, ref, rtol=1e-5)
    assert got[-1] == pytest.approx(ref[:-1].max(), rel=1e-5)  # unseen: the largest seen value
    assert len(np.unique(np.round(got[:-1], 6))) > 3  # several cameras decide


def test_rule_keeps_the_integral_and_leaves_large_gaussians_alone():
    g = torch.Generator().manual_seed(1)
    scales = torch.exp(torch.randn(100, 3, generator=g, dtype=torch.float64) * 2)  # 1e-3 .. 1e3 m
    scales[:10] = 20 + scales[:10]  # large in every axis
    opac = torch.rand(100, generator=g, dtype=torch.float64) * 0.98 + 0.01
    var = torch.rand(100, generator=g, dtype=torch.float64) * 0.5
    s2, o2 = filtered_scales_opacities(scales, opac, var)
    ref_s = np.sqrt(scales.numpy() ** 2 + var.numpy()[:, None])
    np.testing.assert_allclose(s2.numpy(), ref_s, rtol=1e-12)
    # α·sqrt(det Σ) (the Gaussian's integral up to a constant) is what the filter keeps
    np.testing.assert_allclose((o2 * s2.prod(-1)).numpy(), (opac * scales.prod(-1)).numpy(), rtol=1e-10)
    assert (o2 <= opac).all()
    big = scales.min(-1).values > 20  # σ² ≤ 0.5 m² against s² > 400 m²: nothing changes
    assert big.sum() >= 10
    np.testing.assert_allclose(o2[big].numpy(), opac[big].numpy(), rtol=3e-3)
    # zero variance: the identity
    s0, o0 = filtered_scales_opacities(scales, opac, torch.zeros(100, dtype=torch.float64))
    assert torch.equal(s0, scales) and torch.allclose(o0, opac, rtol=1e-14)


def test_rule_gradients():
    g = torch.Generator().manual_seed(2)
    s = (torch.rand(8, 3, generator=g, dtype=torch.float64) + 0.1).requires_grad_(True)
    o = torch.rand(8, generator=g, dtype=torch.float64).requires_grad_(True)
    v = torch.rand(8, generator=g, dtype=torch.float64) * 0.3
    assert torch.autograd.gradcheck(lambda a, b: filtered_scales_opacities(a, b, v), (s, o))


def test_baked_model_renders_as_the_filtered_one():
    g = torch.Generator().manual_seed(3)
    n = 150
    params = {"means": torch.rand(n, 3, generator=g) * torch.tensor([16.0, 12, 1]) - torch.tensor([8.0, 6, 0]),
              "log_scales": torch.log(torch.rand(n, 3, generator=g) * 0.6 + 0.01),
              "quats": torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
              "opacity_logits": torch.randn(n, generator=g), "colors": torch.rand(n, 3, generator=g)}
    gm = GaussianModel(params, "cir", 16, 3)
    cams = [_look_down(0, 0, 20, 40.0), _look_down(3, 2, 15, 40.0)]
    plain = rasterize_features(gm, gm["colors"], cams[0], backend="torch").image.detach()
    gm.filter_var = filter_variance_m2(gm.means.detach(), cams)
    filtered = rasterize_features(gm, gm["colors"], cams[0], backend="torch").image.detach()
    assert (filtered - plain).abs().max() > 1e-3  # the filter is not a no-op here
    bake_filter(gm.params, gm.filter_var)
    gm.filter_var = None
    baked = rasterize_features(gm, gm["colors"], cams[0], backend="torch").image.detach()
    assert (baked - filtered).abs().max() < 1e-5


def test_filtered_training_resumes_bit_for_bit(tmp_path):
    torch.set_num_threads(1)
    scene = make_plane_scene(tmp_path / "scene", w=40, h=28, n_bands=10)
    cfg = preset("tiny", threads=1, stage1_steps=14, stage2_steps=4, checkpoint_every=5, filter_3d=True,
                 densify=DensifyConfig(refine_start=2, refine_every=4, refine_stop=12))
    ref = train(scene, tmp_path / "ref", cfg, progress=False, log=None)

    def stop(phase, step):
        if (phase, step) == ("stage1", 7):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(scene, tmp_path / "run", cfg, progress=False, callback=stop, log=None)
    got = train(scene, tmp_path / "run", cfg, progress=False, log=None)
    a, b = load(ref)[0], load(got)[0]
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
