"""Gaussian container, initialisation, NamedAdam and densification row edits."""

import numpy as np
import pytest
import torch

from brfgs.model.densify import ADCConfig, DensifyState, quat_to_rotmat, refine, reset_opacity
from brfgs.model.gaussians import init_from_points, knn_scale, scene_extent
from brfgs.model.optim import NamedAdam


def _model(n=50, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-5, 5, (n, 3))
    pts[:, 2] *= 0.1
    return init_from_points(pts, rng.uniform(0, 0.5, (n, 3)), latent_dim=4, init_opacity=0.1)


def test_init_from_points():
    m = _model()
    assert m.n == 50
    assert torch.allclose(m.opacities, torch.full((50,), 0.1), atol=1e-6)
    assert torch.allclose(m.quats, torch.tensor([1.0, 0, 0, 0]).expand(50, 4))
    # isotropic scale = RMS distance to the 3 nearest neighbours
    pts = m.means.detach().numpy().astype(np.float64)
    d = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1))
    d.sort(1)
    ref = np.sqrt((d[:, 1:4] ** 2).mean(1))
    assert np.allclose(m.scales[:, 0].detach().numpy(), ref, rtol=1e-5)
    assert np.allclose(knn_scale(pts), ref)
    assert scene_extent(pts) > 1
    with pytest.raises(ValueError):
        init_from_points(np.zeros((3, 2)), np.zeros((3, 1)), 4)


def test_named_adam_matches_torch_adam():
    torch.manual_seed(0)
    x = torch.randn(7, 3, requires_grad=True)
    y = x.detach().clone().requires_grad_(True)
    ours = NamedAdam({"x": 0.01})
    ref = torch.optim.Adam([y], lr=0.01, eps=1e-15)
    for _ in range(5):
        for p in (x, y):
            p.grad = None
        (x**3).sum().backward()
        (y**3).sum().backward()
        ours.step({"x": x})
        ref.step()
    assert torch.allclose(x, y, atol=1e-6)


def test_refine_clones_splits_prunes_and_keeps_optimiser_rows_aligned():
    m = _model()
    n = m.n
    opt = NamedAdam({k: 1e-3 for k in m.params})
    for p in m.params.values():
        p.grad = torch.ones_like(p)
    opt.step(m.params)
    st = DensifyState(n)
    st.count[:] = 1
    st.grad2d[:10] = 1.0  # high gradient for the first 10
    with torch.no_grad():
        m.params["log_scales"][:5] = np.log(0.001)  # small -> clone
        m.params["log_scales"][5:10] = np.log(5.0)  # large -> split
        m.params["opacity_logits"][40:] = -10  # transparent -> prune
    mark = torch.arange(n, dtype=torch.float32)[:, None].repeat(1, 3)
    m.params["colors"] = mark.clone().requires_grad_(True)  # row identity
    opt.m["colors"] = mark.clone()
    cfg = ADCConfig(grow_grad2d=0.5, grow_scale3d=0.01, prune_opacity=0.005)
    info = refine(m, opt, st, cfg, extent=10.0, gen=torch.Generator().manual_seed(0), max_gaussians=60_000)
    assert info == {"cloned": 5, "split": 5, "pruned": 10, "n": n + 5 + 5 - 10}
    rows = m["colors"][:, 0].long().tolist()
    # originals 0..39 minus split parents 5..9, then clones 0..4, then 2 children each of 5..9
    assert rows == [i for i in range(40) if not 5 <= i < 10] + [0, 1, 2, 3, 4] + [5, 6, 7, 8, 9] * 2
    # moments follow: survivors keep theirs, new rows start at zero
    mom = opt.m["colors"][:, 0]
    assert mom[:35].tolist() == [float(i) for i in range(40) if not 5 <= i < 10]
    assert (mom[35:] == 0).all()
    for k, v in m.params.items():
        assert v.shape[0] == m.n and v.requires_grad and v.is_leaf, k
        assert opt.m[k].shape == v.shape and opt.v[k].shape == v.shape, k
    # split children: scale / 1.6, means near the parent
    assert torch.allclose(m.scales[-1], torch.full((3,), 5.0 / 1.6), rtol=1e-5)
    reset_opacity(m, opt, st, cfg)
    assert (m.opacities <= 0.0100001).all() and st.n_resets == 1


def test_quat_to_rotmat_is_rotation():
    q = torch.randn(20, 4)
    R = quat_to_rotmat(q)
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3).expand(20, 3, 3), atol=1e-5)
    assert torch.allclose(torch.linalg.det(R), torch.ones(20), atol=1e-5)
