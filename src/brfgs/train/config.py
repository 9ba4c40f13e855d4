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

from brfgs.bands.options import STRATEGIES as BAND_STRATEGIES
from brfgs.errors import UserError
from brfgs.init.options import POSE_MODES
from brfgs.model.densify_config import STRATEGIES, ADCConfig, MCMCConfig
from brfgs.train.config_format import upgrade

VARIANTS = ("brf", "sh", "neural", "cir")
DECODE_ORDERS = ("pixel", "gaussian")
INIT_FILLS = ("surface", "mvs", "truth")
BACKENDS = ("auto", "torch", "cpu", "cuda")  # brfgs.render.BACKENDS (a test keeps them equal; no render import here)
SPECTRAL_BASES = ("autoencoder", "linear")  # brfgs.spectral.decoders.SPECTRAL_BASES (this module loads no torch)
MAX_SUPERSAMPLE = 4  # --supersample: at most 4 x 4 sub-pixel samples per pixel (brfgs.render.supersample)
FORMAT_VERSION = 2  # of config.json (and the options stored in checkpoints and model files)

METHOD, SCHEDULE, LOSSES, DATA, COMPUTE = "Method", "Schedule", "Losses", "Data", "Compute"


def _opt(default, help: str, flag: str | None = None, panel: str | None = None, expert: bool = False):
    """A dataclass field with its command-line help, flag (e.g. "--joint/--decoupled"), the panel it
    is listed under in ``--help``, or ``expert`` (listed only by ``--help-all``)."""
    meta = {"help": help, "panel": panel, "expert": expert}
    if flag is not None:
        meta["flag"] = flag
    if isinstance(default, (ADCConfig, MCMCConfig)):
        return field(default_factory=lambda: replace(default), metadata=meta)
    return field(default=default, metadata=meta)


def _x(default, help: str, flag: str | None = None):
    """An experimental or expert option (``brfgs train --help-all``)."""
    return _opt(default, help, flag, expert=True)


