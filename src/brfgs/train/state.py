"""What a training run holds between steps, and how it goes into checkpoints and the model file.

A checkpoint is the run's :class:`brfgs.model.TrainedModel` (Gaussians, head, decoder,
background, scene description, options) plus the optimiser moments (``optim.``), the
densification statistics (``densify.``), the random generator (``rng.torch``) and the view
order, so that a resumed run continues bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from brfgs.brdf.geometry import sun_direction
from brfgs.errors import UserError
from brfgs.brdf.head import HeadConfig
from brfgs.model import DensifyState, GaussianModel, NamedAdam, TrainedModel
from brfgs.model import io
from brfgs.model.camera import Camera, cameras_from_description
from brfgs.model.layout import check_written
from brfgs.model.features import NeuralHead, uncentre
from brfgs.model.shadows import gaussian_visibility, scene_diffuse_fraction
from brfgs.spectral.autoencoder import SpectralAutoencoder
from brfgs.train.config import TrainConfig
from brfgs.train.phases import Phase
from brfgs.train.dense_depth import DenseDepth

# meta keys that describe the run's set-up (carried from checkpoint to checkpoint)
SETUP_KEYS = ("scene", "bands", "stage1_bands", "cir_indices", "cir_scale", "extent_m", "autoencoder_report",
              "stage1_from")


def head_config(cfg: TrainConfig) -> HeadConfig | None:
    """The :class:`HeadConfig` of a variant (None for the neural head)."""
    if cfg.variant == "brf":
        return HeadConfig(kind="hybrid", components=tuple(cfg.components))
    if cfg.variant in ("sh", "cir"):
        return HeadConfig(kind="sh", sh_degree=3)
    return None


class TrainState:
    """The tensors and counters of a run (see the module docstring)."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.gaussians: GaussianModel | None = None
        self.extra: dict[str, Tensor] = {}          # bg_colors [C] / bg_latent [d]
        self.neural: NeuralHead | None = None
        self.decoder: SpectralAutoencoder | None = None
        self.opt = NamedAdam({})
        self.densify: DensifyState | None = None
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.phase = Phase.DONE
        self.step = 0
        self.perm: list[int] = []                   # training views left in this epoch (popped from the end)
        self.meta: dict = {}                        # set-up facts (SETUP_KEYS)
        self.timings: dict[str, float] = {}
        self._cameras: list[Camera] | None = None
        self.dense_depth: DenseDepth | None = None  # the dense depth maps (option lambda_dense_depth)
        self._visibility: dict[tuple, Tensor] = {}  # option shadows: sun -> V [N] of the frozen geometry
        self._diffuse: tuple[dict, dict] | None = None  # option shadows: (scene description, {frame: f_b [B]})

    # -- derived -----------------------------------------------------------------------
    @property
    def cameras(self) -> list[Camera]:
        """Training-frame cameras (poses of the set-up: known or SfM)."""
        if self._cameras is None:
            self._cameras = cameras_from_description(self.meta["scene"])
        return self._cameras

    @property
    def sun(self) -> Tensor:
        """ω_i [3] of the acquisition's reference sun (the scene's; the centring sun of the head)."""
        sc = self.meta["scene"]
        return sun_direction(sc["sun_zenith_deg"], sc["sun_azimuth_deg"])

    def sun_of(self, i: int) -> Tensor:
        """ω_i [3] of training frame ``i``: its own sun (brfgs.data.sun) unless the option
        ``frame_suns`` is off or it has none; then the reference sun."""
        fr = self.meta["scene"]["frames"][i]
        if not self.cfg.frame_suns or fr.get("sun_zenith_deg") is None:
            return self.sun
        return sun_direction(fr["sun_zenith_deg"], fr["sun_azimuth_deg"])

    def sun_visibility(self, i: int) -> Tensor:  # [N]
        """Direct-sun visibility V [N] of every Gaussian under training frame ``i``'s sun (option
        ``shadows``), from the geometry as it is: computed once per sun while the geometry is frozen
        (stage 2; :meth:`geometry_changed` forgets them)."""
        omega = self.sun_of(i)
        key = tuple(round(float(v), 7) for v in omega)
        if key not in self._visibility:
            g = self.gaussians
            self._visibility[key] = gaussian_visibility(g.means, g.quats, g.scales, g.opacities, omega,
                                                        backend=self.cfg.backend)
        return self._visibility[key]

    def geometry_changed(self) -> None:
        """Forget the sun visibilities of the geometry before (a new phase or a loaded checkpoint)."""
        self._visibility = {}

    def diffuse_fraction(self, i: int) -> Tensor:  # [B]
        """f_b of training frame ``i``: its own sky share of the irradiance per band, else the scene's,
        else the clear-sky default; made once per frame and scene description (every stage-2 step reads it)."""
        sc = self.meta["scene"]
        if self._diffuse is None or self._diffuse[0] is not sc:
            self._diffuse = (sc, {})
        cache = self._diffuse[1]
        if i not in cache:
            cache[i] = scene_diffuse_fraction(sc, i)
        return cache[i]

    def stage1_bands(self) -> list[int]:
        """Band indices stage 1 fits (runs made before stage1_cir_bands existed: the selected bands)."""
        return list(self.meta.get("stage1_bands", self.meta["bands"]))

    def params(self) -> dict[str, Tensor]:
        """Every tensor the optimiser may update, by name."""
        p = dict(self.gaussians.params)
        p.update(self.extra)
        if self.neural is not None:
            p.update({"neural." + k: v for k, v in self.neural.named_parameters()})
        if self.decoder is not None and self.cfg.finetune_decoder and self.phase.fits_head:
            p.update({"decoder." + k: v for k, v in self.decoder.named_parameters()})
        return p

    # -- files -------------------------------------------------------------------------
    def trained_model(self, final: bool = False) -> TrainedModel:
        """The run as a :class:`TrainedModel`; ``final``: phase "done" and the head in eq. 12 form."""
        meta = {k: self.meta[k] for k in SETUP_KEYS if k in self.meta}
        meta.update({"phase": Phase.DONE.value if final else self.phase.value, "step": self.step,
                     "timings_s": self.timings,
                     "kernel_form": "centred" if self.gaussians.centred and not final else "eq12"})
        gm = self.gaussians
        if final and gm.centred:
            gm = GaussianModel(uncentre(gm, head_config(self.cfg), self.sun), gm.appearance, gm.latent_dim, gm.n_colors)
        return TrainedModel(gaussians=gm, head_cfg=head_config(self.cfg), decoder=self.decoder,
                            scene=self.meta["scene"], config=self.cfg.to_dict(), extra=self.extra,
                            neural=self.neural, meta=meta)

    def save_checkpoint(self, path: Path) -> Path:
        """Model + optimiser, densification statistics, generator and view order (resume state)."""
        tm = self.trained_model()
        tensors = tm.tensors()
        tensors.update(self.opt.state_tensors("optim."))
        tensors.update(self.densify.tensors("densify."))
        tensors["rng.torch"] = self.gen.get_state()
        meta = tm.metadata()
        meta.update({"optim": self.opt.state_meta(), "densify_resets": self.densify.n_resets, "perm": list(self.perm)})
        check_written(tensors, meta, path)
        return io.save(path, tensors, meta)

    def save_model(self, path: Path) -> Path:
        """The final model file (model.safetensors)."""
        return self.trained_model(final=True).save(path)

    def load_checkpoint(self, path: Path) -> tuple[dict[str, Tensor], dict]:
        """Restore the model part of a checkpoint (validated, the resume state too); returns its (tensors, meta)."""
        tensors, meta = io.load(path)
        check_resume_state(tensors, meta, Path(path))
        tm = TrainedModel.from_file_contents(tensors, meta, Path(path))
        self.meta = {k: meta[k] for k in SETUP_KEYS if k in meta}
        self.gaussians = tm.gaussians
        self.extra = {k: v.clone().requires_grad_(True) for k, v in tm.extra.items()}
        self.decoder = tm.decoder
        if self.decoder is not None:
            self.decoder.requires_grad_(self.cfg.finetune_decoder)
        self.neural = tm.neural
        self.timings = dict(meta.get("timings_s", {}))
        self._cameras = None
        self.geometry_changed()
        return tensors, meta

    def load_training_state(self, tensors: dict[str, Tensor], meta: dict) -> None:
        """Restore the optimiser, densification statistics, generator, view order, phase and step."""
        self.opt = NamedAdam({})
        self.opt.load(tensors, meta["optim"], "optim.")
        self.densify = DensifyState(self.gaussians.n)
        self.densify.load(tensors, meta.get("densify_resets", 0), "densify.")
        self.gen.set_state(tensors["rng.torch"])
        self.perm = list(meta.get("perm", []))
        self.phase = Phase(meta["phase"])
        self.step = int(meta["step"])


