"""Centred kernel parametrisation used in training == eq. 12 after uncentre()."""

import numpy as np
import torch

from brfgs.brdf.head import HeadConfig, evaluate_head, init_head_params
from brfgs.brdf.geometry import gaussian_normals
from brfgs.model.gaussians import init_from_points
from brfgs.brdf.geometry import view_directions as view_dirs
from brfgs.model.features import centred_hybrid_latent, uncentre


def _random_model(n: int, latent_dim: int, seed: int):
    """n Gaussians at random positions with random rotations and scales (torch and numpy seeded)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    m = init_from_points(rng.uniform(-5, 5, (n, 3)), rng.uniform(0, 1, (n, 3)), latent_dim=latent_dim)
    with torch.no_grad():
        m.params["quats"].copy_(torch.randn(n, 4))
        m.params["log_scales"].copy_(torch.randn(n, 3))
    return m


def test_centred_equals_eq12_after_uncentre():
    m = _random_model(40, 5, seed=0)
    cfg = HeadConfig(kind="hybrid")
    params = init_head_params(cfg, 40, 5, z_init=torch.randn(40, 5))
    for k in ("z_vol", "z_geo", "z_spec"):
        params[k] = torch.randn(40, 5)
    params["rho_raw"] = torch.randn(40)
    m.set_head(params, "brf")
    m.centred = True
    sun = torch.tensor([0.3, -0.5, 0.81])
    sun = sun / sun.norm()
    plain = uncentre(m, cfg, sun)
    for centre in (torch.tensor([30.0, 10.0, 80.0]), torch.tensor([0.0, 0.0, 100.0])):
        wo = view_dirs(m.means, centre)
        n = gaussian_normals(m.quats, m.scales, wo)
        a = centred_hybrid_latent(m, cfg, n, sun, wo)
        b = evaluate_head(cfg, {k: plain[k] for k in ("z_iso", "z_vol", "z_geo", "z_spec", "rho_raw")}, n, sun, wo)
        assert torch.allclose(a, b, atol=1e-4), (a - b).abs().max()
    # at nadir the centred form gives z'_iso exactly
    wo = torch.zeros(40, 3)
    wo[:, 2] = 1
    n = gaussian_normals(m.quats, m.scales, wo)
    assert torch.allclose(centred_hybrid_latent(m, cfg, n, sun, wo), m["z_iso"], atol=1e-5)


def test_learned_shading_normals_replace_the_smallest_axis():
    """With a 'normals' tensor the head uses it (normalised, facing ω_o), in the centred and the eq. 12 form."""
    from brfgs.brdf.geometry import shading_normals

    m = _random_model(30, 4, seed=1)
    wo = view_dirs(m.means, torch.tensor([20.0, -10.0, 90.0]))
    # no learned normals: the smallest axis
    assert torch.equal(shading_normals(m.quats, m.scales, wo, None), gaussian_normals(m.quats, m.scales, wo))
    raw = torch.randn(30, 3) * 3.0
    n = shading_normals(m.quats, m.scales, wo, raw)
    assert torch.allclose(n.norm(dim=-1), torch.ones(30), atol=1e-6)
    assert bool(((n * wo).sum(-1) >= 0).all())
    assert torch.allclose(n.abs(), (raw / raw.norm(dim=-1, keepdim=True)).abs(), atol=1e-6)
    cfg = HeadConfig(kind="hybrid")
    params = init_head_params(cfg, 30, 4, z_init=torch.randn(30, 4))
    for k in ("z_vol", "z_geo", "z_spec"):
        params[k] = torch.randn(30, 4)
    params["normals"] = raw
    m.set_head(params, "brf")
    m.centred = True
    sun = torch.tensor([0.3, -0.5, 0.81])
    sun = sun / sun.norm()
    plain = uncentre(m, cfg, sun)
    a = centred_hybrid_latent(m, cfg, n, sun, wo)
    b = evaluate_head(cfg, {k: plain[k] for k in ("z_iso", "z_vol", "z_geo", "z_spec", "rho_raw")}, n, sun, wo)
    assert torch.allclose(a, b, atol=1e-4), (a - b).abs().max()
    # and it differs from the geometric-normal head (the normals matter)
    c = centred_hybrid_latent(m, cfg, gaussian_normals(m.quats, m.scales, wo), sun, wo)
    assert (a - c).abs().max() > 1e-3


def test_centred_form_with_frame_suns_is_eq12_under_each_frames_sun():
    """Frames with their own suns share one centring (the reference sun): the trained centred form
    under frame sun ω_f equals eq. 12 (after uncentre with the reference sun) evaluated under ω_f."""
    m = _random_model(30, 4, seed=1)
    cfg = HeadConfig(kind="hybrid")
    params = init_head_params(cfg, 30, 4, z_init=torch.randn(30, 4))
    for k in ("z_vol", "z_geo", "z_spec"):
        params[k] = torch.randn(30, 4)
    params["rho_raw"] = torch.randn(30)
    m.set_head(params, "brf")
    m.centred = True
    ref = torch.tensor([0.2, -0.5, 0.84])
    ref = ref / ref.norm()
    plain = uncentre(m, cfg, ref)
    wo = view_dirs(m.means, torch.tensor([20.0, -15.0, 90.0]))
    n = gaussian_normals(m.quats, m.scales, wo)
    keys = ("z_iso", "z_vol", "z_geo", "z_spec", "rho_raw")
    for frame_sun in (torch.tensor([0.25, -0.45, 0.86]), torch.tensor([0.1, -0.6, 0.79])):
        frame_sun = frame_sun / frame_sun.norm()
        a = centred_hybrid_latent(m, cfg, n, frame_sun, wo, ref_sun=ref)
        b = evaluate_head(cfg, {k: plain[k] for k in keys}, n, frame_sun, wo)
        assert torch.allclose(a, b, atol=1e-4), (a - b).abs().max()
        # centring with the frame's own sun instead would be a different model: the reference matters
        c = centred_hybrid_latent(m, cfg, n, frame_sun, wo)
        assert (c - b).abs().max() > 1e-3
