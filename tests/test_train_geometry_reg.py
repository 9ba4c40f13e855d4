"""Geometry regularisers of the geometry-training phases: depth-normal consistency and flatness."""

import math

import numpy as np
import torch

from brfgs.brdf.geometry import gaussian_normals
from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.model.gaussians import init_from_points
from brfgs.model.camera import camera_from_c2w
from brfgs.model.features import camera_depth_normals
from brfgs.model.rendering import rasterize_features
from brfgs.render.geometry import normals_from_depth
from brfgs.train.losses import depth_normal_loss, flatten_loss


def _K(w=24, h=20, f=30.0):
    return torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]], dtype=torch.float64)


def _plane_depth(n0: np.ndarray, c: float, K: torch.Tensor, w: int, h: int) -> torch.Tensor:
    """Depth map of the plane n0 · P = c (camera axes): d = c / (n0 · K⁻¹[u, v, 1])."""
    Kn = K.numpy()
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    r = np.stack([(u - Kn[0, 2]) / Kn[0, 0], (v - Kn[1, 2]) / Kn[1, 1], np.ones_like(u)], -1)
    return torch.as_tensor(c / (r @ n0))


def test_normals_from_depth_of_a_tilted_plane():
    w, h = 24, 20
    K = _K(w, h)
    n0 = np.array([0.3, -0.2, -1.0])
    n0 /= np.linalg.norm(n0)  # facing the camera (negative z: toward the origin)
    depth = _plane_depth(n0, -10.0, K, w, h)
    assert bool((depth > 0).all())
    n, valid = normals_from_depth(depth, K)
    assert valid.sum() == (w - 2) * (h - 2)
    err = (n[valid] - torch.as_tensor(n0)).abs().max()
    assert err < 1e-9, err
    # a hole invalidates its neighbours, not the rest
    depth[5, 5] = float("nan")
    _, valid2 = normals_from_depth(depth, K)
    assert not valid2[5, 5] and not valid2[4, 5] and not valid2[5, 6] and valid2[10, 10]


def _tilted_plane():
    """A 16 x 14 window of the plane with unit normal ~(0.1, 0.25, -1) 8 m away: sizes, K, normal,
    depth [H, W] and a uniform alpha 0.9."""
    w, h = 16, 14
    K = _K(w, h, 20.0)
    n0 = torch.tensor([0.1, 0.25, -1.0], dtype=torch.float64)
    n0 = n0 / n0.norm()
    return w, h, K, n0, _plane_depth(n0.numpy(), -8.0, K, w, h), torch.full((h, w), 0.9, dtype=torch.float64)


def _normal_gradcheck(geo: torch.Tensor, alpha: torch.Tensor, K: torch.Tensor, rows, cols) -> bool:
    """gradcheck of depth_normal_loss in the normal channels of a window of ``geo`` (the depth is
    detached by the loss: no gradient reaches it, checked apart)."""
    g = geo[rows, cols].clone()
    Kc = K.clone()
    Kc[0, 2] -= cols.start
    Kc[1, 2] -= rows.start
    a = alpha[rows, cols]
    d = g[..., :1]
    n = g[..., 1:].clone().requires_grad_(True)
    whole = g.clone().requires_grad_(True)
    depth_normal_loss(whole, a, Kc).backward()
    assert float(whole.grad[..., 0].abs().max()) == 0.0  # the prior never moves the depth
    return torch.autograd.gradcheck(lambda x: depth_normal_loss(torch.cat([d, x], -1), a, Kc), (n,), eps=1e-6,
                                    atol=1e-6)