@dataclass
class TrainConfig:
    """Every option of ``brfgs train`` (stored in run folders, checkpoints and model files).

    Each field's help is its ``--option`` help (``brfgs train --help``; expert fields with
    ``--help-all``), generated from this class. The additions beyond the paper and their switches are
    :data:`brfgs.train.presets.ADDITIONS` (docs/method.md).
    """

    # -- the method
    preset: str = _opt("fast", "fast, fine (supersampled, more accurate, slower), paper (the published "
                       "method, GPU-scale schedule), paper-fast (the published method, CPU schedule), tiny (tests).",
                       panel=METHOD)
    variant: str = _opt("brf", "brf (BRF-GS kernels), sh (SH-3 baseline), neural (MLP baseline), cir (3DGS on CIR "
                        "composites).", panel=METHOD)
    components: tuple[str, ...] = _opt(("iso", "vol", "geo", "spec"), "Kernel terms of brf: a subset of "
                                       "iso,vol,geo,spec.", panel=METHOD)
    joint: bool = _opt(False, "Train geometry and reflectance at once on all bands instead of in two stages.",
                       "--joint/--decoupled", panel=METHOD)
    shadows: bool = _x(False, "Stage 2 fits the lit surface: spectra rendered times the sun where the model's "
                       "geometry lets it through plus the sky (scene's diffuse_fraction); shadows move with the sun.",
                       "--shadows/--no-shadows")
    decode: str = _opt("pixel", "Spectral decoding: pixel (blend latents, decode pixels) or gaussian (paper eq. 13).",
                       panel=METHOD)
    band_strategy: str = _opt("efc-top3", "Geometry bands for SfM and stage 1 (see brfgs select-bands).", panel=METHOD)
    top: int = _opt(3, "Number of bands the band strategy selects.", panel=METHOD)
    latent_dim: int = _opt(16, "Latent size of the spectral decoder (1-32).", panel=METHOD)
    # -- the schedule
    stage1_steps: int = _opt(3000, "Geometry (stage-1) steps for 17 training views.", panel=SCHEDULE)
    stage2_steps: int = _opt(750, "Reflectance (stage-2) steps for 17 training views.", panel=SCHEDULE)
    schedule_ref_views: int = _opt(17, "Steps and Gaussian caps grow with the training views beyond this many (0 = "
                                   "as given).", panel=SCHEDULE)
    strategy: str = _opt("adc", "Densification: adc (3DGS clone/split/prune) or mcmc (3DGS-MCMC).", panel=SCHEDULE)
    max_gaussians: int = _opt(0, "Never grow beyond this many Gaussians (0 = follow the image: 60,000 up to 128² "
                              "pixels, growing with the pixel count above, at most 3,000,000).", panel=SCHEDULE)
    # -- the losses' weights
    alpha_dssim: float = _opt(0.2, "Weight of D-SSIM in the geometry loss (paper eq. 24).", panel=LOSSES)
    beta_cos: float = _opt(0.5, "Weight of the spectral cosine loss in the reflectance loss (eq. 25).", panel=LOSSES)
    lambda_normal: float = _opt(0.05, "Depth-normal consistency of the Gaussians' normals (0 = off).", panel=LOSSES)
    lambda_flat: float = _opt(0.01, "Flatness of the Gaussians (0 = off).", panel=LOSSES)
    lambda_depth_smooth: float = _opt(50.0, "Edge-aware smoothness of the rendered depth (0 = off).", panel=LOSSES)
    lambda_normal_smooth: float = _opt(0.1, "Smoothness of the learned shading normals (0 = off).", panel=LOSSES)
    lambda_spectral_tv: float = _opt(0.1, "Edge-aware spectral-angle smoothness of the rendered spectra (0 = off).",
                                     panel=LOSSES)
    # -- the data
    poses: str = _opt("auto", "Camera poses: known, sfm or auto (known when every frame has one).", panel=DATA)
    downscale: int = _opt(1, "Read the cubes downscaled by this integer factor (area average).", panel=DATA)
    validation: bool = _opt(False, "Hold out 1 in 6 training views and score them (choose settings there).",
                            "--validation/--no-validation", panel=DATA)
    seed: int = _opt(0, "Seed of every random choice of the training.", panel=DATA)
    split_seed: int = _opt(0, "Seed of the train/test split (6:1 per view ring).", panel=DATA)
    learn_irradiance: bool = _opt(False, "Learn a per-frame irradiance scale (frames without a known one).",
                                  "--learn-irradiance/--no-learn-irradiance", panel=DATA)
    frame_suns: bool = _opt(True, "Evaluate each view's kernels under its own frame's sun.",
                            "--frame-suns/--no-frame-suns", panel=DATA)
    # -- the computer
    backend: str = _opt("auto", "Rasterizer: auto, torch, cpu (compiled) or cuda (gsplat).", panel=COMPUTE)
    threads: int = _opt(0, "CPU threads (0 = all).", panel=COMPUTE)
    views_per_step: int = _opt(1, "Training views per step (data-parallel runs share them out).", panel=COMPUTE)
    checkpoint_every: int = _opt(500, "Steps between checkpoints (also at each stage's end and on Ctrl-C).",
                                 panel=COMPUTE)
    # -- experimental and expert options (brfgs train --help-all)
    stage1_cir_bands: bool = _x(True, "Stage 1 also fits the CIR bands (off: the selected bands only, as the paper).",
                                "--stage1-cir-bands/--stage1-selected-bands-only")
    stage1_kernels: bool = _x(True, "Stage-1 colours with the Ross-Thick and Li-Sparse view dependence (off: flat, "
                              "as the paper).", "--stage1-kernels/--stage1-flat-colours")
    dssim_per_band: bool = _x(True, "D-SSIM per stage-1 band (off: on the band mean, as the paper).",
                              "--dssim-per-band/--dssim-grayscale")
    learn_normals: bool = _x(True, "Learn shading normals in stage 2 (off: the smallest axis, as the paper).",
                             "--learn-normals/--geometric-normals")
    centred_kernels: bool = _x(True, "Train eq. 12 in its centred form (off: plain, as the paper).",
                               "--centred-kernels/--plain-kernels")
    learn_background: bool = _x(True, "Learn the background seen where no Gaussian covers a pixel (off: fixed).",
                                "--learn-background/--fixed-background")
    finetune_decoder: bool = _x(False, "Also optimise the spectral decoder in stage 2.",
                                "--finetune-decoder/--frozen-decoder")
    spectral_basis: str = _x("autoencoder", "Spectral decoder: autoencoder (paper eq. 9) or linear (noise-weighted "
                             "PCA: each band's BRF the kernel model, exact kernel products).")
    normal_start: float = _x(0.3, "Fraction of a geometry phase after which the surface priors start.")
    ae_steps: int = _x(2400, "Adam steps of the spectral autoencoder.")
    ae_batch: int = _x(1024, "Autoencoder batch size (pixels).")
    ae_max_pixels: int = _x(100_000, "Training pixels sampled for the autoencoder.")
    lr_means: float = _x(1.6e-4, "Initial learning rate of the means (x scene extent).")
    lr_means_final: float = _x(1.6e-6, "Final learning rate of the means (x scene extent).")
    lr_scales: float = _x(5e-3, "Learning rate of the log-scales.")
    lr_quats: float = _x(1e-3, "Learning rate of the rotations.")
    lr_opacity: float = _x(5e-2, "Learning rate of the opacity logits.")
    lr_colors: float = _x(5e-3, "Learning rate of the stage-1 colours and the CIR SH.")
    lr_latent: float = _x(1e-2, "Learning rate of the latents z_iso, z_vol, z_geo (and SH, features).")
    lr_spec: float = _x(0.2, "Learning rate of the specular latent z_spec (a glint needs a large latent).")
    lr_head_final: float = _x(0.1, "The appearance head's rates at the end of stage 2, x their start (1 = constant).")
    head_lr_decay_from: float = _x(0.75, "Fraction of stage 2 after which the head's rates decay log-linearly.")
    lr_normals: float = _x(2e-3, "Learning rate of the learned shading normals.")
    lr_rho: float = _x(1e-2, "Learning rate of the roughness.")
    lr_neural: float = _x(2e-3, "Learning rate of the neural head's MLP.")
    lr_decoder: float = _x(1e-4, "Learning rate of the decoder when it is fine-tuned.")
    lr_background: float = _x(1e-2, "Learning rate of the learned backgrounds.")
    lr_irradiance: float = _x(5e-3, "Learning rate of the learned log irradiance scales.")
    lambda_irradiance: float = _x(0.1, "Weight of the prior (log scale)^2 of the learned irradiance scales.")
    init_opacity: float = _x(0.1, "Opacity of the initial Gaussians.")
    init_fill_points: int = _x(10_000, "Gaussians added to the sparse SfM points (0 = the sparse points only).")
    init_fill: str = _x("surface", "Where the added Gaussians start: surface (through the sparse points), mvs (dense "
                        "stereo) or truth (a simulated scene's true surface).")
    lambda_dense_depth: float = _x(0.0, "Rendered depth against the dense depth maps of --init-fill mvs or truth "
                                   "(0 = off).")
    antialias: bool = _x(False, "Mip-Splatting's 2D filter in training and rendering.", "--antialias/--no-antialias")
    supersample: int = _x(1, "Each pixel the mean of s x s sub-pixel samples, in training and rendering (1-4).")
    supersample_start: float = _x(0.0, "Fraction of a geometry phase after which --supersample applies.")
    max_gaussians_per_px: float = _x(3.0, "Cap the Gaussians at this many per image pixel (0 = no cap).")
    densify: ADCConfig = _x(ADCConfig(), "3DGS adaptive density control (--strategy adc).")
    mcmc: MCMCConfig = _x(MCMCConfig(), "3DGS-MCMC densification (--strategy mcmc).")
    patch_px: int = _x(256, "Train on random patches of this size when an image is larger (0 = whole images).")
    stage2_rays: int = _x(0, "Stage 2 scores this many random pixels of each view (0 = all).")
    cache_gib: float = _x(4.0, "Hold whole training cubes in memory up to this size (GiB; the least recently used "
                          "leave first); other frames are read per step, only the patch's window.")
    log_every: int = _x(10, "Steps between rows of train_log.csv.")
    allow_outside_links: bool = _x(False, "Read files that links in the scene folder lead to outside it.",
                                   "--allow-outside-links/--confine-to-scene")
    value_range: tuple[float, float] = _x((-0.5, 10.0), "Plausible reflectance range LO,HI of the cubes.")

    def validate(self) -> "TrainConfig":
        """``self`` when every option is in range; UserError naming the option otherwise."""
        for name, allowed in (("variant", VARIANTS), ("decode", DECODE_ORDERS), ("init_fill", INIT_FILLS),
                              ("strategy", STRATEGIES), ("poses", POSE_MODES), ("band_strategy", BAND_STRATEGIES),
                              ("backend", BACKENDS), ("spectral_basis", SPECTRAL_BASES)):
            if getattr(self, name) not in allowed:
                raise UserError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}", field=name)
        if not 1 <= self.latent_dim <= 32:
            raise UserError(f"latent_dim must be in 1..32, got {self.latent_dim}", field="latent_dim")
        nonneg = ("stage1_steps", "stage2_steps", "lambda_normal", "lambda_flat", "lambda_normal_smooth",
                  "lambda_depth_smooth", "lambda_dense_depth", "lambda_spectral_tv", "stage2_rays", "patch_px",
                  "init_fill_points", "schedule_ref_views", "max_gaussians_per_px")
        for name in nonneg:
            if not getattr(self, name) >= 0:
                raise UserError(f"{name} must be >= 0, got {getattr(self, name)}", field=name)
        for name in ("normal_start", "supersample_start", "alpha_dssim", "beta_cos"):
            if not 0 <= getattr(self, name) <= 1:
                raise UserError(f"{name} must be in [0, 1], got {getattr(self, name)}", field=name)
        if not 0 <= self.head_lr_decay_from < 1:
            raise UserError(f"head_lr_decay_from must be in [0, 1), got {self.head_lr_decay_from}",
                            field="head_lr_decay_from")
        for f in fields(self):
            if f.name.startswith("lr_") and not getattr(self, f.name) > 0:
                raise UserError(f"{f.name} must be > 0, got {getattr(self, f.name)}", field=f.name)
        for name in ("growth", "noise_lr", "opacity_reg", "scale_reg"):
            if not getattr(self.mcmc, name) >= 0:
                raise UserError(f"mcmc {name} must be >= 0, got {getattr(self.mcmc, name)}", field=f"mcmc.{name}")
        if not 1 <= self.supersample <= MAX_SUPERSAMPLE:
            raise UserError(f"supersample must be in 1..{MAX_SUPERSAMPLE}, got {self.supersample}", field="supersample")
        if self.downscale < 1:
            raise UserError("downscale must be >= 1", field="downscale")
        if self.lambda_dense_depth > 0 and (self.init_fill == "surface" or self.init_fill_points <= 0):
            raise UserError("the dense-depth loss needs the depth maps of --init-fill mvs or truth (with "
                            "--init-fill-points > 0)", field="lambda_dense_depth")
        for name in ("views_per_step", "checkpoint_every"):
            if getattr(self, name) < 1:
                raise UserError(f"{name} must be >= 1, got {getattr(self, name)}", field=name)
        if self.max_gaussians < 0:
            raise UserError(f"max_gaussians must be >= 1, or 0 to follow the image, got {self.max_gaussians}",
                            field="max_gaussians")
        if not (math.isfinite(self.cache_gib) and self.cache_gib >= 0):
            raise UserError(f"cache_gib must be >= 0, got {self.cache_gib}", field="cache_gib")
        if not 0 < self.init_opacity < 1:
            raise UserError(f"init_opacity must be in (0, 1), got {self.init_opacity}", field="init_opacity")
        lo, hi = self.value_range
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise UserError(f"value_range must be two finite numbers LO < HI, got {lo}, {hi}", field="value_range")
        if self.shadows and (self.joint or self.variant == "cir"):
            raise UserError("--shadows needs the two-stage spectral training (not --joint, not the cir variant): "
                            "the sun's visibility is computed from the stage-1 geometry", field="shadows")
        bad = [c for c in self.components if c not in ("iso", "vol", "geo", "spec")]
        if bad or not self.components:
            raise UserError(f"components must be a non-empty subset of iso,vol,geo,spec, got {self.components}", field="components")
        return self

    def to_dict(self) -> dict:
        """The options as config.json writes them (with the format version)."""
        d = asdict(self)
        d["components"] = list(self.components)
        d["value_range"] = list(self.value_range)
        d["format_version"] = FORMAT_VERSION
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict, source: str | None = None) -> "TrainConfig":
        """Options from a dict as :meth:`to_dict` writes it (config.json, model files); UserError
        naming ``source`` and the field for unknown options or values of the wrong type."""
        d = dict(d)
        version = d.pop("format_version", FORMAT_VERSION)
        if version != FORMAT_VERSION:
            raise UserError(f"options of format {version!r}; this version of brfgs reads format {FORMAT_VERSION} "
                            "(and format 1, converted by TrainConfig.from_written)", file=source, field="format_version")
        unknown = set(d) - {f.name for f in fields(cls)}
        if unknown:
            raise UserError(f"unknown training options {sorted(unknown)}", file=source, field="config")
        for key, sub in (("densify", ADCConfig), ("mcmc", MCMCConfig)):
            if isinstance(d.get(key), dict):
                bad = set(d[key]) - {f.name for f in fields(sub)}
                if bad:
                    raise UserError(f"unknown {key} options {sorted(bad)}", file=source, field=key)
                _check_types(sub, d[key], source, f"{key}.")
                d[key] = sub(**d[key])
        for key in ("components", "value_range"):
            if isinstance(d.get(key), list):
                d[key] = tuple(d[key])
        _check_types(cls, d, source)
        return cls(**d)

    @classmethod
    def from_run_config(cls, path) -> "TrainConfig":
        """The options a run folder's config.json (``path``) trained with (:meth:`from_written`)."""
        try:
            written = json.loads(Path(path).read_text())
        except (OSError, ValueError, RecursionError) as exc:
            raise UserError(f"unreadable run options ({exc})", file=str(path)) from None
        if not isinstance(written, dict):
            raise UserError("run options must be a JSON object", file=str(path), field="config")
        return cls.from_written(written, source=str(path))

    @classmethod
    def from_written(cls, written: dict, source: str | None = None) -> "TrainConfig":
        """:meth:`from_dict` of options as any version of brfgs wrote them (config.json, checkpoints,
        model files): format 1 (brfgs 0.1) is converted first (:func:`brfgs.train.config_format.upgrade`)."""
        return cls.from_dict(upgrade(written, source), source=source)

    def changed_options(self, other: "TrainConfig", ignore: tuple[str, ...] = ()) -> list[str]:
        """Names of the options (as config.json writes them) whose values differ from ``other``'s."""
        a, b = json.loads(self.to_json()), json.loads(other.to_json())
        return sorted(k for k in set(a) | set(b) if k not in ignore and a.get(k) != b.get(k))

    @property
    def strategy_config(self) -> ADCConfig | MCMCConfig:
        """The options of the chosen densification strategy."""
        return self.mcmc if self.strategy == "mcmc" else self.densify

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
    """The options a run on ``n_train_views`` training views trains with: stage1_steps, stage2_steps,
    the chosen strategy's refine_stop and max_gaussians_per_px times s = max(1, n_train_views /
    schedule_ref_views), and schedule_ref_views 0 (applied; the result is not scaled again).
    ``cfg`` itself when schedule_ref_views is 0 (the values as given)."""
    if cfg.schedule_ref_views <= 0:
        return cfg
    s = max(1.0, n_train_views / cfg.schedule_ref_views)
    key = "mcmc" if cfg.strategy == "mcmc" else "densify"
    sub = getattr(cfg, key)
    return replace(cfg, stage1_steps=int(round(cfg.stage1_steps * s)), stage2_steps=int(round(cfg.stage2_steps * s)),
                   max_gaussians_per_px=round(cfg.max_gaussians_per_px * s, 4),
                   **{key: replace(sub, refine_stop=int(round(sub.refine_stop * s)))}, schedule_ref_views=0)


