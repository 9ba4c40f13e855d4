"""A trained BRF-GS model for analysis: load it, render any view under any sun.

:class:`BRFModel` holds what the analysis needs: the Gaussians (brfgs.model.GaussianModel),
the appearance head (brfgs.brdf.head.HeadConfig, or the neural head), the spectral decoder
(eq. 13), the learned latent background, wavelengths, the training sun, intrinsics and the
training frames (names, poses, split). :func:`load_model` reads it from a run folder or a
model file written by the trainer (brfgs.train.checkpoint: safetensors + JSON, never
executes code from the file).

Rendering follows the trainer's path exactly (brfgs.model.render): per-Gaussian latent
z_k(ω_i, ω_o) with ω_o = normalize(camera centre − μ_k), rasterized (premultiplied), the
latent background composited with (1 − α), decoded per pixel. Here the sun ω_i can be any
direction and a pixel subset can be decoded alone (ROI means).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from brfgs.data.cameras import Intrinsics, viewmat_from_c2w
from brfgs.errors import UserError

__all__ = ["torch_threads", "BRFModel", "RenderedView", "load_model", "frustum_subset", "render_features", "render_view"]


@dataclass
class RenderedView:
    """Planes of one rendered view (numpy). cube None unless decoded; latent [H,W,d] composited."""

    latent: np.ndarray | None
    cube: np.ndarray | None
    alpha: np.ndarray
    depth: np.ndarray
    normal: np.ndarray | None
    c2w: np.ndarray
    intr: Intrinsics
    timings_s: dict = field(default_factory=dict)


@dataclass
class BRFModel:
    """Everything the analysis needs from a trained model (see the module docstring)."""

    model: object                       # brfgs.model.gaussians.GaussianModel
    head_cfg: object | None             # brfgs.brdf.head.HeadConfig (None: neural head)
    decoder: object | None              # has .decode(z [..., d]) -> [..., B]; None for the CIR variant
    wavelengths_nm: np.ndarray
    sun_zenith_deg: float
    sun_azimuth_deg: float
    intrinsics: Intrinsics
    frames: list = field(default_factory=list)  # dicts: name, split, c2w, view_zenith_deg, view_azimuth_deg
    bg_latent: torch.Tensor | None = None
    neural: object | None = None
    cir_indices: tuple = (0, 0, 0)
    cir_scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    fwhm_nm: np.ndarray | None = None
    scene_root: str | None = None
    scene_name: str = "scene"
    source: str | None = None
    meta: dict = field(default_factory=dict)

    # -- properties -------------------------------------------------------------------
    @property
    def appearance(self) -> str:
        return self.model.appearance

    @property
    def spectral(self) -> bool:
        return self.decoder is not None and self.appearance != "cir"

    @property
    def n_gaussians(self) -> int:
        return self.model.n

    def sun_direction(self, sun_zenith_deg: float | None = None, sun_azimuth_deg: float | None = None) -> torch.Tensor:
        """ω_i [3] (float32) for the given sun or the training sun."""
        from brfgs.brdf.geometry import sun_direction

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

    def typical_distance_m(self) -> float:
        """Median distance (m) of the training cameras to the median Gaussian position."""
        centre = self.model.means.detach().median(0).values.double().numpy()
        if not self.frames:
            return 100.0
        d = [float(np.linalg.norm(np.asarray(f["c2w"])[:3, 3] - centre)) for f in self.frames]
        return float(np.median(d))

    def scene_centre_m(self) -> np.ndarray:
        """Median Gaussian position [3] (m) weighted by nothing (robust scene centre)."""
        return self.model.means.detach().median(0).values.double().numpy()

    def scene_half_extent_m(self) -> float:
        """Half the horizontal 2–98 % extent of the Gaussians (m)."""
        p = self.model.means.detach().double().numpy()
        lo, hi = np.percentile(p[:, :2], 2, 0), np.percentile(p[:, :2], 98, 0)
        return float(0.5 * np.max(hi - lo))

    # -- frozen tensors (the analysis never changes the model) ------------------------
    def frozen(self) -> dict[str, torch.Tensor]:
        """Detached tensors computed once: means, scales, max_scale, quats, opacities and the
        head parameters (call :meth:`invalidate` after editing ``model.params``)."""
        key = tuple((k, id(v), v._version) for k, v in sorted(self.model.params.items()))
        if getattr(self, "_frozen_key", None) != key:
            m = self.model
            f = {k: v.detach() for k, v in m.params.items()}
            f["scales"] = m.scales.detach()
            f["max_scale"] = f["scales"].max(1).values
            f["opacities"] = m.opacities.detach()
            self._frozen = f
            self._frozen_key = key
        return self._frozen

    def invalidate(self) -> None:
        self._frozen_key = None

    # -- per-Gaussian appearance ------------------------------------------------------
    def head_params(self, idx: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        keys = ("z_iso", "z_vol", "z_geo", "z_spec", "rho_raw", "sh", "color")
        f = self.frozen()
        p = {k: f[k] for k in keys if k in f}
        if idx is None:
            return p
        if "_head_cat" not in f:  # one gather instead of one per tensor (ROI loops index thousands of rows)
            flat = {k: v.reshape(v.shape[0], -1) for k, v in p.items() if v.dtype == torch.float32}
            if len(flat) == len(p) and p:
                f["_head_cat"] = (torch.cat(list(flat.values()), 1),
                                  [(k, p[k].shape[1:], v.shape[1]) for k, v in flat.items()])
            else:
                f["_head_cat"] = None
        cat = f["_head_cat"]
        if cat is None:
            return {k: v[idx] for k, v in p.items()}
        rows = cat[0][idx]
        out, o = {}, 0
        for k, shp, w in cat[1]:
            out[k] = rows[:, o:o + w].reshape((rows.shape[0],) + tuple(shp))
            o += w
        return out

    @torch.no_grad()
    def head_normals(self, omega_o: torch.Tensor, idx: torch.Tensor | None = None) -> torch.Tensor:
        """Normals n_k [n, 3] the head uses for Gaussians ``idx`` (all if None), facing ω_o [n, 3]:
        the learned shading normals when the model has them, else the smallest axes."""
        from brfgs.brdf.geometry import shading_normals

        f = self.frozen()

        def rows(t):
            return None if t is None else (t if idx is None else t[idx])

        return shading_normals(rows(f["quats"]), rows(f["scales"]), omega_o, rows(f.get("normals")))

    @torch.no_grad()
    def gaussian_latent(self, omega_i: torch.Tensor, omega_o: torch.Tensor, idx: torch.Tensor | None = None
                        ) -> torch.Tensor:
        """Latent reflectance [n, d] of Gaussians ``idx`` (all if None) for ω_i [3], ω_o [n, 3]."""
        f = self.frozen()
        if self.appearance == "neural":
            feat = f["feat"] if idx is None else f["feat"][idx]
            return self.neural(feat, omega_o, omega_i.expand_as(omega_o))
        from brfgs.brdf.head import evaluate_head

        normals = self.head_normals(omega_o, idx) if self.head_cfg.needs_normals else None
        return evaluate_head(self.head_cfg, self.head_params(idx), normals, omega_i, omega_o)

    @torch.no_grad()
    def decode(self, latent: torch.Tensor | np.ndarray, chunk: int = 1 << 15) -> np.ndarray:
        """Decode latent vectors [..., d] to reflectance [..., B] (float32 numpy)."""
        if self.decoder is None:
            raise UserError("this model has no spectral decoder (CIR variant): no spectra to analyse", field="model")
        z = torch.as_tensor(np.asarray(latent) if not isinstance(latent, torch.Tensor) else latent, dtype=torch.float32)
        shp = z.shape[:-1]
        flat = z.reshape(-1, z.shape[-1])
        outs = [self.decoder.decode(flat[i:i + chunk]) for i in range(0, flat.shape[0], chunk)] or \
            [self.decoder.decode(flat)]
        return torch.cat(outs, 0).reshape(*shp, -1).numpy().astype(np.float32)


class torch_threads:
    """Context manager: run with ``n`` PyTorch threads (loops over many small tensors run
    fastest single-threaded on a shared machine), then restore the previous count."""

    def __init__(self, n: int | None):
        self.n = n
        self.prev = None

    def __enter__(self):
        if self.n:
            self.prev = torch.get_num_threads()
            torch.set_num_threads(int(self.n))
        return self

    def __exit__(self, *exc):
        if self.prev is not None:
            torch.set_num_threads(self.prev)
        return False


# ----------------------------------------------------------------------------------------
# loading


def load_model(path: str | Path) -> BRFModel:
    """Load a trained model from a run folder (its model.safetensors) or a model file.

    Uses the trainer's loader (brfgs.train.trainer.LoadedModel): safetensors, no code runs.
    """
    p = Path(path)
    if p.is_dir():
        cand = p / "model.safetensors"
        if not cand.is_file():
            raise UserError("no model.safetensors in this folder (is the training finished?)", file=p)
        p = cand
    if not p.is_file():
        raise UserError("model file or run folder not found", file=p)
    from brfgs.train.trainer import LoadedModel

    lm = LoadedModel(p)
    sc = lm.scene
    intr = Intrinsics(**{k: (int(v) if k in ("w", "h") else float(v)) for k, v in sc["intrinsics"].items()})
    decoder = lm.decoder if lm.spectral else None
    head_cfg = lm.head_cfg
    model = lm.model
    for v in model.params.values():
        v.requires_grad_(False)
    return BRFModel(
        model=model, head_cfg=head_cfg, decoder=decoder,
        wavelengths_nm=np.asarray(sc["wavelengths_nm"], float),
        sun_zenith_deg=float(sc["sun_zenith_deg"]), sun_azimuth_deg=float(sc["sun_azimuth_deg"]),
        intrinsics=intr, frames=list(sc.get("frames", [])),
        bg_latent=(lm.extra.get("bg_latent").detach() if lm.extra.get("bg_latent") is not None else None),
        neural=lm.neural, cir_indices=tuple(lm.cir_indices), cir_scale=np.asarray(lm.cir_scale, float),
        fwhm_nm=None if sc.get("fwhm_nm") is None else np.asarray(sc["fwhm_nm"], float),
        scene_root=sc.get("root"), scene_name=sc.get("name", "scene"), source=str(p.resolve()), meta=lm.meta,
    )


# ----------------------------------------------------------------------------------------
# rendering


def frustum_subset(means: torch.Tensor, max_scale: torch.Tensor, c2w: np.ndarray, intr: Intrinsics,
                   margin_sigma: float = 3.0) -> torch.Tensor:
    """Indices of Gaussians that can touch the image: in front of the camera and within the
    image grown by ``margin_sigma`` × their largest scale (a superset of what the rasterizer keeps)."""
    vm = torch.as_tensor(viewmat_from_c2w(c2w), dtype=means.dtype)
    pc = means @ vm[:3, :3].T + vm[:3, 3]                      # [N, 3]
    z = pc[:, 2]
    zs = z.clamp_min(1e-6)
    r = margin_sigma * max_scale
    u = intr.fl_x * pc[:, 0] / zs + intr.cx
    v = intr.fl_y * pc[:, 1] / zs + intr.cy
    ru = intr.fl_x * r / zs + 2.0
    rv = intr.fl_y * r / zs + 2.0
    ok = (z > 0.01) & (u + ru >= 0) & (u - ru <= intr.w) & (v + rv >= 0) & (v - rv <= intr.h)
    # Gaussians straddling the camera plane cannot be projected reliably; 3DGS drops them too.
    return torch.nonzero(ok).squeeze(1)


@torch.no_grad()
def render_features(bm: BRFModel, features_fn, c2w: np.ndarray, intr: Intrinsics, *, backend: str = "auto",
                    want_normals: bool = False, cull: bool = True):
    """Rasterize per-Gaussian features for one camera.

    ``features_fn(idx [n] long, omega_o [n, 3]) -> [n, C]`` gives the features of the
    Gaussians kept after frustum culling. Returns brfgs.render.RenderOutput.
    """
    from brfgs.render import rasterize

    f = bm.frozen()
    means = f["means"]
    scales = f["scales"]
    if cull:
        idx = frustum_subset(means, f["max_scale"], c2w, intr)
    else:
        idx = torch.arange(means.shape[0])
    centre = torch.as_tensor(np.asarray(c2w, float)[:3, 3], dtype=means.dtype)
    mu = means[idx]
    d = centre[None] - mu
    omega_o = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)  # [n, 3]
    feats = features_fn(idx, omega_o).to(means.dtype).contiguous()
    normals = None
    if want_normals:
        from brfgs.brdf.geometry import gaussian_normals

        normals = gaussian_normals(f["quats"][idx], scales[idx], omega_o).contiguous()
    vm = torch.as_tensor(viewmat_from_c2w(c2w), dtype=torch.float32)
    K = torch.as_tensor(intr.K(), dtype=torch.float32)
    if idx.numel() == 0:
        h, w = intr.h, intr.w
        from brfgs.render import RenderOutput

        z = torch.zeros(h, w)
        return RenderOutput(torch.zeros(h, w, feats.shape[1]), z, z.clone(),
                            torch.zeros(h, w, 3) if want_normals else None, {"backend": "none"})
    return rasterize(mu.contiguous(), f["quats"][idx].contiguous(), scales[idx].contiguous(),
                     f["opacities"][idx].contiguous(), feats, vm, K, intr.w, intr.h, backend=backend,
                     normals=normals)


@torch.no_grad()
def render_view(bm: BRFModel, c2w: np.ndarray, intr: Intrinsics, *, sun_zenith_deg: float | None = None,
                sun_azimuth_deg: float | None = None, decode: bool = True, want_normals: bool = True,
                backend: str = "auto") -> RenderedView:
    """Render the model from camera ``c2w`` (OpenGL c2w) under the given sun (default: training sun).

    Returns latent (background composited), decoded cube [H, W, B] (when ``decode``), alpha,
    depth (metres along the optical axis, 0 where nothing), unit normals [H, W, 3] (world,
    facing the camera; 0 where alpha = 0) and timings.
    """
    import time

    t0 = time.perf_counter()
    omega_i = bm.sun_direction(sun_zenith_deg, sun_azimuth_deg)

    if bm.appearance == "cir" or bm.decoder is None:
        def fn(idx, oo):
            from brfgs.brdf.head import evaluate_head

            return evaluate_head(bm.head_cfg, bm.head_params(idx), None, omega_i, oo)
    else:
        def fn(idx, oo):
            return bm.gaussian_latent(omega_i, oo, idx)

    out = render_features(bm, fn, c2w, intr, backend=backend, want_normals=want_normals)
    t1 = time.perf_counter()
    img = out.image
    if bm.bg_latent is not None and bm.spectral:
        img = img + (1.0 - out.alpha)[..., None] * bm.bg_latent.to(img.dtype)
    latent = img.numpy().astype(np.float32)
    cube = None
    if decode and bm.spectral:
        hit = out.alpha > 0
        if bool(hit.all()) or bm.bg_latent is None:
            cube = bm.decode(img)
        else:  # pixels showing only the background share one decoded spectrum
            bg = bm.decode(bm.bg_latent.to(img.dtype)[None])[0]
            cube = np.broadcast_to(bg, img.shape[:2] + bg.shape).copy()
            if bool(hit.any()):
                cube[hit.numpy()] = bm.decode(img[hit])
    t2 = time.perf_counter()
    normal = None
    if out.normal is not None:
        n = out.normal.numpy().astype(np.float64)
        nn = np.linalg.norm(n, axis=-1, keepdims=True)
        normal = np.where(nn > 1e-8, n / np.maximum(nn, 1e-12), 0.0).astype(np.float32)
    return RenderedView(latent=latent, cube=cube, alpha=out.alpha.numpy(), depth=out.depth.numpy(), normal=normal,
                        c2w=np.asarray(c2w, float), intr=intr,
                        timings_s={"rasterize_s": t1 - t0, "decode_s": t2 - t1, "total_s": t2 - t0})