def test_depth_normal_loss_zero_when_consistent_and_gradients():
    w, h, K, n0, depth, alpha = _tilted_plane()
    geo = torch.cat([(alpha * depth)[..., None], alpha[..., None] * n0.expand(h, w, 3)], -1)
    assert float(depth_normal_loss(geo, alpha, K)) < 1e-12
    # a wrong rendered normal costs 1 - cos (weighted by alpha)
    wrong = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    geo_w = torch.cat([(alpha * depth)[..., None], alpha[..., None] * wrong.expand(h, w, 3)], -1)
    expected = 0.9 * (1 - float(wrong @ n0))
    assert math.isclose(float(depth_normal_loss(geo_w, alpha, K)), expected, rel_tol=1e-9)
    # transparent pixels do not count
    assert float(depth_normal_loss(geo_w, torch.full_like(alpha, 0.2), K)) == 0.0
    # gradients of the normal channels against finite differences
    g = geo_w + 0.01 * torch.randn(h, w, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    assert _normal_gradcheck(g, alpha, K, slice(4, 10), slice(5, 11))


def test_depth_normal_loss_counts_each_disc_by_its_weight():
    """Two discs on every ray of a plane: 80 % of the weight facing the plane's normal, 10 % a fin
    turned 80° away. 2DGS's per-Gaussian form is sum_k w_k (1 - n_k . n_d) (float64 reference); a
    renormalised mean normal would nearly hide the fin."""
    w, h, K, n0, depth, _ = _tilted_plane()
    side = torch.linalg.cross(n0, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    side = side / side.norm()
    fin = math.cos(math.radians(80)) * n0 + math.sin(math.radians(80)) * side
    wk = (0.8, 0.1)
    alpha = torch.full((h, w), sum(wk), dtype=torch.float64)
    blended = wk[0] * n0 + wk[1] * fin  # [3] premultiplied
    geo = torch.cat([(alpha * depth)[..., None], blended.expand(h, w, 3)], -1)
    expected = sum(wi * (1 - float(ni @ n0)) for wi, ni in zip(wk, (n0, fin)))
    per = float(depth_normal_loss(geo, alpha, K))
    assert math.isclose(per, expected, rel_tol=1e-9)
    renormalised = 0.9 * (1 - float(blended @ n0) / float(blended.norm()))
    assert per > 5 * renormalised  # the fin's misalignment is not averaged away
    flat = torch.cat([(alpha * depth)[..., None], alpha[..., None] * n0.expand(h, w, 3)], -1)
    assert float(depth_normal_loss(flat, alpha, K)) < 1e-12
    g = geo + 0.01 * torch.randn(h, w, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    assert _normal_gradcheck(g, alpha, K, slice(3, 9), slice(4, 10))


def test_flatten_loss_limits():
    disc = torch.log(torch.tensor([[1.0, 1.0, 1e-4]]))
    ball = torch.zeros(1, 3)
    assert float(flatten_loss(disc)) < 1e-3
    assert math.isclose(float(flatten_loss(ball)), 1.0)


def _plane_model(tilt_deg: float, n_side: int = 14, seed: int = 0):
    """Flat discs on a regular grid over z = 0 (10 m square), each tilted by ``tilt_deg`` about a random axis."""
    rng = np.random.default_rng(seed)
    g = (np.arange(n_side) + 0.5) / n_side * 10 - 5
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pts = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    m = init_from_points(pts, np.full((len(pts), 3), 0.5), latent_dim=2)
    axis_ang = rng.uniform(0, 2 * np.pi, len(pts))
    t = np.radians(tilt_deg) / 2
    q = np.stack([np.full(len(pts), np.cos(t)), np.sin(t) * np.cos(axis_ang), np.sin(t) * np.sin(axis_ang),
                  np.zeros(len(pts))], 1)
    with torch.no_grad():
        m.params["quats"].copy_(torch.as_tensor(q, dtype=torch.float32))
        s = 10 / n_side
        m.params["log_scales"].copy_(torch.log(torch.tensor([[s, s, s * 0.05]])).expand(len(pts), 3))
        m.params["opacity_logits"].fill_(3.0)
    return m


def _tilt_deg(m) -> np.ndarray:
    up = torch.zeros_like(m.means)
    up[:, 2] = 1
    n = gaussian_normals(m.quats, m.scales, up).detach()
    return np.degrees(np.arccos(np.clip(n[:, 2].numpy(), -1, 1)))


def test_camera_depth_normals_at_nadir():
    m = _plane_model(0.0, n_side=4)
    intr = Intrinsics.from_fov(40.0, 16, 16)
    cam = camera_from_c2w("nadir", pose_from_view_angles(0.0, 0.0, 30.0), intr.K(), 16, 16)
    g = camera_depth_normals(m, cam)
    assert torch.allclose(g[:, 0], torch.full((m.n,), 30.0), atol=1e-4)  # depth along the optical axis
    assert torch.allclose(g[:, 1:], torch.tensor([0.0, 0.0, -1.0]).expand(m.n, 3), atol=1e-5)  # faces the camera


def test_depth_normal_loss_levels_tilted_discs_on_a_plane():
    """Textureless flat ground: the photometric loss cannot orient its Gaussians; the depth-normal
    loss (their depths lie on the plane) turns their normals toward the plane's normal."""
    torch.manual_seed(0)
    m = _plane_model(35.0, n_side=10)
    before = _tilt_deg(m)
    assert np.median(before) > 30
    intr = Intrinsics.from_fov(50.0, 24, 24)
    cams = [camera_from_c2w(f"v{k}", pose_from_view_angles(z, a, 25.0), intr.K(), 24, 24)
            for k, (z, a) in enumerate([(0, 0), (20, 0), (20, 120), (20, 240)])]
    opt = torch.optim.Adam([m.params["quats"]], lr=0.03)
    for step in range(40):
        cam = cams[step % len(cams)]
        out = rasterize_features(m, camera_depth_normals(m, cam), cam, backend="cpu")
        loss = depth_normal_loss(out.image, out.alpha, cam.K)
        opt.zero_grad()
        loss.backward()
        opt.step()
    after = _tilt_deg(m)
    assert np.median(after) < 0.5 * np.median(before), (np.median(before), np.median(after))


def test_normal_smoothness_loss_limits_and_effect():
    from brfgs.train.losses import normal_smoothness_loss

    g = torch.Generator().manual_seed(0)
    up = torch.tensor([0.0, 0.0, 1.0]).expand(50, 3).clone()
    nbr = torch.stack([(torch.arange(50) + s) % 50 for s in (1, 2, 3, 49, 48)], 1)  # ring neighbours
    assert float(normal_smoothness_loss(up, nbr)) < 1e-12
    flipped = up * torch.where(torch.rand(50, 1, generator=g) < 0.5, -1.0, 1.0) * 3.0  # sign and length free
    assert float(normal_smoothness_loss(flipped, nbr)) < 1e-12
    # a tilted normal among upright neighbours (and nobody's neighbour itself) costs sin² of its tilt
    tilted = up.clone()
    tilted[0] = torch.tensor([math.sin(0.3), 0.0, math.cos(0.3)])
    star = torch.arange(1, 6).expand(50, 5)
    assert math.isclose(float(normal_smoothness_loss(tilted, star)) * 50, math.sin(0.3) ** 2, rel_tol=1e-5)
    # minimising it pulls randomly tilted normals (tilts about the vertical) toward their common direction
    n = (up + 0.4 * torch.randn(50, 3, generator=g)).requires_grad_(True)
    spread0 = float(normal_smoothness_loss(n, nbr).detach())
    opt = torch.optim.Adam([n], lr=0.02)
    for _ in range(100):
        loss = normal_smoothness_loss(n, nbr)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(normal_smoothness_loss(n, nbr).detach()) < 0.2 * spread0
