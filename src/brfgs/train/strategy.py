"""Densification strategies with hooks, one class per strategy (the idea of gsplat's
``DefaultStrategy`` and ``MCMCStrategy``).

The trainer builds the strategy the options choose (:func:`make_strategy`) and calls its
:meth:`before_backward` (keep the screen-space gradient), :meth:`after_backward` (accumulate it)
and :meth:`after_step` (edit the Gaussians on the strategy's schedule) in the phases that train
geometry. The row edits themselves are :mod:`brfgs.model.densify` and :mod:`brfgs.model.mcmc`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from brfgs.model import DensifyState, GaussianModel, NamedAdam, refine, reset_opacity
from brfgs.model.densify import accumulate
from brfgs.model.densify_config import ADCConfig, MCMCConfig
from brfgs.model.mcmc import add_gaussians, mcmc_regulariser, perturb_means, relocate_dead
from brfgs.render import RenderOutput
from brfgs.train.config import auto_max_gaussians


@dataclass
class _Strategy:
    """What both strategies share: the cap on the number of Gaussians and the gradient hooks.

    max_gaussians: never more Gaussians than this (0: follow the image); max_gaussians_per_px: nor more than this many per
    pixel of a training image (0 = no such cap); width, height: a full training image (px);
    extent_m: the scene extent (m) that the size thresholds are relative to.
    """

    max_gaussians: int
    max_gaussians_per_px: float
    width: int
    height: int
    extent_m: float

    def cap(self) -> int:
        """The most Gaussians allowed: max_gaussians (0: the cap that follows the image,
        :func:`~brfgs.train.config.auto_max_gaussians`), or fewer by the per-pixel cap."""
        cap = self.max_gaussians or auto_max_gaussians(self.width, self.height)
        if self.max_gaussians_per_px > 0:
            cap = min(cap, int(self.max_gaussians_per_px * self.width * self.height))
        return cap

    def before_backward(self, out: RenderOutput) -> None:
        """Keep the gradient of the projected means (the densification signal)."""
        means2d = out.meta.get("means2d")
        if means2d is not None and means2d.requires_grad and not means2d.is_leaf:
            means2d.retain_grad()

    def after_backward(self, state: DensifyState, out: RenderOutput, width: int, height: int,
                       grad_scale: float = 1.0) -> None:
        """Accumulate the screen-space gradient norms of the visible Gaussians (``grad_scale``: the
        number of views whose mean loss was backpropagated, so that each view counts as one, as
        gsplat's strategy does for batches of cameras). A supersampled render's means2d are in
        sub-pixels (``meta["supersample"]``), so its grid is that many times wider and taller."""
        ss = int(out.meta.get("supersample", 1))
        accumulate(state, out.meta.get("means2d"), out.meta["visible"], width * ss, height * ss, grad_scale,
                   self.absgrad)

    @property
    def absgrad(self) -> bool:
        """Whether the rasterizer should compute AbsGS's gradient for this strategy."""
        return False

    def regulariser(self, model: GaussianModel) -> torch.Tensor | None:
        """The strategy's own loss term on the Gaussians (None: none)."""
        return None

    def _stop(self, refine_stop: int, steps: int) -> int:
        # densification stops at 3/4 of the phase at the latest (3DGS: 15k of 30k steps)
        return min(refine_stop, int(0.75 * steps))


@dataclass
class ADCStrategy(_Strategy):
    """3DGS adaptive density control: clone, split and prune every ``refine_every`` steps, reset the
    opacities every ``reset_every``. No reset after the last refinement: a late reset leaves the
    frozen stage-2 geometry nearly transparent."""

    cfg: ADCConfig = None

    @property
    def absgrad(self) -> bool:
        return self.cfg.absgrad

    def after_step(self, model: GaussianModel, opt: NamedAdam, state: DensifyState, step: int, steps: int,
                   gen: torch.Generator) -> None:
        d = self.cfg
        stop = self._stop(d.refine_stop, steps)
        if d.refine_start < step <= stop and step % d.refine_every == 0:
            refine(model, opt, state, d, self.extent_m, gen, self.cap())
        if d.reset_every > 0 and step % d.reset_every == 0 and step < stop:
            reset_opacity(model, opt, state, d)


@dataclass
class MCMCStrategy(_Strategy):
    """3DGS-MCMC: relocate dead Gaussians and grow by ``growth`` every ``refine_every`` steps, add the
    exploration noise every step until the last refinement, and the L1 opacity and scale priors."""

    cfg: MCMCConfig = None

    def after_step(self, model: GaussianModel, opt: NamedAdam, state: DensifyState, step: int, steps: int,
                   gen: torch.Generator) -> None:
        d = self.cfg
        stop = self._stop(d.refine_stop, steps)
        if d.refine_start < step <= stop and step % d.refine_every == 0:
            relocate_dead(model, opt, d.min_opacity, gen)
            add_gaussians(model, opt, min(self.cap(), int((1 + d.growth) * model.n)) - model.n, gen)
            state.grad2d, state.count = torch.zeros(model.n), torch.zeros(model.n)
        if step < stop:
            perturb_means(model, opt.lrs.get("means", 0.0), self.extent_m, d.noise_lr, gen)

    def regulariser(self, model: GaussianModel) -> torch.Tensor:
        return mcmc_regulariser(model, self.cfg.opacity_reg, self.cfg.scale_reg, self.extent_m)


def make_strategy(cfg, width: int, height: int, extent_m: float) -> ADCStrategy | MCMCStrategy:
    """The densification strategy ``cfg.strategy`` chooses (``cfg``: a TrainConfig), with its options."""
    cls, sub = (MCMCStrategy, cfg.mcmc) if cfg.strategy == "mcmc" else (ADCStrategy, cfg.densify)
    return cls(cfg.max_gaussians, cfg.max_gaussians_per_px, width, height, extent_m, cfg=sub)
