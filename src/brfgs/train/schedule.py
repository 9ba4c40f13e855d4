"""Learning rates per phase and step (Adam over named tensors, brfgs.model.optim.NamedAdam)."""

from __future__ import annotations

import math

from brfgs.train.config import TrainConfig
from brfgs.train.phases import Phase

LATENT_KEYS = ("z_iso", "z_vol", "z_geo", "sh", "feat")


def means_lr(cfg: TrainConfig, step: int, steps: int, extent_m: float) -> float:
    """Learning rate of the means: log-linear from lr_means to lr_means_final over the phase,
    times the scene extent in metres (3DGS)."""
    frac = step / max(steps, 1)
    return math.exp((1 - frac) * math.log(cfg.lr_means * extent_m) + frac * math.log(cfg.lr_means_final * extent_m))


def head_lr_decay(cfg: TrainConfig, step: int, steps: int) -> float:
    """Factor on the head's learning rates at ``step`` of a phase of ``steps``: 1 until
    ``cfg.head_lr_decay_from`` of the phase, then log-linear to ``cfg.lr_head_final`` at its end (1
    throughout when that is 1)."""
    start = cfg.head_lr_decay_from
    frac = min(max((step / max(steps, 1) - start) / (1.0 - start), 0.0), 1.0)
    return math.exp(frac * math.log(cfg.lr_head_final))


def learning_rates(cfg: TrainConfig, phase: Phase, step: int, steps: int, extent_m: float,
                   neural_names=(), decoder_names=()) -> dict[str, float]:
    """{tensor name: learning rate} of every tensor the phase optimises (absent = frozen).

    ``neural_names`` / ``decoder_names``: parameter names of the neural head / the decoder.
    """
    c = cfg
    lrs: dict[str, float] = {}
    if phase.trains_geometry:
        lrs.update({"means": means_lr(c, step, steps, extent_m), "log_scales": c.lr_scales, "quats": c.lr_quats,
                    "opacity_logits": c.lr_opacity})
    if phase == Phase.STAGE1:  # the kernel terms at a twentieth, as 3DGS's SH rest terms
        lrs.update({"colors": c.lr_colors, "colors_kernels": c.lr_colors / 20.0,
                    "bg_colors": c.lr_background})
    if phase.fits_head:  # the head's rates, all scaled by the decay of the phase
        head = {k: c.lr_latent for k in LATENT_KEYS}
        head.update({"z_spec": c.lr_spec, "rho_raw": c.lr_rho, "normals": c.lr_normals, "bg_latent": c.lr_background,
                     "log_irradiance": c.lr_irradiance})
        head.update({"neural." + k: c.lr_neural for k in neural_names})
        if c.finetune_decoder:
            head.update({"decoder." + k: c.lr_decoder for k in decoder_names})
        decay = head_lr_decay(c, step, steps)
        lrs.update({k: v * decay for k, v in head.items()})
    if phase == Phase.CIR:
        lrs.update({"sh": c.lr_colors, "bg_colors": c.lr_background})
    if not c.learn_background:  # fixed at its initial value (the training images' mean)
        lrs.pop("bg_colors", None)
        lrs.pop("bg_latent", None)
    return lrs
