"""Options as brfgs 0.1 wrote them (config.json, checkpoints and model files of format 1) read by
today's :class:`brfgs.train.config.TrainConfig` (format 2).

Format 1 had no ``format_version`` key, kept the densification options in one ``densify`` block
with a ``mode`` string, and had options that measured no gain and were removed. :func:`upgrade`
converts such a dict: an option the file predates takes the value it had before the option existed
(:data:`BEFORE_OPTION`), a removed option at its neutral value is dropped, and a removed option that
was switched on is refused (the run cannot be reproduced by this version).
"""

from __future__ import annotations

from brfgs.errors import UserError

# Options whose default changed after they were added: a file written before the option existed
# trained with the value here.
BEFORE_OPTION: dict = {"stage1_kernels": False, "dssim_per_band": False, "lr_head_final": 1.0,
                       "head_lr_decay_from": 0.0, "spectral_basis": "autoencoder"}

# Removed options and the value at which they changed nothing (what format-1 files of today's method
# hold); ``None``: any value (the option only mattered together with another removed one).
REMOVED: dict = {"far_field_plane": False, "filter_3d": False, "lambda_sparse_depth": 0.0, "lambda_multiview": 0.0,
                 "spec_shrink": 0.0, "wd_spec": 0.0, "normal_edge_rel": 0.0, "normal_prior_moves_depth": False,
                 "normal_prior_per_gaussian": True, "coarse_levels": 0, "coarse_until": None, "refine_steps": 0,
                 "refine_lr_scale": None, "stage1_sh_degree": 0, "lambda_depth_conc": 0.0, "lambda_alpha": 0.0,
                 "patch_rays": 0, "split_rule": "spread"}
# What a format-1 file without the key trained with (the option did not exist yet; a partial file of
# options, written by hand, takes the neutral values).
REMOVED_BEFORE: dict = {"normal_prior_moves_depth": True, "normal_prior_per_gaussian": False, "split_rule": "random",
                        "patch_rays": 2048}

ADC_KEYS = ("refine_start", "refine_stop", "refine_every", "reset_every", "grow_grad2d", "absgrad", "grow_scale3d",
            "prune_opacity", "prune_scale3d")
MCMC_KEYS = {"growth": "mcmc_growth", "noise_lr": "mcmc_noise_lr", "opacity_reg": "mcmc_opacity_reg",
             "scale_reg": "mcmc_scale_reg", "min_opacity": "prune_opacity"}


def upgrade(written: dict, source: str | None = None) -> dict:
    """``written`` (options of any format) as a format-2 dict for ``TrainConfig.from_dict``."""
    if "format_version" in written:
        return dict(written)
    d = {**BEFORE_OPTION, **written}
    if "patch_rays" not in d and "stage2_rays" in written:  # one option sized both before patch_rays existed
        d["patch_rays"] = written["stage2_rays"]
    full = any(k in written for k in REMOVED)  # a file brfgs 0.1 wrote (it listed every option), not a partial one
    for key, neutral in REMOVED.items():
        value = d.pop(key, REMOVED_BEFORE.get(key, neutral) if full else neutral)
        if neutral is None or value == neutral or _irrelevant(key, d):
            continue
        raise UserError(f"trained with {key} = {value!r}, which this version of brfgs no longer has (use brfgs 0.1 "
                        "to continue or reproduce this run)", file=source, field=key)
    if isinstance(d.get("densify"), dict):
        d.update(_strategy_options(d.pop("densify")))
    return d


def _irrelevant(key: str, d: dict) -> bool:
    """Whether removed option ``key`` did not act in the run ``d`` (patch_rays sized only the joint
    phase and stage 2 with decode order "gaussian")."""
    return key == "patch_rays" and not d.get("joint", False) and d.get("decode", "pixel") == "pixel"


def _strategy_options(old: dict) -> dict:
    """strategy, max_gaussians and the chosen strategy's options of a format-1 ``densify`` block (the
    other strategy keeps its defaults: its options did not act)."""
    out: dict = {"strategy": old.get("mode", "adc")}
    if out["strategy"] == "mcmc":
        mcmc = {k: old[src] for k, src in MCMC_KEYS.items() if src in old}
        mcmc.update({k: old[k] for k in ("refine_start", "refine_stop", "refine_every") if k in old})
        out["mcmc"] = mcmc
    else:
        out["densify"] = {k: old[k] for k in ADC_KEYS if k in old}
    if "max_gaussians" in old:
        out["max_gaussians"] = old["max_gaussians"]
    return out
