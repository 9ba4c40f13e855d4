"""Initial surface fill covers what the cameras see; no opacity reset at the end of a phase."""

import numpy as np
import torch

from brfgs.model.densify import DensifyState
from brfgs.model.densify_config import ADCConfig, MCMCConfig
from brfgs.model.gaussians import init_from_points, surface_fill
from brfgs.model.optim import NamedAdam
from brfgs.train.config import TrainConfig
from brfgs.train.strategy import ADCStrategy, MCMCStrategy, make_strategy


def _points():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-5, 5, (40, 2))
    return np.concatenate([xy, (0.1 * xy[:, :1] + 2.0)], 1)  # plane z = 2 + 0.1 x


def test_fill_without_cover_stays_in_hull():
    g = surface_fill(_points(), 500)
    assert g.shape[0] > 300
    assert np.abs(g[:, :2]).max() <= 5.0
    np.testing.assert_allclose(g[:, 2], 2 + 0.1 * g[:, 0], atol=1e-9)  # linear interpolation is exact on a plane


def test_fill_with_cover_reaches_the_footprint_and_keeps_filter():
    cover = np.array([[-20.0, -20.0], [20.0, 20.0]])
    g = surface_fill(_points(), 1000, cover_xy=cover)
    assert g[:, 0].min() < -18 and g[:, 0].max() > 18 and g[:, 1].min() < -18 and g[:, 1].max() > 18
    assert np.isfinite(g).all()
    # outside the sparse points' hull the height is the nearest point's (within the points' range)
    assert g[:, 2].min() >= 2 + 0.1 * -5 - 1e-9 and g[:, 2].max() <= 2 + 0.1 * 5 + 1e-9
    kept = surface_fill(_points(), 1000, cover_xy=cover, keep=lambda p: p[:, 0] > 0)
    assert (kept[:, 0] > 0).all() and kept.shape[0] >= 800  # about n_target nodes survive the filter


def _strategy_and_model(reset_every, refine_stop):
    m = init_from_points(_points(), np.full((40, 3), 0.2), 4, init_opacity=0.9)
    strategy = ADCStrategy(60_000, max_gaussians_per_px=0.0, width=8, height=8, extent_m=5.0,
                           cfg=ADCConfig(refine_start=10_000, refine_stop=refine_stop, reset_every=reset_every))
    return strategy, m, NamedAdam({}), DensifyState(m.n), torch.Generator().manual_seed(0)


def test_no_opacity_reset_in_the_last_quarter_of_a_phase():
    strategy, m, opt, state, gen = _strategy_and_model(reset_every=100, refine_stop=10_000)
    strategy.after_step(m, opt, state, 100, 100, gen)  # the last step of a 100-step phase
    assert float(m.opacities.detach().min()) > 0.8
    strategy.after_step(m, opt, state, 100, 1000, gen)  # early in a long phase: 3DGS opacity reset
    assert float(m.opacities.detach().max()) < 0.02


def test_the_options_choose_the_strategy_class_with_its_own_options():
    adc = make_strategy(TrainConfig(max_gaussians=500, max_gaussians_per_px=2.0), 10, 20, 3.0)
    assert isinstance(adc, ADCStrategy) and adc.cfg == ADCConfig() and adc.cap() == 400
    assert adc.regulariser(None) is None and not adc.absgrad
    assert make_strategy(TrainConfig(densify=ADCConfig(absgrad=True)), 10, 20, 3.0).absgrad
    mc = make_strategy(TrainConfig(strategy="mcmc", mcmc=MCMCConfig(growth=0.3)), 10, 20, 3.0)
    assert isinstance(mc, MCMCStrategy) and mc.cfg.growth == 0.3 and mc.cap() == 600
    m = init_from_points(_points(), np.full((40, 3), 0.2), 4, init_opacity=0.5)
    assert float(mc.regulariser(m)) > 0


def test_mcmc_strategy_relocates_and_grows_on_its_schedule():
    m = init_from_points(_points(), np.full((40, 3), 0.2), 4, init_opacity=0.5)
    with torch.no_grad():
        m.params["opacity_logits"][:5] = -20.0  # five dead Gaussians
    mc = MCMCStrategy(60, 0.0, 8, 8, 5.0, cfg=MCMCConfig(refine_start=0, refine_stop=100, refine_every=10, growth=0.25))
    opt, state, gen = NamedAdam({}), DensifyState(m.n), torch.Generator().manual_seed(0)
    mc.after_step(m, opt, state, 5, 100, gen)  # off the schedule: only noise
    assert m.n == 40
    mc.after_step(m, opt, state, 10, 100, gen)
    assert m.n == 50 and float(m.opacities.detach().min()) > 1e-6  # grown by 25 %, the dead relocated
    mc.after_step(m, opt, state, 20, 100, gen)
    assert m.n == 60  # the cap

