"""3DGS-MCMC densification (brfgs.model.mcmc): the relocation weights against 1-D quadrature,
relocation and growth keep rows and optimiser moments aligned, the noise moves only nearly
transparent Gaussians, and the L1 priors."""

import numpy as np
import pytest
import torch
from scipy.integrate import quad

from brfgs.model.gaussians import init_from_points, inverse_sigmoid
from brfgs.model.mcmc import (add_gaussians, mcmc_regulariser, perturb_means, relocate_dead,
                              relocation_opacity_scale)
from brfgs.model.optim import NamedAdam


@pytest.mark.parametrize("o", [0.05, 0.3, 0.7, 0.95])
@pytest.mark.parametrize("n", [1, 2, 5, 20])
def test_relocation_weights_composite_like_the_original(o, n):
    """N copies with (o', s') alpha-composited: the peak opacity 1 − (1 − o')^N equals o and the
    integral of the composited profile along an axis equals that of the original (eq. 9's aim)."""
    on, sn = relocation_opacity_scale(torch.tensor([o], dtype=torch.float64), torch.full((1, 3), 0.7, dtype=torch.float64),
                                      torch.tensor([n]))
    on, sn = float(on), sn[0].numpy()
    assert 1 - (1 - on) ** n == pytest.approx(o, rel=1e-12)
    np.testing.assert_allclose(sn, sn[0])  # every axis scaled alike
    orig = quad(lambda x: o * np.exp(-x * x / (2 * 0.7**2)), -20, 20)[0]
    comp = quad(lambda x: 1 - (1 - on * np.exp(-x * x / (2 * sn[0] ** 2))) ** n, -20, 20)[0]
    assert comp == pytest.approx(orig, rel=1e-9)
    if n == 1:
        assert on == pytest.approx(o) and sn[0] == pytest.approx(0.7)


def _model(n=12, seed=0):
    rng = np.random.default_rng(seed)
    m = init_from_points(rng.normal(size=(n, 3)), rng.uniform(0, 1, (n, 3)), latent_dim=2)
    with torch.no_grad():
        m.params["opacity_logits"].copy_(inverse_sigmoid(torch.tensor(rng.uniform(0.1, 0.9, n))))
    opt = NamedAdam({k: 1e-2 for k in m.params})
    for _ in range(2):  # some moments
        loss = sum((v.float() ** 2).sum() for v in m.params.values())
        NamedAdam.zero_grad(m.params)
        loss.backward()
        opt.step(m.params)
    return m, opt


def test_relocation_moves_dead_gaussians_onto_live_ones():
    m, opt = _model()
    with torch.no_grad():
        m.params["opacity_logits"][[2, 7]] = float(inverse_sigmoid(0.001))
    before = {k: v.detach().clone() for k, v in m.params.items()}
    moved = relocate_dead(m, opt, 0.005, torch.Generator().manual_seed(0))
    assert moved == 2 and m.n == 12
    means = m.means.detach()
    for dead in (2, 7):  # each dead row now sits exactly on a live one, sharing its re-weighted opacity
        src = [i for i in range(12) if i not in (2, 7) and torch.equal(means[i], means[dead])]
        assert len(src) == 1
        s = src[0]
        copies = sum(torch.equal(means[j], means[s]) for j in range(12))
        o_new = float(m.opacities[s].detach())
        assert 1 - (1 - o_new) ** copies == pytest.approx(float(torch.sigmoid(before["opacity_logits"][s])), rel=1e-5)
        assert float(m.opacities[dead].detach()) == pytest.approx(o_new)
        for k in ("m", "v"):
            assert float(getattr(opt, k)["means"][dead].abs().sum()) == 0.0
            assert float(getattr(opt, k)["means"][s].abs().sum()) == 0.0
    untouched = [i for i in range(12) if not any(torch.equal(means[i], means[d]) for d in (2, 7))]
    assert untouched and all(float(opt.m["means"][i].abs().sum()) > 0 for i in untouched)
    assert relocate_dead(m, opt, 0.005, torch.Generator().manual_seed(0)) == 0  # nothing dead now


def test_growth_appends_copies_with_zero_moments():
    m, opt = _model()
    total_before = float(m.opacities.detach().sum())
    assert add_gaussians(m, opt, 5, torch.Generator().manual_seed(1)) == 5
    assert m.n == 17 and all(v.shape[0] == 17 for v in m.params.values())
    assert all(opt.m[k].shape[0] == 17 and opt.v[k].shape[0] == 17 for k in opt.m)
    assert float(opt.m["means"][12:].abs().sum()) == 0.0
    for i in range(12, 17):  # every new row is a copy of an old one
        assert any(torch.equal(m.means[i], m.means[j]) for j in range(12))
    assert float(m.opacities.detach().sum()) < total_before + 5  # sources were re-weighted, not duplicated at full opacity


def test_noise_moves_only_nearly_transparent_gaussians_and_is_seeded():
    m, _ = _model()
    with torch.no_grad():
        m.params["opacity_logits"][:6] = float(inverse_sigmoid(0.6))
        m.params["opacity_logits"][6:] = float(inverse_sigmoid(0.001))
    start = m.means.detach().clone()
    perturb_means(m, lr_means_m=0.01, extent_m=2.0, noise_lr=5e5, gen=torch.Generator().manual_seed(3))
    moved = (m.means.detach() - start).norm(dim=-1)
    assert float(moved[:6].max()) < 1e-12 and float(moved[6:].min()) > 1e-4
    m2, _ = _model()
    with torch.no_grad():
        m2.params["opacity_logits"].copy_(m.params["opacity_logits"])
    perturb_means(m2, lr_means_m=0.01, extent_m=2.0, noise_lr=5e5, gen=torch.Generator().manual_seed(3))
    assert torch.equal(m2.means, m.means)


def test_l1_priors_value_and_gradient_sign():
    m, _ = _model()
    r = mcmc_regulariser(m, 0.01, 0.02, extent_m=4.0)
    ref = 0.01 * float(m.opacities.detach().mean()) + 0.02 * float(m.scales.detach().mean()) / 4.0
    assert float(r.detach()) == pytest.approx(ref, rel=1e-6)
    NamedAdam.zero_grad(m.params)
    r.backward()
    assert (m.params["opacity_logits"].grad > 0).all() and (m.params["log_scales"].grad > 0).all()
