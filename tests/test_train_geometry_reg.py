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
from brfgs.train.losses import depth_normal_loss, flatten_loss, image_edge_weight


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
    # gradients (depth and normal channels) against finite differences
    g = (geo_w + 0.01 * torch.randn(h, w, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(0)))
    g = g[4:10, 5:11].clone().requires_grad_(True)
    Kc = K.clone()
    Kc[0, 2] -= 5
    Kc[1, 2] -= 4
    a = alpha[4:10, 5:11]
    assert torch.autograd.gradcheck(lambda x: depth_normal_loss(x, a, Kc), (g,), eps=1e-6, atol=1e-6)


def test_per_gaussian_depth_normal_loss_counts_each_disc_by_its_weight():
    """Two discs on every ray of a plane: 80 % of the weight facing the plane's normal, 10 % a fin
    turned 80° away. 2DGS's per-Gaussian form is sum_k w_k (1 - n_k . n_d) (float64 reference);
    the blended form renormalises the mean normal, in which the fin is nearly hidden."""
    w, h, K, n0, depth, _ = _tilted_plane()
    side = torch.linalg.cross(n0, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    side = side / side.norm()
    fin = math.cos(math.radians(80)) * n0 + math.sin(math.radians(80)) * side
    wk = (0.8, 0.1)
    alpha = torch.full((h, w), sum(wk), dtype=torch.float64)
    blended = wk[0] * n0 + wk[1] * fin  # [3] premultiplied
    geo = torch.cat([(alpha * depth)[..., None], blended.expand(h, w, 3)], -1)
    expected = sum(wi * (1 - float(ni @ n0)) for wi, ni in zip(wk, (n0, fin)))
    per = float(depth_normal_loss(geo, alpha, K, per_gaussian=True))
    assert math.isclose(per, expected, rel_tol=1e-9)
    old = float(depth_normal_loss(geo, alpha, K))
    assert math.isclose(old, 0.9 * (1 - float(blended @ n0) / float(blended.norm())), rel_tol=1e-9)
    assert per > 5 * old  # the fin's misalignment is not averaged away
    # consistent discs cost nothing in either form
    flat = torch.cat([(alpha * depth)[..., None], alpha[..., None] * n0.expand(h, w, 3)], -1)
    assert float(depth_normal_loss(flat, alpha, K, per_gaussian=True)) < 1e-12
    g = (geo + 0.01 * torch.randn(h, w, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(1)))
    g = g[3:9, 4:10].clone().requires_grad_(True)
    Kc = K.clone()
    Kc[0, 2] -= 4
    Kc[1, 2] -= 3
    assert torch.autograd.gradcheck(lambda x: depth_normal_loss(x, alpha[3:9, 4:10], Kc, per_gaussian=True), (g,),
                                    eps=1e-6, atol=1e-6)


def _edge_weight_reference(img: np.ndarray, valid: np.ndarray, edge_rel: float) -> np.ndarray:
    """float64 loops: 3x3 box mean (edges replicated, invalid pixels 0), largest contrast to a
    valid 4-neighbour, relative to edge_rel x the channel's mean |I| over the valid pixels."""
    h, w, c = img.shape
    t = np.where(valid[..., None], img, 0.0)
    scale = edge_rel * np.abs(t[valid]).mean(0)
    box = np.zeros_like(t)
    for y in range(h):
        for x in range(w):
            ys = [min(max(y + d, 0), h - 1) for d in (-1, 0, 1)]
            xs = [min(max(x + d, 0), w - 1) for d in (-1, 0, 1)]
            box[y, x] = t[np.ix_(ys, xs)].reshape(9, c).mean(0)
    out = np.ones((h, w))
    for y in range(h):
        for x in range(w):
            g = np.zeros(c)
            for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                yy, xx = y + dy, x + dx
                if 0 <= yy < h and 0 <= xx < w and valid[y, x] and valid[yy, xx]:
                    g = np.maximum(g, np.abs(box[yy, xx] - box[y, x]))
            out[y, x] = math.exp(-(g / scale).max())
    return out


def test_image_edge_weight_against_float64_loops_and_limits():
    rng = np.random.default_rng(3)
    img = rng.uniform(0.05, 0.6, (9, 11, 3))
    valid = rng.uniform(size=(9, 11)) > 0.15
    img[~valid] = np.nan
    got = image_edge_weight(torch.as_tensor(img), torch.as_tensor(valid), 0.3).numpy()
    np.testing.assert_allclose(got, _edge_weight_reference(np.nan_to_num(img), valid, 0.3), rtol=1e-12, atol=1e-14)
    # a uniform surface weighs 1; a material edge (a bright crown against dark ground) ~0 on both
    # sides (box means 0.2 | 0.33 | 0.47 | 0.6: contrast 0.13 against 0.1 x the mean 0.4), and 1
    # two pixels away, where the 3x3 mean no longer straddles it
    flat = torch.full((8, 12, 2), 0.2, dtype=torch.float64)
    ok = torch.ones(8, 12, dtype=torch.bool)
    assert torch.equal(image_edge_weight(flat, ok, 0.1), torch.ones(8, 12, dtype=torch.float64))
    step = flat.clone()
    step[:, 6:] = 0.6
    w = image_edge_weight(step, ok, 0.1)
    assert torch.allclose(w[:, 5:7], torch.tensor(math.exp(-0.4 / 3 / 0.04), dtype=torch.float64))
    assert float(w[:, :4].min()) == 1.0 and float(w[:, 8:].min()) == 1.0


def test_weighted_depth_normal_loss_is_a_weighted_mean():
    w, h, K, n0, depth, alpha = _tilted_plane()
    gen = torch.Generator().manual_seed(1)
    nr = torch.nn.functional.normalize(n0 + 0.3 * torch.randn(h, w, 3, dtype=torch.float64, generator=gen), dim=-1)
    geo = torch.cat([(alpha * depth)[..., None], alpha[..., None] * nr], -1)
    ones = torch.ones(h, w, dtype=torch.float64)
    plain = float(depth_normal_loss(geo, alpha, K))
    assert math.isclose(float(depth_normal_loss(geo, alpha, K, weight=3.0 * ones)), plain, rel_tol=1e-12)
    wt = torch.rand(h, w, dtype=torch.float64, generator=gen)
    nd, valid = normals_from_depth(depth, K)  # the plane's own normal
    err = 0.9 * (1 - (nr * nd).sum(-1))
    expected = float((err * wt)[valid].sum() / wt[valid].sum())
    assert math.isclose(float(depth_normal_loss(geo, alpha, K, weight=wt)), expected, rel_tol=1e-10)
    # a pixel of weight 0 does not count, however wrong its normal
    bad = geo.clone()
    bad[5, 5, 1:] = alpha[5, 5] * torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    wz = wt.clone()
    wz[5, 5] = 0.0
    assert math.isclose(float(depth_normal_loss(bad, alpha, K, weight=wz)), float(depth_normal_loss(geo, alpha, K, weight=wz)),
                        rel_tol=1e-12)
    # normals only: the same value, no gradient reaches the depth channel, the normals' is unchanged
    gd = geo.clone().requires_grad_(True)
    gn = geo.clone().requires_grad_(True)
    depth_normal_loss(gd, alpha, K, weight=wt).backward()
    only = depth_normal_loss(gn, alpha, K, weight=wt, depth_grad=False)
    only.backward()
    assert math.isclose(float(only.detach()), expected, rel_tol=1e-10)
    assert float(gd.grad[..., 0].abs().max()) > 0 and float(gn.grad[..., 0].abs().max()) == 0.0
    assert torch.equal(gn.grad[..., 1:], gd.grad[..., 1:])
    g = geo[3:9, 4:10].clone().requires_grad_(True)
    Kc = K.clone()
    Kc[0, 2] -= 4
    Kc[1, 2] -= 3
    assert torch.autograd.gradcheck(lambda x: depth_normal_loss(x, alpha[3:9, 4:10], Kc, weight=wt[3:9, 4:10]), (g,),
                                    eps=1e-6, atol=1e-6)


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
