"""Training options: one dataclass, :class:`TrainConfig` (the CLI's options are generated from it).

The named presets (``fast``, ``fine``, ``paper``, ``paper-fast``, ``tiny``) and the additions beyond
the published method (``ADDITIONS``) are in :mod:`brfgs.train.presets`.
"""

from __future__ import annotations

import json
import math
import typing
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from brfgs.data.splits import DEFAULT_SPLIT_RULE, SPLIT_RULE_BEFORE, SPLIT_RULES
from brfgs.errors import UserError
from brfgs.model.densify_config import DensifyConfig

VARIANTS = ("brf", "sh", "neural", "cir")
DECODE_ORDERS = ("pixel", "gaussian")
INIT_FILLS = ("surface", "mvs")
MAX_COARSE_LEVELS = 4  # --coarse-levels: the first blur is at most 16 x 16 pixels
MAX_SUPERSAMPLE = 4  # --supersample: at most 4 x 4 sub-pixel samples per pixel (brfgs.render.supersample)


# Options whose default changed after they were added: a run folder's config.json written before the
# option existed trained with the value here (brfgs.train.run_folder compares a resumed run with it).
BEFORE_OPTION: dict = {"normal_prior_moves_depth": True, "normal_prior_per_gaussian": False,
                       "split_rule": SPLIT_RULE_BEFORE, "stage1_kernels": False, "dssim_per_band": False,
                       "lr_head_final": 1.0, "head_lr_decay_from": 0.0, "patch_rays": 2048}
# Options that an older run folder set through another one: it reads back with that one's value.
BEFORE_OPTION_FROM: dict = {"patch_rays": "stage2_rays"}  # one option sized both before Session 37


def _opt(default, help: str, flag: str | None = None):
    """A dataclass field with its command-line help (and an explicit flag, e.g. "--joint/--decoupled")."""
    meta = {"help": help} if flag is None else {"help": help, "flag": flag}
    if isinstance(default, (list, dict, DensifyConfig)):
        return field(default_factory=lambda: replace(default) if isinstance(default, DensifyConfig) else default,
                     metadata=meta)
    return field(default=default, metadata=meta)


