"""Options of the adaptive density control (:mod:`brfgs.model.densify`); no heavy imports, so that
the command line can build its options from them quickly."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class DensifyConfig:
    """Adaptive density control (see the module docstring); every field is a ``brfgs train``
    option ``--densify-<field>``."""

    refine_start: int = field(default=300, metadata={"help": "First step that may clone, split or prune."})
    refine_stop: int = field(default=2500, metadata={"help": "Last step that may (at most 3/4 of the phase)."})
    refine_every: int = field(default=100, metadata={"help": "Steps between refinements."})
    reset_every: int = field(default=1500, metadata={"help": "Steps between opacity resets (0 = never)."})
    grow_grad2d: float = field(default=0.0002, metadata={"help": "Mean screen-space gradient (NDC) that grows a Gaussian."})
    absgrad: bool = field(default=False, metadata={"help": "Grow by AbsGS's gradient (Ye et al. 2024): per-pixel gradients "
                                                          "summed in absolute value, so opposite pulls do not cancel "
                                                          "(gsplat: absgrad=True, with grow_grad2d 0.0008). A candidate; "
                                                          "--preset fine: with --supersample 2, 0.0004."})
    grow_scale3d: float = field(default=0.01, metadata={"help": "Clone below, split above this largest scale (x scene extent)."})
    prune_opacity: float = field(default=0.005, metadata={"help": "Prune Gaussians below this opacity."})
    prune_scale3d: float = field(default=0.1, metadata={"help": "Prune Gaussians larger than this (x scene extent) after a reset."})
    mode: str = field(default="adc", metadata={"help": "adc: 3DGS adaptive density control (clone, split, prune, "
                                                    "opacity resets); mcmc: 3DGS-MCMC (relocate dead Gaussians, "
                                                    "grow by mcmc_growth, noise, L1 priors; brfgs.model.mcmc)."})
    mcmc_growth: float = field(default=0.05, metadata={"help": "mcmc: fraction more Gaussians per refinement (up to the cap)."})
    mcmc_noise_lr: float = field(default=5e5, metadata={"help": "mcmc: scale of the exploration noise (paper: 5e5)."})
    mcmc_opacity_reg: float = field(default=0.01, metadata={"help": "mcmc: weight of the L1 opacity prior."})
    mcmc_scale_reg: float = field(default=0.01, metadata={"help": "mcmc: weight of the L1 scale prior (scales / extent)."})
    max_gaussians: int = field(default=60_000, metadata={"help": "Never grow beyond this many Gaussians."})
