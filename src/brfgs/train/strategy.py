"""Densification as a strategy with hooks (the idea of gsplat's ``DefaultStrategy``).

The trainer calls :meth:`DensifyStrategy.before_backward` (keep the screen-space gradient),
:meth:`DensifyStrategy.after_backward` (accumulate it) and :meth:`DensifyStrategy.after_step`
(clone/split/prune every ``refine_every`` steps, reset opacities every ``reset_every``) in the
phases that train geometry. The row edits themselves are :mod:`brfgs.model.densify`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from brfgs.model import DensifyConfig, DensifyState, GaussianModel, NamedAdam, refine, reset_opacity
from brfgs.model.densify import accumulate
from brfgs.model.mcmc import add_gaussians, perturb_means, relocate_dead
from brfgs.render import RenderOutput


@dataclass
class DensifyStrategy:
    """3DGS adaptive density control for one run.

    cfg: thresholds and schedule (:class:`brfgs.model.DensifyConfig`).
    max_gaussians_per_px: cap at this many Gaussians per image pixel (0 = cfg.max_gaussians only).
    width, height: size of a full training image (px).
    extent_m: scene extent (m) that the size thresholds are relative to.
    Densification stops at 3/4 of the phase at the latest (3DGS: 15k of 30k steps) and no
    opacity reset happens after that: a late reset leaves the frozen stage-2 geometry nearly
    transparent.
    """

    cfg: DensifyConfig
    max_gaussians_per_px: float
    width: int
    height: int
    extent_m: float

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
                   self.cfg.absgrad)

    def after_step(self, model: GaussianModel, opt: NamedAdam, state: DensifyState, step: int, steps: int,
                   gen: torch.Generator) -> None:
        """Refine (clone, split, prune) or reset opacities when the schedule says so; in mode
        "mcmc", relocate and grow instead, and add the exploration noise every step."""
        d = self.cfg
        stop = min(d.refine_stop, int(0.75 * steps))
        refine_now = d.refine_start < step <= stop and step % d.refine_every == 0
        if d.mode == "mcmc":
            if refine_now:
                relocate_dead(model, opt, d.prune_opacity, gen)
                add_gaussians(model, opt, min(self.cap(), int((1 + d.mcmc_growth) * model.n)) - model.n, gen)
                state.grad2d, state.count = torch.zeros(model.n), torch.zeros(model.n)
            if step < stop:
                perturb_means(model, opt.lrs.get("means", 0.0), self.extent_m, d.mcmc_noise_lr, gen)
            return
        if refine_now:
            refine(model, opt, state, replace(d, max_gaussians=self.cap()), self.extent_m, gen)
        if d.reset_every > 0 and step % d.reset_every == 0 and step < stop:
            reset_opacity(model, opt, state, d)

    def cap(self) -> int:
        """The most Gaussians allowed: max_gaussians, or fewer by the per-pixel cap."""
        cap = self.cfg.max_gaussians
        if self.max_gaussians_per_px > 0:
            cap = min(cap, int(self.max_gaussians_per_px * self.width * self.height))
        return cap