@dataclass
class TrainConfig:
    """Every option of ``brfgs train`` (stored in run folders and checkpoints as config.json).

    Each field's help is its ``--option`` help (``brfgs train --help``), generated from this class:
    the command line never lists the options by hand. The choices beyond the paper are
    :data:`brfgs.train.presets.ADDITIONS` (each switchable, its reason and measured effect in docs/method.md).
    """

    preset: str = _opt("fast", "Preset the other defaults come from: fast (CPU minutes, every addition on), fine (fast "
                       "with --supersample 2 from half of stage 1 and --densify-absgrad: +0.1-0.9 dB on the 49-view "
                       "scenes, 1.2-1.3x the training time and its views ~1.6x the render time on a CPU), paper (the "
                       "published method, GPU-scale schedule), paper-fast (the published method, fast schedule), "
                       "tiny (tests).")
    variant: str = _opt("brf", "brf (BRF-GS, hybrid kernels), sh (SH-3 in latent space), neural (MS-Splatting-style "
                        "feature + view direction -> MLP), cir (3DGS with SH-3 on CIR composites, no spectra).")
    components: tuple[str, ...] = _opt(("iso", "vol", "geo", "spec"), "Hybrid kernel terms of brf, e.g. iso,vol,geo,spec "
                                       "(Table 3 ablations).")
    joint: bool = _opt(False, "Train geometry and reflectance at once on all bands (Table 4 ablation).", "--joint/--decoupled")
    band_strategy: str = _opt("efc-top3", "Band selection for initialisation (SfM) and stage 1 (brfgs select-bands).")
    top: int = _opt(3, "Number of bands the strategy selects.")
    stage1_cir_bands: bool = _opt(True, "Stage 1 also fits the CIR bands (green, red, NIR), which carry the visible "
                                  "texture (not in the paper, which fits the selected bands only).",
                                  "--stage1-cir-bands/--stage1-selected-bands-only")
    poses: str = _opt("auto", "Camera poses: known | sfm | auto (brfgs init).")
    downscale: int = _opt(1, "Integer area-average factor applied when reading cubes.")
    allow_outside_links: bool = _opt(False, "Read files that links in the scene folder lead to outside it (refused "
                                     "by default).", "--allow-outside-links/--confine-to-scene")
    value_range: tuple[float, float] = _opt((-0.5, 10.0), "Plausible reflectance range LO,HI of the cubes: a frame with "
                                                    "more than 5 % of its pixels above it or 1 % below is refused.")
    latent_dim: int = _opt(16, "Latent size d of the spectral autoencoder (<= 32).")
    ae_steps: int = _opt(2400, "Adam steps of the autoencoder (2400 halves 800's spectral angle, S4; 9600 lowers "
                               "the decoder's floor but not the model's SAM, S44; docs/results.md).")
    ae_batch: int = _opt(1024, "Autoencoder batch size (pixels).")
    ae_max_pixels: int = _opt(100_000, "Training pixels sampled for the autoencoder.")
    stage1_steps: int = _opt(3000, "Stage-1 (geometry) steps; joint and cir use stage1_steps + stage2_steps.")
    stage2_steps: int = _opt(750, "Stage-2 (BRDF) steps (for 17 training views: see --schedule-ref-views).")
    refine_steps: int = _opt(0, "Stage-3 steps after stage 2 (for 17 training views, scaled as stage 2): geometry and "
                             "the appearance head refined together on all bands, no densification (0 = off; not in "
                             "the paper; measured worse on the forest, docs/method.md).")
    refine_lr_scale: float = _opt(1.0, "Geometry learning rates of the refinement, as a multiple of those stage 1 "
                                  "ended with.")
    alpha_dssim: float = _opt(0.2, "alpha of eq. 24 (weight of D-SSIM).")
    dssim_per_band: bool = _opt(True, "D-SSIM of eq. 24 as the mean over the stage-1 bands, each scaled by its "
                                "maximum (3DGS's per-channel SSIM; not in the paper), or on the grayscale band mean "
                                "(--dssim-grayscale: the paper).", "--dssim-per-band/--dssim-grayscale")
    beta_cos: float = _opt(0.5, "beta of eq. 25 (weight of the cosine loss).")
    lambda_normal: float = _opt(0.05, "Weight of the depth-normal consistency loss while geometry trains (0 = off; "
                                "not in the paper).")
    normal_edge_rel: float = _opt(0.0, "Edge-aware depth-normal loss (PGSR): a pixel's weight is exp(-c / (E * mean)), c "
                                  "its largest contrast to a neighbour in the 3x3-mean observed image, E this value; "
                                  "a weighted mean, so the prior moves off edges at the same strength (0 = off).")
    normal_prior_moves_depth: bool = _opt(False, "Let the depth-normal loss move the rendered depth as well as the "
                                          "Gaussians' normals (2DGS; before Session 26), or only turn the normals "
                                          "toward the depth's normal (default: it no longer lifts the ground toward "
                                          "crowns).", "--normal-prior-moves-depth/--normal-prior-normals-only")
    normal_prior_per_gaussian: bool = _opt(True, "Depth-normal loss in 2DGS's per-Gaussian form, sum_k w_k (1 - n_k . "
                                           "n_d): each Gaussian on a ray is turned in proportion to its blending "
                                           "weight, so a minority of tilted discs in a stack is not hidden in the "
                                           "ray's blended, renormalised normal (--normal-prior-blended, before "
                                           "Session 27). Grass and soil normal maps 30-50 % closer to the truth, "
                                           "images +0.07 dB (docs/method.md).",
                                           "--normal-prior-per-gaussian/--normal-prior-blended")
    normal_start: float = _opt(0.3, "Fraction of a geometry phase after which the surface priors start.")
    lambda_flat: float = _opt(0.01, "Weight of the flatness loss (smallest/largest scale) while geometry trains (0 = off).")
    lambda_depth_conc: float = _opt(0.0, "Weight of the ray-wise depth concentration loss (2DGS-style surface prior; "
                                    "sharper depth maps, lower PSNR; 0 = off).")
    lambda_alpha: float = _opt(0.0, "Weight of the coverage prior mean(1 - alpha) while geometry trains: every pixel of "
                               "a UAV image sees the ground, so the Gaussians should cover it (no learned background "
                               "showing through semi-transparent ground; 0 = off).")
    lambda_depth_smooth: float = _opt(50.0, "Weight of the edge-aware second-order smoothness of the rendered inverse "
                                      "depth while geometry trains (0 = off).")
    lambda_sparse_depth: float = _opt(0.0, "Weight of the sparse-depth loss while geometry trains: the rendered depth "
                                      "at each sparse SfM point a training view observed, against the point's depth "
                                      "(relative L1; DS-NeRF-style; 0 = off).")
    lambda_dense_depth: float = _opt(0.0, "Weight of the dense-depth loss while geometry trains: the rendered depth "
                                     "against each training view's stereo depth map where stereo kept one (relative "
                                     "L1; needs --init-fill mvs; 0 = off).")
    lambda_multiview: float = _opt(0.0, "Weight of the multi-view photometric consistency loss while geometry "
                                   "trains: patches carried into two neighbouring training views by the rendered "
                                   "depth and normal must match their observed images (1 - NCC; PGSR-style; 0 = off).")
    learn_normals: bool = _opt(True, "Learn per-Gaussian shading normals in stage 2, or use the smallest axis (paper).",
                               "--learn-normals/--geometric-normals")
    lambda_normal_smooth: float = _opt(0.1, "Weight of the stage-2 smoothness loss of the learned normals over 8 "
                                       "neighbours (0 = off).")
    lambda_spectral_tv: float = _opt(0.1, "Weight of the stage-2 edge-aware spectral-angle smoothness between "
                                     "neighbouring rendered pixels: keeps dark, uniform surfaces (water, shadow) "
                                     "from fitting the noise of their observations (brightness is free; 0 = off).")
    stage1_sh_degree: int = _opt(0, "View dependence of the stage-1 colours: SH degree 0 (none, as the paper) to 3 "
                                 "(as 3DGS; measured worse on validation views, docs/method.md).")
    stage1_kernels: bool = _opt(True, "Stage-1 colours with the view dependence of eq. 12's volumetric and geometric "
                                "kernels, c_iso + c_vol K_Ross + c_geo K_Li per stage-1 band (an addition: +0.20 dB on the "
                                "validation views of the five 49-view scenes, two seeds, no scene worse). "
                                "--stage1-flat-colours: view-independent, as the paper (docs/method.md).",
                                "--stage1-kernels/--stage1-flat-colours")
    lr_normals: float = _opt(2e-3, "Adam learning rate of the learned shading normals.")
    lr_means: float = _opt(1.6e-4, "Initial learning rate of the means (x scene extent in m).")
    lr_means_final: float = _opt(1.6e-6, "Final learning rate of the means (x scene extent in m).")
    lr_scales: float = _opt(5e-3, "Learning rate of the log-scales.")
    lr_quats: float = _opt(1e-3, "Learning rate of the rotations.")
    lr_opacity: float = _opt(5e-2, "Learning rate of the opacity logits.")
    lr_colors: float = _opt(5e-3, "Learning rate of the stage-1 colours (SH rest terms: /20) and the CIR SH.")
    lr_latent: float = _opt(1e-2, "Learning rate of the latent kernel weights (z_iso, z_vol, z_geo), SH and features.")
    lr_spec: float = _opt(0.2, "Learning rate of the specular latent z_spec (20x lr_latent: a glint needs a latent an "
                          "order of magnitude larger, seen in few views; docs/results.md, Session 4).")
    wd_spec: float = _opt(0.0, "Decoupled weight decay of z_spec (AdamW: z_spec x (1 - lr_spec x wd_spec) per "
                          "step): a specular latent that no glint holds up decays towards 0 instead of drifting "
                          "at the high specular rate (0 = off).")
    spec_shrink: float = _opt(0.0, "Soft threshold of z_spec after each step, in units of lr_spec (the proximal step "
                              "of an L1 penalty): a specular latent grows only where its Adam steps keep one "
                              "direction, as at a glint, and does not drift elsewhere (0 = off).")
    lr_head_final: float = _opt(0.1, "The appearance head's learning rates at the end of a phase that fits it (stage "
                                "2, joint), as a multiple of their starting rates: log-linear from --head-lr-decay-"
                                "from of the phase on, as 3DGS decays its means' rate (1 = constant, before Session 38).")
    head_lr_decay_from: float = _opt(0.75, "Fraction of that phase after which the head's rates decay (0 = from its "
                                     "first step).")
    lr_rho: float = _opt(1e-2, "Learning rate of the roughness.")
    lr_neural: float = _opt(2e-3, "Learning rate of the neural head's MLP.")
    lr_decoder: float = _opt(1e-4, "Learning rate of the decoder when it is fine-tuned.")
    lr_background: float = _opt(1e-2, "Learning rate of the learned backgrounds.")
    learn_background: bool = _opt(True, "Learn the background colour / latent seen where the Gaussians do not cover a "
                                  "pixel, or keep it fixed at the training images' mean (as 3DGS's fixed colour).",
                                  "--learn-background/--fixed-background")
    finetune_decoder: bool = _opt(False, "Also optimise the spectral decoder in stage 2.",
                                  "--finetune-decoder/--frozen-decoder")
    centred_kernels: bool = _opt(True, "Train the hybrid head in the centred form z'_iso + sum_j z_j (K_j - K_j(nadir)) "
                                 "(same function class as eq. 12; saved in eq. 12 form).", "--centred-kernels/--plain-kernels")
    far_field_plane: bool = _opt(False, "Keep the Gaussians that fewer than 30% of the training views see (the far "
                                 "field beyond the area of interest) on the ground surface: no floaters where few "
                                 "views constrain depth (brfgs.train.far_field).",
                                 "--far-field-plane/--free-far-field")
    antialias: bool = _opt(False, "Mip-Splatting's 2D filter: scale each opacity by sqrt(det cov2d / det(cov2d + 0.3 I)) "
                           "so that a Gaussian seen smaller than a pixel (oblique views) is not brightened by the "
                           "low-pass (training and rendering; brfgs.render.rasterize.antialias_opacities).",
                           "--antialias/--no-antialias")
    supersample: int = _opt(1, "Render each pixel as the mean of s x s sub-pixel samples, a box integral over its "
                            "footprint as a sensor pixel (and the simulator's truth) integrates, instead of one "
                            "sample at its centre (training and rendering; brfgs.render.supersample). Rasterizes s^2 "
                            "times the pixels; 1 = 3DGS's point sample (the paper). A candidate: 2 gains 0.36-0.63 dB "
                            "on the testsites and loses 0.34 dB on the forest (validation views, docs/method.md); with "
                            "--supersample-start 0.5 and --densify-absgrad it is --preset fine.")
    supersample_start: float = _opt(0.0, "Fraction of a geometry phase after which --supersample applies (0 = from "
                                    "its first step; before it each pixel is one sample). Stage 2 and rendering "
                                    "always supersample. --preset fine: 0.5 (the forest +0.30 dB against 0, the "
                                    "testsites -0.15 to -0.01; docs/method.md).")
    coarse_levels: int = _opt(0, "Coarse-to-fine geometry (nerfstudio's splatfacto resolution schedule): early in a "
                              "geometry phase the photometric loss compares the render and the observation area-"
                              "averaged over 2^k x 2^k pixels, k falling from this value to 1 over --coarse-until of "
                              "the phase, then full resolution. A blurred image keeps a height error of a pixel's "
                              "parallax inside the loss's basin (brfgs.train.losses.area_pool). 0 = off (the paper).")
    coarse_until: float = _opt(0.2, "Fraction of a geometry phase over which --coarse-levels applies.")
    filter_3d: bool = _opt(False, "Mip-Splatting's 3D smoothing filter while geometry trains: each Gaussian convolved "
                           "with an isotropic Gaussian of sqrt(0.2) x its finest training-view pixel footprint "
                           "(opacity compensated), recomputed every 100 steps and baked into the model at the end of "
                           "the geometry phase (brfgs.model.filter3d); with --antialias: Mip-Splatting. Measured "
                           "worse (docs/method.md); with opacity resets training collapses: use "
                           "--densify-reset-every 0.", "--filter-3d/--no-filter-3d")
    init_opacity: float = _opt(0.1, "Opacity of the initial Gaussians.")
    init_fill_points: int = _opt(10_000, "Add about this many Gaussians to the sparse points (0 = sparse points "
                                 "only, as 3DGS), placed as --init-fill says.")
    init_fill: str = _opt("surface", "Where the added Gaussians go: surface (a 2.5-D surface through the sparse "
                          "points) or mvs (dense plane-sweep stereo of the training views, brfgs.init.mvs, its holes "
                          "filled by a 2.5-D surface through the dense points).")
    max_gaussians_per_px: float = _opt(3.0, "Cap densification at this many Gaussians per image pixel (0 = no cap).")
    schedule_ref_views: int = _opt(17, "Training views that --stage1-steps, --stage2-steps, --refine-steps, "
                                   "--densify-refine-stop and --max-gaussians-per-px are given for: with n > this many "
                                   "training views all five "
                                   "are multiplied by n / this (the same passes over the views, the same Gaussians per "
                                   "observed pixel); with fewer they stay as given. run.json records the values used. "
                                   "0 = always as given (docs/results.md, Session 13).")
    densify: DensifyConfig = _opt(DensifyConfig(), "Adaptive density control (brfgs.model.densify).")
    patch_px: int = _opt(256, "Train on random patches of this size when an image is larger (0 = whole images).")
    stage2_rays: int = _opt(0, "Stage 2 (--decode pixel) decodes and scores this many random pixels of each rendered "
                            "view or patch per step (0 = all: since Session 37; 2048 before, which at 128 x 128 scored "
                            "each pixel ~5 times in stage 2 against ~22 at 64 x 64).")
    patch_rays: int = _opt(0, "The joint phase, and stage 2 with --decode gaussian, train on square patches of about this "
                           "many pixels (0 = whole views or --patch-px patches, as stages 1-2 train; 2048 before Session 41).")
    views_per_step: int = _opt(1, "Training views per step (the global batch; gradients are those of the mean loss, "
                               "each view counts once in the densification statistics). Data-parallel runs "
                               "(--nproc N, torchrun --distributed) share each step's views out: a multiple of N.")
    cache_gib: float = _opt(4.0, "Keep training cubes in memory up to this size (GiB), else read them per step.")
    checkpoint_every: int = _opt(500, "Steps between checkpoints (also at each stage's end and on Ctrl-C).")
    log_every: int = _opt(10, "Steps between rows of train_log.csv.")
    backend: str = _opt("auto", "Rasterizer backend: auto | torch | cpu | cuda.")
    threads: int = _opt(0, "CPU threads (0 = leave the default: all).")
    seed: int = _opt(0, "Seed of every random choice (view order, patches, splits of Gaussians, autoencoder).")
    split_seed: int = _opt(0, "Seed of the deterministic 6:1 train/test split (stratified by view ring).")
    split_rule: str = _opt(DEFAULT_SPLIT_RULE, "Which views of each ring are held out: spread (farthest-point over the view "
                           "directions, so the held-out views lie as far apart as the layout allows) or random (the rule before "
                           "Session 30).")
    validation: bool = _opt(False, "Hold out 1 in 6 training views (stratified by view ring) as a validation split "
                            "and score them (metrics_validation.json): choose settings on these, never on test views.",
                            "--validation/--no-validation")
    decode: str = _opt("pixel", "Spectral decoding order: pixel (alpha-blend latents, decode each pixel) or gaussian "
                       "(paper eq. 13 as published: decode each Gaussian's latent for the view, blend spectra).")
    learn_irradiance: bool = _opt(False, "Learn a per-frame irradiance scale (frames without a known irradiance_scale: "
                                  "clouds, no downwelling sensor) that multiplies the predicted spectra of that "
                                  "training view, with a prior toward 1; reported in run.json.",
                                  "--learn-irradiance/--no-learn-irradiance")
    lambda_irradiance: float = _opt(0.1, "Weight of the prior (log scale)^2 of the learned per-frame irradiance scales.")
    lr_irradiance: float = _opt(5e-3, "Learning rate of the learned per-frame log irradiance scales.")
    frame_suns: bool = _opt(True, "Evaluate every training view's kernels under its own sun (frames' sun_zenith_deg/"
                            "sun_azimuth_deg or time, brfgs.data.sun); --no-frame-suns: the scene's one sun for all.",
                            "--frame-suns/--no-frame-suns")

    def validate(self) -> "TrainConfig":
        if self.variant not in VARIANTS:
            raise UserError(f"variant must be one of {VARIANTS}, got {self.variant!r}", field="variant")
        if self.split_rule not in SPLIT_RULES:
            raise UserError(f"split_rule must be one of {SPLIT_RULES}, got {self.split_rule!r}", field="split_rule")
        if self.decode not in DECODE_ORDERS:
            raise UserError(f"decode must be one of {DECODE_ORDERS}, got {self.decode!r}", field="decode")
        if not 1 <= self.latent_dim <= 32:
            raise UserError(f"latent_dim must be in 1..32, got {self.latent_dim}", field="latent_dim")
        for name in ("stage1_steps", "stage2_steps", "refine_steps"):
            if getattr(self, name) < 0:
                raise UserError(f"step counts must be >= 0, got {getattr(self, name)}", field=name)
        if not 0 <= self.head_lr_decay_from < 1:
            raise UserError(f"head_lr_decay_from must be in [0, 1), got {self.head_lr_decay_from}",
                            field="head_lr_decay_from")
        if not 0 <= self.alpha_dssim <= 1 or not 0 <= self.beta_cos <= 1:
            raise UserError("alpha_dssim and beta_cos must be in [0, 1]", field="alpha_dssim")
        nonneg = ("lambda_normal", "lambda_flat", "lambda_normal_smooth", "lambda_depth_conc", "lambda_depth_smooth",
                  "lambda_alpha", "lambda_sparse_depth", "lambda_dense_depth", "lambda_multiview", "lambda_spectral_tv",
                  "wd_spec", "spec_shrink", "normal_edge_rel", "refine_lr_scale", "stage2_rays", "patch_rays", "patch_px")
        for name in nonneg:
            if getattr(self, name) < 0:
                raise UserError(f"{name} must be >= 0, got {getattr(self, name)}", field=name)
        for f in fields(self):
            if f.name.startswith("lr_") and not getattr(self, f.name) > 0:
                raise UserError(f"{f.name} must be > 0, got {getattr(self, f.name)}", field=f.name)
        if self.densify.mode not in ("adc", "mcmc"):
            raise UserError(f"densify mode must be adc or mcmc, got {self.densify.mode!r}", field="densify.mode")
        for name in ("mcmc_growth", "mcmc_noise_lr", "mcmc_opacity_reg", "mcmc_scale_reg"):
            if getattr(self.densify, name) < 0:
                raise UserError(f"densify {name} must be >= 0, got {getattr(self.densify, name)}", field=f"densify.{name}")
        if not 0 <= self.normal_start <= 1:
            raise UserError(f"normal_start must be in [0, 1], got {self.normal_start}", field="normal_start")
        if not 0 <= int(self.stage1_sh_degree) <= 3:
            raise UserError(f"stage1_sh_degree must be 0..3, got {self.stage1_sh_degree}", field="stage1_sh_degree")
        if not 1 <= self.supersample <= MAX_SUPERSAMPLE:
            raise UserError(f"supersample must be in 1..{MAX_SUPERSAMPLE}, got {self.supersample}", field="supersample")
        if not 0 <= self.supersample_start <= 1:
            raise UserError(f"supersample_start must be in [0, 1], got {self.supersample_start}", field="supersample_start")
        if not 0 <= self.coarse_levels <= MAX_COARSE_LEVELS:
            raise UserError(f"coarse_levels must be in 0..{MAX_COARSE_LEVELS}, got {self.coarse_levels}",
                            field="coarse_levels")
        if not 0 < self.coarse_until <= 1:
            raise UserError(f"coarse_until must be in (0, 1], got {self.coarse_until}", field="coarse_until")
        if self.downscale < 1:
            raise UserError("downscale must be >= 1", field="downscale")
        if self.init_fill not in INIT_FILLS:
            raise UserError(f"init_fill must be one of {', '.join(INIT_FILLS)}, got {self.init_fill!r}", field="init_fill")
        if self.lambda_dense_depth > 0 and (self.init_fill != "mvs" or self.init_fill_points <= 0):
            raise UserError("the dense-depth loss needs the stereo depth maps of --init-fill mvs (with "
                            "--init-fill-points > 0)", field="lambda_dense_depth")
        if self.init_fill_points < 0:
            raise UserError(f"init_fill_points must be >= 0, got {self.init_fill_points}", field="init_fill_points")
        if self.schedule_ref_views < 0:
            raise UserError(f"schedule_ref_views must be >= 0, got {self.schedule_ref_views}", field="schedule_ref_views")
        if self.views_per_step < 1:
            raise UserError(f"views_per_step must be >= 1, got {self.views_per_step}", field="views_per_step")
        if self.checkpoint_every < 1:
            raise UserError("checkpoint_every must be >= 1", field="checkpoint_every")
        bad = [c for c in self.components if c not in ("iso", "vol", "geo", "spec")]
        if bad or not self.components:
            raise UserError(f"components must be a non-empty subset of iso,vol,geo,spec, got {self.components}", field="components")
        return self

    def to_dict(self) -> dict:
        d = asdict(self)
        d["components"] = list(self.components)
        d["value_range"] = list(self.value_range)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict, source: str | None = None) -> "TrainConfig":
        """Options from a dict as :meth:`to_dict` writes it (config.json, model files); UserError
        naming ``source`` and the field for unknown options or values of the wrong type."""
        d = dict(d)
        unknown = set(d) - {f.name for f in fields(cls)}
        if unknown:
            raise UserError(f"unknown training options {sorted(unknown)}", file=source, field="config")
        if isinstance(d.get("densify"), dict):
            dd = d["densify"]
            bad = set(dd) - {f.name for f in fields(DensifyConfig)}
            if bad:
                raise UserError(f"unknown densification options {sorted(bad)}", file=source, field="densify")
            _check_types(DensifyConfig, dd, source, "densify.")
            d["densify"] = DensifyConfig(**dd)
        for key in ("components", "value_range"):
            if isinstance(d.get(key), list):
                d[key] = tuple(d[key])
        _check_types(cls, d, source)
        return cls(**d)

    @classmethod
    def from_run_config(cls, path) -> "TrainConfig":
        """The options a run folder's config.json (``path``) trained with: as :meth:`from_dict`, but an
        option the file predates takes its value of then (:data:`BEFORE_OPTION`, or the option that set
        it then, :data:`BEFORE_OPTION_FROM`) where the default changed since, else today's default."""
        try:
            written = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise UserError(f"unreadable run options ({exc})", file=str(path)) from None
        if not isinstance(written, dict):
            raise UserError("run options must be a JSON object", file=str(path), field="config")
        return cls.from_written(written, source=str(path))

    @classmethod
    def from_written(cls, written: dict, source: str | None = None) -> "TrainConfig":
        """:meth:`from_dict` of a run's written options (config.json), an option they predate taking its
        value of then (:data:`BEFORE_OPTION`, :data:`BEFORE_OPTION_FROM`), else today's default."""
        derived = {k: written[src] for k, src in BEFORE_OPTION_FROM.items() if k not in written and src in written}
        return cls.from_dict({**BEFORE_OPTION, **derived, **written}, source=source)

    def changed_options(self, other: "TrainConfig", ignore: tuple[str, ...] = ()) -> list[str]:
        """Names of the options (as config.json writes them) whose values differ from ``other``'s."""
        a, b = json.loads(self.to_json()), json.loads(other.to_json())
        return sorted(k for k in set(a) | set(b) if k not in ignore and a.get(k) != b.get(k))

    @property
    def total_steps(self) -> int:
        return self.stage1_steps + self.stage2_steps


