"""Training options (one dataclass the CLI exposes) and presets.

Presets: ``fast`` (CPU, minutes for a 128-px scene), ``paper`` (GPU-scale, 3DGS-like
30k-step schedule), ``tiny`` (tests: a few steps).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields, replace

from brfgs.errors import UserError
from brfgs.model.densify import DensifyConfig

VARIANTS = ("brf", "sh", "neural", "cir")


@dataclass
class TrainConfig:
    """Every option of ``brfgs train`` (stored in run folders and checkpoints).

    Attributes (units in names):
        variant: "brf" (BRF-GS, hybrid kernels), "sh" (SH degree 3 in the latent space),
            "neural" (per-Gaussian feature + view direction -> MLP, MS-Splatting style),
            "cir" (3DGS with SH degree 3 on CIR composites only; no spectra).
        components: hybrid kernel terms used by "brf" (Table 3 ablations).
        joint: train geometry and reflectance at once on all bands (Table 4 ablation).
        band_strategy/top: band selection for initialisation (SfM) and stage 1 (brfgs.bands).
        stage1_cir_bands: stage 1 also fits the CIR bands (green, red, NIR) next to the selected
            ones; they carry the visible-band texture (not in the paper, which fits the selected bands only).
        poses: "known" | "sfm" | "auto" (brfgs.init).
        downscale: integer area-average factor applied when reading cubes.
        value_range: plausible reflectance range of the cubes (brfgs.data.read_scene).
        latent_dim: d of the spectral autoencoder (<= 32).
        ae_steps/ae_batch/ae_max_pixels: its Adam steps, batch and the training pixels sampled
            (2400 steps: half the spectral angle of 800 on the truth of the 128² testsite,
            0.0077 vs 0.0150 rad, for about a minute more; docs/results.md, Session 4).
        stage1_steps/stage2_steps: optimisation steps; joint uses their sum.
        alpha_dssim: alpha of eq. 24; beta_cos: beta of eq. 25.
        lambda_normal: weight of the depth-normal consistency loss in the phases that train
            geometry (brfgs.train.losses.depth_normal_loss; 0 = off), from the fraction
            normal_start of the phase on; lambda_flat: weight of the flatness loss
            (smallest/largest scale). Both give the specular kernel usable normals n_k on flat,
            textureless surfaces (not in the paper, which leaves n_k to the photometric loss).
        lambda_depth_conc: weight of the ray-wise depth concentration loss (surface prior, as 2DGS's
            distortion loss; brfgs.train.losses.depth_concentration_loss); lambda_depth_smooth: weight
            of the edge-aware second-order smoothness of the rendered inverse depth
            (brfgs.train.losses.depth_smoothness_loss). Both from normal_start on, 0 = off.
        lr_*: Adam learning rates (lr_means is multiplied by the scene extent in metres).
            lr_spec (z_spec) is 20x lr_latent: a glint needs a specular latent an order of
            magnitude larger than the others (K_Cook carries F0 = 0.04), and its few glinting
            pixels give it few steps to get there (docs/results.md, Session 4).
        init_opacity: opacity of the initial Gaussians.
        init_fill_points: add about this many Gaussians on a 2.5-D surface interpolated through
            the sparse points (0 = sparse points only, as in 3DGS); helps short CPU schedules.
        max_gaussians_per_px: cap densification at this many Gaussians per image pixel
            (0 = only densify.max_gaussians); keeps CPU steps fast.
        centred_kernels: train the hybrid head in the centred form z'_iso + sum_j z_j (K_j - K_j(nadir))
            (same function class as eq. 12; saved in eq. 12 form).
        finetune_decoder: also optimise the decoder in stage 2 (lr_decoder).
        patch_px: train on random patch_px x patch_px windows when an image has more than
            patch_px**2 pixels (0 = always whole images).
        stage2_rays: stage 2 decodes and scores this many random pixels of each rendered view
            (ray sampling; 0 = all); the joint phase uses square patches of this many pixels.
        cache_gib: keep training cubes in memory up to this size, else read them per step.
        checkpoint_every: steps between checkpoints (also at each stage's end and on Ctrl-C).
        backend: rasterizer backend ("auto" | "torch" | "cpu" | "cuda").
        threads: torch threads (0 = leave torch's default).
        seed: every random choice (view order, patches, splits of Gaussians, autoencoder).
    """

    preset: str = "fast"
    variant: str = "brf"
    components: tuple[str, ...] = ("iso", "vol", "geo", "spec")
    joint: bool = False
    band_strategy: str = "efc-top3"
    top: int = 3
    stage1_cir_bands: bool = True
    poses: str = "auto"
    downscale: int = 1
    value_range: tuple[float, float] = (-0.5, 10.0)
    latent_dim: int = 16
    ae_steps: int = 2400
    ae_batch: int = 1024
    ae_max_pixels: int = 100_000
    stage1_steps: int = 3000
    stage2_steps: int = 1500
    alpha_dssim: float = 0.2
    beta_cos: float = 0.5
    lambda_normal: float = 0.05
    normal_start: float = 0.3
    lambda_flat: float = 0.01
    lambda_depth_conc: float = 0.0
    lambda_depth_smooth: float = 50.0
    learn_normals: bool = True
    lambda_normal_smooth: float = 0.1
    stage1_sh_degree: int = 3
    lr_normals: float = 2e-3
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_opacity: float = 5e-2
    lr_colors: float = 5e-3
    lr_latent: float = 1e-2
    lr_spec: float = 0.2
    lr_rho: float = 1e-2
    lr_neural: float = 2e-3
    lr_decoder: float = 1e-4
    lr_background: float = 1e-2
    finetune_decoder: bool = False
    centred_kernels: bool = True
    init_opacity: float = 0.1
    init_fill_points: int = 10_000
    max_gaussians_per_px: float = 3.0
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    patch_px: int = 256
    stage2_rays: int = 2048
    cache_gib: float = 4.0
    checkpoint_every: int = 500
    log_every: int = 10
    backend: str = "auto"
    threads: int = 0
    seed: int = 0
    split_seed: int = 0

    def validate(self) -> "TrainConfig":
        if self.variant not in VARIANTS:
            raise UserError(f"variant must be one of {VARIANTS}, got {self.variant!r}", field="variant")
        if not 1 <= self.latent_dim <= 32:
            raise UserError(f"latent_dim must be in 1..32, got {self.latent_dim}", field="latent_dim")
        if self.stage1_steps < 0 or self.stage2_steps < 0:
            raise UserError("step counts must be >= 0", field="stage1_steps")
        if not 0 <= self.alpha_dssim <= 1 or not 0 <= self.beta_cos <= 1:
            raise UserError("alpha_dssim and beta_cos must be in [0, 1]", field="alpha_dssim")
        lambdas = ("lambda_normal", "lambda_flat", "lambda_normal_smooth", "lambda_depth_conc", "lambda_depth_smooth")
        for name in lambdas:
            if getattr(self, name) < 0:
                raise UserError(f"{name} must be >= 0, got {getattr(self, name)}", field=name)
        for f in fields(self):
            if f.name.startswith("lr_") and not getattr(self, f.name) > 0:
                raise UserError(f"{f.name} must be > 0, got {getattr(self, f.name)}", field=f.name)
        if not 0 <= self.normal_start <= 1:
            raise UserError(f"normal_start must be in [0, 1], got {self.normal_start}", field="normal_start")
        if not 0 <= int(self.stage1_sh_degree) <= 3:
            raise UserError(f"stage1_sh_degree must be 0..3, got {self.stage1_sh_degree}", field="stage1_sh_degree")
        if self.downscale < 1:
            raise UserError("downscale must be >= 1", field="downscale")
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
    def from_dict(cls, d: dict) -> "TrainConfig":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise UserError(f"unknown training options {sorted(unknown)}", field="config")
        d = dict(d)
        if "densify" in d and isinstance(d["densify"], dict):
            d["densify"] = DensifyConfig(**d["densify"])
        if "components" in d:
            d["components"] = tuple(d["components"])
        if "value_range" in d:
            d["value_range"] = tuple(d["value_range"])
        return cls(**d)

    @property
    def total_steps(self) -> int:
        return self.stage1_steps + self.stage2_steps


def preset(name: str, **overrides) -> TrainConfig:
    """A :class:`TrainConfig` from a named preset with keyword overrides."""
    if name == "fast":
        cfg = TrainConfig(preset="fast")
    elif name == "paper":
        cfg = TrainConfig(
            preset="paper",
            ae_steps=5000,
            ae_batch=4096,
            ae_max_pixels=1_000_000,
            stage1_steps=30_000,
            stage2_steps=30_000,
            densify=DensifyConfig(refine_start=500, refine_stop=15_000, refine_every=100, reset_every=3000, max_gaussians=3_000_000),
            checkpoint_every=2000,
            patch_px=0,
            stage2_rays=0,
            init_fill_points=0,
            max_gaussians_per_px=0.0,
            stage1_cir_bands=False,
        )
    elif name == "tiny":
        cfg = TrainConfig(
            preset="tiny",
            ae_steps=60,
            ae_batch=256,
            ae_max_pixels=5000,
            stage1_steps=30,
            stage2_steps=30,
            latent_dim=4,
            init_fill_points=500,
            densify=DensifyConfig(refine_start=10, refine_stop=25, refine_every=10, reset_every=1000, max_gaussians=5000),
            checkpoint_every=10,
            log_every=1,
            backend="torch",
        )
    else:
        raise UserError(f"unknown preset {name!r}; choose fast, paper or tiny", field="preset")
    if "densify" in overrides and isinstance(overrides["densify"], dict):
        overrides["densify"] = replace(cfg.densify, **overrides["densify"])
    return replace(cfg, **overrides).validate()
