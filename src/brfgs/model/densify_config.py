"""Options of the densification strategies (:mod:`brfgs.train.strategy`): one dataclass per
strategy, each with its own fields; no heavy imports, so that the command line can build its
options from them quickly.

- :class:`ADCConfig` — 3DGS adaptive density control (clone, split, prune, opacity resets;
  :mod:`brfgs.model.densify`), options ``--densify-<field>``;
- :class:`MCMCConfig` — 3DGS-MCMC (relocation, growth, exploration noise, L1 priors;
  :mod:`brfgs.model.mcmc`), options ``--mcmc-<field>``.

The cap on the number of Gaussians is shared (``TrainConfig.max_gaussians`` and
``max_gaussians_per_px``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

STRATEGIES = ("adc", "mcmc")


def _f(default, help: str):
    return field(default=default, metadata={"help": help, "expert": True})


@dataclass
class ADCConfig:
    """3DGS adaptive density control (Kerbl et al. 2023; gsplat's DefaultStrategy)."""

    refine_start: int = _f(300, "First step that may clone, split or prune.")
    refine_stop: int = _f(2500, "Last step that may clone, split or prune (at most 3/4 of the phase).")
    refine_every: int = _f(100, "Steps between refinements.")
    reset_every: int = _f(1500, "Steps between opacity resets (0 = never).")
    grow_grad2d: float = _f(0.0002, "Mean screen-space gradient (NDC) that grows a Gaussian.")
    absgrad: bool = _f(False, "Grow by AbsGS's gradient: per-pixel gradients summed in absolute value.")
    grow_scale3d: float = _f(0.01, "Clone below, split above this largest scale (x scene extent).")
    prune_opacity: float = _f(0.005, "Prune Gaussians below this opacity.")
    prune_scale3d: float = _f(0.1, "Prune Gaussians larger than this (x scene extent) after an opacity reset.")


@dataclass
class MCMCConfig:
    """3DGS as Markov-chain Monte Carlo (Kheradmand et al. 2024; gsplat's MCMCStrategy)."""

    refine_start: int = _f(300, "First step that relocates and grows.")
    refine_stop: int = _f(2500, "Last step that relocates and grows (at most 3/4 of the phase).")
    refine_every: int = _f(100, "Steps between relocations.")
    growth: float = _f(0.05, "Fraction more Gaussians per refinement (up to the cap).")
    noise_lr: float = _f(5e5, "Scale of the exploration noise on nearly transparent Gaussians.")
    opacity_reg: float = _f(0.01, "Weight of the L1 opacity prior.")
    scale_reg: float = _f(0.01, "Weight of the L1 scale prior (scales / scene extent).")
    min_opacity: float = _f(0.005, "Gaussians below this opacity are dead and relocated.")