def _check_types(cls, d: dict, source: str | None, prefix: str = "") -> None:
    """UserError unless every value of ``d`` has the type of the field of ``cls`` it sets."""
    hints = typing.get_type_hints(cls)
    for name, v in d.items():
        tp = hints[name]
        if typing.get_origin(tp) is tuple:
            item = typing.get_args(tp)[0]
            ok = isinstance(v, tuple) and all(isinstance(x, item) or (item is float and isinstance(x, int))
                                              for x in v) and not any(isinstance(x, bool) for x in v)
        elif tp is float:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        elif tp is int:
            ok = isinstance(v, int) and not isinstance(v, bool)
        else:
            ok = isinstance(v, tp)
        if not ok:
            raise UserError(f"expected {getattr(tp, '__name__', str(tp))}, got {v!r}", file=source, field=prefix + name)


def scaled_schedule(cfg: "TrainConfig", n_train_views: int) -> "TrainConfig":
    """The options a run on ``n_train_views`` training views trains with: stage1_steps,
    stage2_steps, refine_steps, densify.refine_stop and max_gaussians_per_px times s = max(1, n_train_views /
    schedule_ref_views), and schedule_ref_views 0 (applied; the result is not scaled again).
    ``cfg`` itself when schedule_ref_views is 0 (the values as given)."""
    if cfg.schedule_ref_views <= 0:
        return cfg
    s = max(1.0, n_train_views / cfg.schedule_ref_views)
    return replace(cfg, stage1_steps=int(round(cfg.stage1_steps * s)), stage2_steps=int(round(cfg.stage2_steps * s)),
                   refine_steps=int(round(cfg.refine_steps * s)), max_gaussians_per_px=round(cfg.max_gaussians_per_px * s, 4),
                   densify=replace(cfg.densify, refine_stop=int(round(cfg.densify.refine_stop * s))),
                   schedule_ref_views=0)
