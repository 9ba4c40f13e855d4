"""Training phases (paper section 3.3) and which phases do what.

- ``STAGE1`` (eq. 24): geometry μ, Σ, o and per-Gaussian reflectance of the stage-1 bands,
  (1 − α) L1 + α D-SSIM, with 3DGS densification.
- ``STAGE2`` (eqs. 25–27): geometry frozen; the appearance head (hybrid kernels, SH, neural)
  in the autoencoder's latent space is rendered, decoded and fitted on all bands with
  (1 − β) L_refl + β L_cos.
- ``JOINT`` (Table 4 ablation): everything at once, stage-2 loss plus α D-SSIM on the stage-1
  bands, densification as in stage 1.
- ``CIR`` (3DGS baseline): SH degree 3 on CIR composites, L1 + D-SSIM, one phase.
- ``DONE``: training finished.
"""

from __future__ import annotations

from enum import Enum


class Phase(str, Enum):
    """A training phase; the value is what checkpoints, logs and run.json record."""

    STAGE1 = "stage1"
    STAGE2 = "stage2"
    JOINT = "joint"
    CIR = "cir"
    DONE = "done"

    @property
    def trains_geometry(self) -> bool:
        """μ, Σ and opacity are optimised in this phase (densified too where :attr:`grows`)."""
        return self in (Phase.STAGE1, Phase.JOINT, Phase.CIR)

    @property
    def grows(self) -> bool:
        """The geometry is densified in this phase (every phase that trains it)."""
        return self in (Phase.STAGE1, Phase.JOINT, Phase.CIR)

    @property
    def fits_head(self) -> bool:
        """The spectral appearance head is optimised in this phase."""
        return self in (Phase.STAGE2, Phase.JOINT)

    @property
    def renders_colors(self) -> bool:
        """Per-Gaussian colours (stage-1 bands or CIR) are rendered, not the latent head."""
        return self in (Phase.STAGE1, Phase.CIR)


def plan(variant: str, joint: bool, stage1_steps: int, stage2_steps: int) -> list[tuple[Phase, int]]:
    """The phases of a run and their step counts."""
    if variant == "cir":
        return [(Phase.CIR, stage1_steps + stage2_steps)]
    if joint:
        return [(Phase.JOINT, stage1_steps + stage2_steps)]
    return [(Phase.STAGE1, stage1_steps), (Phase.STAGE2, stage2_steps)]


def run_plan(cfg) -> list[tuple[Phase, int]]:
    """:func:`plan` of a run's options ``cfg`` (a :class:`brfgs.train.config.TrainConfig`)."""
    return plan(cfg.variant, cfg.joint, cfg.stage1_steps, cfg.stage2_steps)


def next_phase(phases: list[tuple[Phase, int]], phase: Phase) -> Phase:
    """The phase after ``phase`` (DONE after the last)."""
    names = [p for p, _ in phases]
    k = names.index(phase) + 1
    return names[k] if k < len(names) else Phase.DONE
