"""The presets of ``brfgs train`` and the additions beyond the published method.

Presets: ``fast`` (CPU, minutes for a 128-px scene: brfgs's method, every addition on),
``fine`` (``fast`` with supersampled pixels from half of stage 1 on and AbsGS's densification:
more accurate on 49-view scenes, 1.2-1.3x the training time on a CPU, and its models render
supersampled, ~1.6x the time per view; :data:`FINE`), ``paper`` (the published
method on a GPU-scale, 3DGS-like 30k-step schedule), ``paper-fast`` (the published method on the
``fast`` schedule: what the additions are measured against on a CPU), ``tiny`` (tests: a few
steps). :data:`ADDITIONS` names each choice beyond the paper with the option values that switch it
off (docs/method.md); ``brfgs ablate --study additions`` measures each one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from brfgs.errors import UserError
from brfgs.train.config import TrainConfig

__all__ = ["Addition", "ADDITIONS", "PAPER_METHOD", "PAPER_SCHEDULE", "FINE", "PRESETS", "preset", "with_options"]


@dataclass(frozen=True)
class Addition:
    """A choice of brfgs beyond the published method: ``paper`` = the option values of the paper's
    method (switching the addition off), ``stage`` = the first training stage it changes (1 or 2;
    a stage-2 addition can reuse another run's stage 1), ``reason`` = why brfgs adds it."""

    paper: dict
    stage: int
    reason: str


# Every addition beyond the paper (docs/method.md gives each one's paper section and measured effect).
ADDITIONS: dict[str, Addition] = {
    "stage1_cir_bands": Addition(dict(stage1_cir_bands=False), 1, "the EFC bands may all lie in one spectral region; "
                                 "the CIR bands carry the visible texture that stage-1 geometry should explain"),
    "depth_normal": Addition(dict(lambda_normal=0.0), 1, "turns each Gaussian's normal toward the rendered depth's "
                             "gradient (2DGS/GOF-style; normals only), for usable normal maps and specular normals"),
    "flatness": Addition(dict(lambda_flat=0.0), 1, "flattened Gaussians have a defined normal (the smallest axis) for "
                         "the Cook-Torrance kernel"),
    "depth_smoothness": Addition(dict(lambda_depth_smooth=0.0), 1, "edge-aware smoothness of the rendered inverse "
                                 "depth keeps water and flat ground as surfaces instead of floaters"),
    "fill_points": Addition(dict(init_fill_points=0), 1, "a 2.5-D surface through the sparse SfM points seeds Gaussians "
                            "where SfM finds few features (water, shadows)"),
    "learned_normals": Addition(dict(learn_normals=False, lambda_normal_smooth=0.0), 2, "the smallest axis of a "
                                "volumetric crown Gaussian is a poor shading normal for the specular kernel"),
    "lr_spec": Addition(dict(lr_spec=1e-2), 2, "a glint needs a specular latent ~10x the iso latent, seen in few "
                        "views: at the common latent rate it cannot grow in the steps available"),
    "centred_kernels": Addition(dict(centred_kernels=False), 2, "trains eq. 12 in a centred form (same function "
                                "class) because K_Li is about -1 everywhere, making z_iso and z_geo collinear"),
    "learned_background": Addition(dict(learn_background=False), 1, "pixels beyond the Gaussians (oblique views' far "
                                   "field) get a learned colour/latent instead of a fixed one"),
    "spectral_tv": Addition(dict(lambda_spectral_tv=0.0), 2, "the decoded spectrum of a dark pixel turns with a 1 % "
                            "change of its latent: fitted to noisy observations, water and shadow spectra scatter "
                            "from pixel to pixel; an edge-aware spectral-angle smoothness stops it"),
    "pixel_decode": Addition(dict(decode="gaussian"), 2, "blends latents and decodes each pixel, instead of decoding "
                             "each Gaussian and blending spectra (eq. 13): d instead of B channels rasterized"),
    "stage1_kernels": Addition(dict(stage1_kernels=False), 1, "the hotspot and the crowns' shadowing change a "
                               "surface's brightness with the view; with view-independent stage-1 colours only the "
                               "geometry can follow that, with eq. 12's kernels the colours can"),
    "dssim_per_band": Addition(dict(dssim_per_band=False), 1, "the grayscale band mean hides edges between "
                               "surfaces that differ in one band only (grass and soil in the NIR, red paint in "
                               "the red); the D-SSIM of each stage-1 band sees them, as 3DGS's per-channel SSIM"),
}


def with_options(cfg: "TrainConfig", changes: dict) -> "TrainConfig":
    """``cfg`` with ``changes`` (a ``densify`` or ``mcmc`` dict changes only the fields it names)."""
    changes = dict(changes)
    for key in ("densify", "mcmc"):
        if isinstance(changes.get(key), dict):
            changes[key] = replace(getattr(cfg, key), **changes[key])
    return replace(cfg, **changes)


# The published method: every addition off (paper sections 3.1-3.3).
PAPER_METHOD: dict = {k: v for a in ADDITIONS.values() for k, v in a.paper.items()}

# The paper's GPU-scale schedule (3DGS's 30k steps per stage, whole images, no Gaussian cap).
PAPER_SCHEDULE: dict = dict(ae_steps=5000, ae_batch=4096, ae_max_pixels=1_000_000, stage1_steps=30_000,
                            stage2_steps=30_000,
                            densify=dict(refine_start=500, refine_stop=15_000, refine_every=100, reset_every=3000),
                            max_gaussians=3_000_000, checkpoint_every=2000, patch_px=0, stage2_rays=0,
                            max_gaussians_per_px=0.0,
                            schedule_ref_views=0)

# ``fine``: each pixel the mean of 2 x 2 sub-pixel samples (from half of the geometry phase on) and
# AbsGS's densification gradient at 0.0004 (chosen on the validation views of six scenes; not the
# default because stage 1 rasterizes four times the pixels and each view renders supersampled).
FINE: dict = dict(supersample=2, supersample_start=0.5, densify=dict(absgrad=True, grow_grad2d=0.0004))

# Each preset: the options that differ from the dataclass defaults (``fast``: none).
PRESETS: dict[str, dict] = {
    "fast": {},
    "fine": dict(FINE),
    "paper": {**PAPER_SCHEDULE, **PAPER_METHOD},
    "paper-fast": dict(PAPER_METHOD),
    "tiny": dict(ae_steps=60, ae_batch=256, ae_max_pixels=5000, stage1_steps=30, stage2_steps=30, latent_dim=4,
                 init_fill_points=500,
                 densify=dict(refine_start=10, refine_stop=25, refine_every=10, reset_every=1000), max_gaussians=5000,
                 checkpoint_every=10, log_every=1, backend="torch", schedule_ref_views=0),
}


def preset(name: str, **overrides) -> TrainConfig:
    """A :class:`TrainConfig` from a named preset with keyword overrides (``densify`` may be a
    dict of the fields to change)."""
    if name not in PRESETS:
        raise UserError(f"unknown preset {name!r}; choose {', '.join(PRESETS)}", field="preset")
    cfg = TrainConfig(preset=name)
    for changes in (PRESETS[name], overrides):
        cfg = with_options(cfg, changes)
    return cfg.validate()