# The cap on the Gaussians when max_gaussians is 0: AUTO_GAUSSIANS up to AUTO_GAUSSIANS_REF_PX pixels per
# image (128², where it was chosen), in proportion to the pixel count above, at most AUTO_GAUSSIANS_MAX
# (≈ 1.6 kB per Gaussian for parameters, gradients and Adam's moments: ≈ 4.8 GB; docs/scaling.md).
AUTO_GAUSSIANS = 60_000
AUTO_GAUSSIANS_REF_PX = 128 * 128
AUTO_GAUSSIANS_MAX = 3_000_000


def auto_max_gaussians(width: int, height: int) -> int:
    """The cap on the Gaussians for training images of ``width`` x ``height`` px when max_gaussians is 0."""
    grown = AUTO_GAUSSIANS * width * height // AUTO_GAUSSIANS_REF_PX
    return int(min(AUTO_GAUSSIANS_MAX, max(AUTO_GAUSSIANS, grown)))


def with_gaussian_cap(cfg: "TrainConfig", width: int, height: int) -> "TrainConfig":
    """``cfg`` with max_gaussians 0 replaced by :func:`auto_max_gaussians` of the training images
    (``cfg`` itself when a cap is given)."""
    return cfg if cfg.max_gaussians > 0 else replace(cfg, max_gaussians=auto_max_gaussians(width, height))
