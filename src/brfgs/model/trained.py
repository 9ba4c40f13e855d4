"""The trained model: one type that the trainer saves and every analysis loads and renders.

A :class:`TrainedModel` is the Gaussians (:class:`brfgs.model.gaussians.GaussianModel`), the
appearance head (:class:`brfgs.brdf.head.HeadConfig` or the neural head), the spectral decoder
(eq. 13: the autoencoder or a linear basis), the learned background, the scene description
(wavelengths, acquisition sun, intrinsics, frames with poses and split;
:func:`brfgs.model.camera.scene_description`) and the training options, stored as
``model.safetensors`` (:mod:`brfgs.model.io`: safetensors + JSON metadata with a schema version,
validated on load by :mod:`brfgs.model.schema`; no code runs).
:func:`brfgs.model.view.render` renders it from any camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from brfgs.brdf.geometry import shading_normals, sun_direction
from brfgs.brdf.head import HeadConfig, evaluate_head
from brfgs.data.cameras import Intrinsics
from brfgs.data.georef import MapFrame, default_crs, read_georef
from brfgs.errors import UserError
from brfgs.model import io
from brfgs.model.camera import Camera, cameras_from_description, intrinsics_from_description
from brfgs.model.features import HEAD_PARAM_KEYS, NeuralHead
from brfgs.model.gaussians import GaussianModel
from brfgs.model.rendering import decode_image
from brfgs.model.shadows import gaussian_visibility, scene_diffuse_fraction
from brfgs.model.layout import check_written
from brfgs.model.schema import check_metadata, check_tensors
from brfgs.spectral.decoders import (DESCRIPTION_KEYS, SpectralDecoder, decoder_from_state, decoder_metadata,
                                    decoder_state, is_linear)

MODEL_FILE = "model.safetensors"


def head_config_from_dict(d: dict) -> HeadConfig | None:
    """HeadConfig stored in a model file (None for the neural head)."""
    return None if d.get("kind") == "neural" else HeadConfig.from_dict(d)


@dataclass(frozen=True)
class RenderSettings:
    """How a model renders, fixed by how it was trained (a model is tied to its sampling).

    decode_order: "pixel" (blend latents, decode each pixel) or "gaussian" (paper eq. 13: decode each
    Gaussian, blend spectra); antialias: Mip-Splatting's 2D opacity compensation; supersample: sub-pixel
    samples per pixel side (each pixel the mean of s x s samples).

    A model with a linear spectral basis (D(z) = W z + b) renders "pixel" whatever it was trained with:
    for an affine decoder the two orders give the same spectra up to float rounding (the blending
    weights and the background's 1 − α sum to one), and blending d latents is cheaper than B spectra.
    """

    decode_order: str = "pixel"
    antialias: bool = False
    supersample: int = 1

    @classmethod
    def from_training_options(cls, config: dict, spectral: bool = True, linear: bool = False) -> "RenderSettings":
        """The settings of a model trained with the options ``config`` (a config.json dict; options it
        predates take the value they had before they existed); ``linear``: its spectral basis is linear."""
        return cls(decode_order=str(config.get("decode", "pixel")) if spectral and not linear else "pixel",
                   antialias=bool(config.get("antialias", False)), supersample=int(config.get("supersample", 1)))


@dataclass
class TrainedModel:
    """A trained BRF-GS model (or baseline); see the module docstring.

    ``meta`` keeps what the file records beyond the fields (band selection ``bands`` and
    ``stage1_bands``, ``cir_indices``, ``cir_scale``, ``extent_m``, ``autoencoder_report``,
    ``timings_s``, ``phase``, ``step`` ...).
    """

    gaussians: GaussianModel
    head_cfg: HeadConfig | None         # None: the neural head
    decoder: SpectralDecoder | None  # the autoencoder or a LinearBasis; None: the CIR variant
    scene: dict
    config: dict = field(default_factory=dict)  # training options (brfgs.train.config.TrainConfig.to_dict())
    extra: dict[str, Tensor] = field(default_factory=dict)  # bg_latent [d] / bg_colors [C]
    neural: NeuralHead | None = None
    meta: dict = field(default_factory=dict)
    source: str | None = None
    # (tensor identities and versions, detached tensors) of frozen(); not part of the model
    _frozen: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _visibility: dict = field(default_factory=dict, init=False, repr=False, compare=False)  # sun -> V [N]
    _sky: dict = field(default_factory=dict, init=False, repr=False, compare=False)  # sun zenith -> f_b [B]

    # -- description ----------------------------------------------------------------
    @property
    def appearance(self) -> str:
        return self.gaussians.appearance

    @property
    def spectral(self) -> bool:
        return self.decoder is not None and self.appearance != "cir"

    @property
    def n_gaussians(self) -> int:
        return self.gaussians.n

    @cached_property
    def wavelengths_nm(self) -> np.ndarray:
        return np.asarray(self.scene["wavelengths_nm"], float)

    @property
    def fwhm_nm(self) -> np.ndarray | None:
        f = self.scene.get("fwhm_nm")
        return None if f is None else np.asarray(f, float)

    @property
    def sun_zenith_deg(self) -> float:
        return float(self.scene["sun_zenith_deg"])

    @property
    def sun_azimuth_deg(self) -> float:
        return float(self.scene["sun_azimuth_deg"])

    @cached_property
    def intrinsics(self) -> Intrinsics:
        return intrinsics_from_description(self.scene)

    @property
    def frames(self) -> list[dict]:
        """Training frames: dicts with name, split, c2w, view_zenith_deg, view_azimuth_deg."""
        return list(self.scene.get("frames", []))

    @cached_property
    def cameras(self) -> list[Camera]:
        """One camera per training frame, in frame order."""
        return cameras_from_description(self.scene)

    @cached_property
    def map_frame(self) -> MapFrame | None:
        """The scene's georeference (origin and map CRS, :mod:`brfgs.data.georef`), None if not given."""
        origin, crs = read_georef(self.scene)
        return None if origin is None else MapFrame(origin, crs or default_crs(origin))

    @property
    def scene_root(self) -> str | None:
        return self.scene.get("root")

    @property
    def scene_name(self) -> str:
        return self.scene.get("name", "scene")

    @property
    def cir_indices(self) -> tuple[int, int, int]:
        return tuple(int(i) for i in self.meta.get("cir_indices", (0, 0, 0)))

    @property
    def cir_scale(self) -> np.ndarray:
        return np.asarray(self.meta.get("cir_scale", (1.0, 1.0, 1.0)), float)

    @property
    def bg_latent(self) -> Tensor | None:
        return self.extra.get("bg_latent") if self.spectral else None

    @cached_property
    def render_settings(self) -> "RenderSettings":
        """How the model renders: as it was trained (:class:`RenderSettings`)."""
        return RenderSettings.from_training_options(self.config, self.spectral, is_linear(self.decoder))

    @property
    def shadowed(self) -> bool:
        """Trained with shadows (option ``shadows``): spectra are rendered times the sun and sky
        illumination (1 − f_b) V + f_b (:mod:`brfgs.model.shadows`)."""
        return bool(self.config.get("shadows", False)) and self.spectral

    def diffuse_fraction(self, sun_zenith_deg: float | None = None) -> Tensor:  # [B]
        """f_b [B]: the sky share of the downwelling irradiance the model was trained with (the scene's
        field), else the clear-sky default of :mod:`brfgs.data.sky` for the sun (deg; default the
        acquisition's)."""
        z = round(float(self.sun_zenith_deg if sun_zenith_deg is None else sun_zenith_deg), 4)
        if z not in self._sky:
            self._sky[z] = scene_diffuse_fraction(self.scene, sun_zenith_deg=z)
        return self._sky[z]

    def sun_visibility(self, sun_zenith_deg: float | None = None, sun_azimuth_deg: float | None = None,
                       backend: str = "auto") -> Tensor:
        """V [N]: each Gaussian's direct-sun visibility for the sun (deg; default the acquisition's)."""
        return self.sun_visibility_toward(self.sun_direction(sun_zenith_deg, sun_azimuth_deg), backend)

    def sun_visibility_toward(self, omega_sun: Tensor, backend: str = "auto") -> Tensor:
        """V [N] for the sun direction ``omega_sun`` [3] (unit, toward the sun), computed once per sun
        and geometry (:func:`brfgs.model.shadows.gaussian_visibility`)."""
        f = self.frozen()
        omega = omega_sun.to(f["means"].dtype)
        key = (tuple(round(float(v), 7) for v in omega), self._frozen_key(), backend)
        if key not in self._visibility:
            if len(self._visibility) >= 16:
                self._visibility.clear()
            self._visibility[key] = gaussian_visibility(f["means"], f["quats"], f["scales"], f["opacities"], omega,
                                                        backend=backend)
        return self._visibility[key]

    def frame_sun(self, i: int) -> tuple[float, float]:
        """(zenith, azimuth) deg of training frame ``i``'s own sun (brfgs.data.sun), else the scene's."""
        fr = self.frames[i] if 0 <= i < len(self.frames) else {}
        if fr.get("sun_zenith_deg") is None:
            return self.sun_zenith_deg, self.sun_azimuth_deg
        return float(fr["sun_zenith_deg"]), float(fr["sun_azimuth_deg"])

    def sun_direction(self, sun_zenith_deg: float | None = None, sun_azimuth_deg: float | None = None) -> Tensor:
        """ω_i [3] (float32) for the given sun or the acquisition's."""
        z = self.sun_zenith_deg if sun_zenith_deg is None else sun_zenith_deg
        a = self.sun_azimuth_deg if sun_azimuth_deg is None else sun_azimuth_deg
        return sun_direction(float(z), float(a))

    def band_indices(self, wavelengths_nm) -> list[int]:
        """Indices of the bands nearest each requested wavelength; UserError outside the range."""
        wl = self.wavelengths_nm
        out = []
        for w in wavelengths_nm:
            w = float(w)
            if not math.isfinite(w) or w < wl.min() - 10 or w > wl.max() + 10:
                raise UserError(f"band {w:g} nm is outside the model's range {wl.min():.0f}-{wl.max():.0f} nm",
                                field="--bands")
            out.append(int(np.argmin(np.abs(wl - w))))
        return out

    def frame(self, name: str) -> dict:
        for fr in self.frames:
            if fr["name"] == name:
                return fr
        raise UserError(f"no training view named {name!r}; views: {', '.join(f['name'] for f in self.frames[:12])}"
                        + (" ..." if len(self.frames) > 12 else ""), field="--roi")

    def scene_centre_m(self) -> np.ndarray:
        """Median Gaussian position [3] (m): a robust scene centre."""
        return self.gaussians.means.detach().median(0).values.double().numpy()

    def typical_distance_m(self) -> float:
        """Median distance (m) of the training cameras to the median Gaussian position."""
        if not self.frames:
            return 100.0
        centre = self.scene_centre_m()
        return float(np.median([np.linalg.norm(np.asarray(f["c2w"])[:3, 3] - centre) for f in self.frames]))

    def scene_half_extent_m(self) -> float:
        """Half the horizontal 2–98 % extent of the Gaussians (m)."""
        p = self.gaussians.means.detach().double().numpy()
        lo, hi = np.percentile(p[:, :2], 2, 0), np.percentile(p[:, :2], 98, 0)
        return float(0.5 * np.max(hi - lo))

    # -- frozen tensors (rendering never changes the model) ----------------------------
    def frozen(self) -> dict[str, Tensor]:
        """Detached tensors computed once: means, scales, max_scale, quats, opacities and the
        head parameters (recomputed when a tensor of ``gaussians.params`` is replaced or edited)."""
        key = self._frozen_key()
        if self._frozen is None or self._frozen[0] != key:
            m = self.gaussians
            f = {k: v.detach() for k, v in m.params.items()}
            f["scales"] = m.scales.detach()
            f["max_scale"] = f["scales"].max(1).values
            f["opacities"] = m.opacities.detach()
            self._frozen = (key, f)
        return self._frozen[1]

    def _frozen_key(self) -> tuple:
        return tuple((k, id(v), v._version) for k, v in sorted(self.gaussians.params.items()))

    def head_params(self, idx: Tensor | None = None) -> dict[str, Tensor]:
        """Appearance tensors the head reads, rows ``idx`` (all if None)."""
        f = self.frozen()
        p = {k: f[k] for k in HEAD_PARAM_KEYS if k in f}
        if idx is None:
            return p
        if "_head_cat" not in f:  # one gather instead of one per tensor (ROI loops index thousands of rows)
            flat = {k: v.reshape(v.shape[0], -1) for k, v in p.items() if v.dtype == torch.float32}
            ok = len(flat) == len(p) and p
            f["_head_cat"] = (torch.cat(list(flat.values()), 1), [(k, p[k].shape[1:], v.shape[1]) for k, v in flat.items()]) \
                if ok else None
        cat = f["_head_cat"]
        if cat is None:
            return {k: v[idx] for k, v in p.items()}
        rows, out, o = cat[0][idx], {}, 0
        for k, shp, w in cat[1]:
            out[k] = rows[:, o:o + w].reshape((rows.shape[0],) + tuple(shp)).contiguous()
            o += w
        return out

    @torch.no_grad()
    def head_normals(self, omega_o: Tensor, idx: Tensor | None = None) -> Tensor:
        """Normals n_k [n, 3] the head uses for Gaussians ``idx`` (all if None), facing ω_o [n, 3]:
        the learned shading normals when the model has them, else the smallest axes."""
        f = self.frozen()

        def rows(t):
            return t if t is None or idx is None else t[idx]

        return shading_normals(rows(f["quats"]), rows(f["scales"]), omega_o, rows(f.get("normals")))

    @torch.no_grad()
    def gaussian_latent(self, omega_i: Tensor, omega_o: Tensor, idx: Tensor | None = None) -> Tensor:
        """Latent reflectance [n, d] (CIR colour [n, 3] for the CIR variant) of Gaussians ``idx``
        (all if None) for the sun ω_i [3] and view directions ω_o [n, 3] (eq. 12 or a baseline head)."""
        if self.appearance == "neural":
            f = self.frozen()
            feat = f["feat"] if idx is None else f["feat"][idx]
            return self.neural(feat, omega_o, omega_i.expand_as(omega_o))
        normals = self.head_normals(omega_o, idx) if self.head_cfg.needs_normals else None
        return evaluate_head(self.head_cfg, self.head_params(idx), normals, omega_i, omega_o)

    @torch.no_grad()
    def decode(self, latent: Tensor | np.ndarray) -> np.ndarray:
        """Decode latent vectors [..., d] to reflectance [..., B] (float32 numpy)."""
        if self.decoder is None:
            raise UserError("this model has no spectral decoder (CIR variant): no spectra to analyse", field="model")
        z = torch.as_tensor(latent if isinstance(latent, Tensor) else np.asarray(latent), dtype=torch.float32)
        return decode_image(self.decoder, z).numpy().astype(np.float32)

    # -- files -------------------------------------------------------------------------
    def tensors(self) -> dict[str, Tensor]:
        """Named tensors of the model file (prefixes: see :mod:`brfgs.model.io`)."""
        t = io.prefixed(self.gaussians.state(), "param.")
        t.update(io.prefixed({k: v.detach() for k, v in self.extra.items()}, "extra."))
        if self.decoder is not None:
            t.update(decoder_state(self.decoder, "decoder.")[0])
        if self.neural is not None:
            t.update(io.prefixed(self.neural.state_dict(), "neural."))
        return t

    def metadata(self) -> dict:
        """JSON metadata of the model file."""
        m = dict(self.meta)
        m.update({"config": self.config, "scene": self.scene, "appearance": self.appearance,
                  "latent_dim": self.gaussians.latent_dim, "n_colors": self.gaussians.n_colors,
                  "n_gaussians": self.gaussians.n,
                  "head": self.head_cfg.to_dict() if self.head_cfg is not None else {"kind": "neural", "hidden": 64}})
        for key in ("spectral_basis", *DESCRIPTION_KEYS.values()):
            m.pop(key, None)
        if self.decoder is not None:
            m.update(decoder_metadata(self.decoder))  # spectral_basis and the decoder's description
        return m

    def save(self, path: str | Path) -> Path:
        """Write ``path`` (model.safetensors) atomically."""
        tensors, meta = self.tensors(), self.metadata()
        check_written(tensors, meta, path)
        return io.save(path, tensors, meta)

    @classmethod
    def from_file_contents(cls, tensors: dict[str, Tensor], meta: dict, path: Path) -> "TrainedModel":
        """The model of a file's (tensors, meta) after validation (a model file or a checkpoint)."""
        check_metadata(meta, path)
        check_tensors(tensors, meta, path)
        try:
            gm = GaussianModel(io.with_prefix(tensors, "param."), meta["appearance"], meta["latent_dim"], meta["n_colors"])
            head_cfg = head_config_from_dict(meta["head"])
            decoder = decoder_from_state(tensors, meta, "decoder.") if meta["appearance"] != "cir" else None
            neural = None
            if meta["appearance"] == "neural" and any(k.startswith("neural.") for k in tensors):
                neural = NeuralHead(meta["latent_dim"])
                neural.load_state_dict(io.with_prefix(tensors, "neural."))
        except UserError as exc:
            raise UserError(exc.detail, file=path, field=exc.field) from None
        except (KeyError, ValueError, TypeError, RuntimeError) as exc:
            raise UserError(f"the tensors do not fit the model description ({exc})", file=path) from None
        gm.centred = meta.get("kernel_form") == "centred"
        extra = io.with_prefix(tensors, "extra.")
        return cls(gaussians=gm, head_cfg=head_cfg, decoder=decoder, scene=meta["scene"], config=meta["config"],
                   extra=extra, neural=neural, meta=meta, source=str(Path(path).resolve()))

    @classmethod
    def load(cls, path: str | Path) -> "TrainedModel":
        """A model from a run folder (its model.safetensors) or a model file; UserError naming the
        file and the field when it is missing or not a valid model."""
        p = Path(path)
        if p.is_dir():
            if not (p / MODEL_FILE).is_file():
                raise UserError(f"no {MODEL_FILE} in this folder (is the training finished?)", file=p)
            p = p / MODEL_FILE
        if not p.is_file():
            raise UserError("model file or run folder not found", file=p)
        tensors, meta = io.load(p)
        tm = cls.from_file_contents(tensors, meta, p)
        for v in tm.gaussians.params.values():
            v.requires_grad_(False)
        return tm