def check_resume_state(tensors: dict[str, Tensor], meta: dict, path: Path) -> None:
    """UserError naming the checkpoint and the field unless it holds a whole resume state: the phase
    and step, the optimiser's step counts, the generator state and the densification statistics of
    every Gaussian (a file without its checksum is checked all the same)."""
    means = tensors.get("param.means")
    n = None if means is None else means.shape[0]

    def need(ok: bool, field: str, what: str) -> None:
        if not ok:
            raise UserError(f"{what}: not a whole checkpoint (delete it to resume from the one before, or pass "
                            "--overwrite to start again)", file=path, field=field)

    need(meta.get("phase") in {p.value for p in Phase}, "phase", f"unknown phase {meta.get('phase')!r}")
    step = meta.get("step")
    need(isinstance(step, int) and not isinstance(step, bool) and step >= 0, "step", f"bad step {step!r}")
    optim = meta.get("optim")
    need(isinstance(optim, dict) and isinstance(optim.get("t"), dict), "optim", "no optimiser state")
    rng = tensors.get("rng.torch")
    need(rng is not None and rng.dtype == torch.uint8, "rng.torch", "no generator state")
    for key in ("densify.grad2d", "densify.count"):
        t = tensors.get(key)
        need(t is not None and n is not None and tuple(t.shape) == (n,), key,
             f"no densification statistics of {n} Gaussians")
    need(isinstance(meta.get("config"), dict), "config", "no training options")
