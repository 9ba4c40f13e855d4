"""BRF-GS training: setup (bands, init, autoencoder), stage 1, stage 2, checkpoints, resume.

Phases (paper section 3.3):
- ``stage1`` (eq. 24): geometry mu, Sigma, o and per-Gaussian reflectance of the selected
  bands, (1 - alpha) L1 + alpha D-SSIM, with 3DGS densification.
- ``stage2`` (eqs. 25-27): geometry frozen; the appearance head (hybrid kernels, SH,
  neural) in the autoencoder's latent space is rendered, decoded per pixel and fitted on
  all bands with (1 - beta) L_refl + beta L_cos (decoder fine-tuning optional).
- ``joint`` (--joint, Table 4): everything at once from the start, stage-2 loss plus
  alpha D-SSIM on the selected bands, densification as in stage 1.
- ``cir`` (3DGS baseline): SH degree 3 on CIR composites, L1 + D-SSIM, one phase.

Run folder ``OUT``: config.json, split.json, bands.json, init/ (points, cameras, report),
autoencoder.json, checkpoints/last.safetensors (resume state), checkpoints/stage1.safetensors,
model.safetensors (final), train_log.csv, run.json (status). Rerunning on an unfinished OUT
resumes from the last checkpoint; a finished OUT is refused without ``overwrite``.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from brfgs.errors import UserError
from brfgs.model.densify import DensifyState, accumulate, refine, reset_opacity
from brfgs.model.gaussians import GaussianModel, init_from_points, scene_extent, surface_fill
from brfgs.model.optim import NamedAdam
from brfgs.model.render import (
    camera_depth_normals,
    camera_depth_squared,
    stage1_colors,
    Camera,
    NeuralHead,
    camera_from_c2w,
    composite_background,
    decode_image,
    gaussian_features,
    rasterize_features,
)
from brfgs.train import checkpoint as ckpt
from brfgs.train.config import TrainConfig
from brfgs.train.losses import (depth_concentration_loss, depth_normal_loss, depth_smoothness_loss, flatten_loss,
                                 masked_psnr, normal_smoothness_loss, stage1_loss, stage2_loss)

RUN_FILE = "run.json"
MODEL_FILE = "model.safetensors"
LAST_CKPT = "checkpoints/last.safetensors"
STAGE1_CKPT = "checkpoints/stage1.safetensors"
OWNED_OUTPUTS = ("config.json", "split.json", "bands.json", "autoencoder.json", "train_log.csv", RUN_FILE,
                 MODEL_FILE, "checkpoints", "init", "metrics.json", "eval")


# ----------------------------------------------------------------------------------------------
# images
# ----------------------------------------------------------------------------------------------
class ImageStore:
    """Training targets of some frames: cached in memory up to a byte budget, else read per use.

    ``get(i)`` -> (image [H, W, C] float32 tensor with invalid pixels zeroed, valid [H, W] bool).
    ``transform`` maps a loaded cube [H, W, b] (numpy) to the stored target (e.g. CIR composite).
    """

    def __init__(self, scene, indices, bands=None, cache_gib: float = 4.0, transform=None):
        self.scene = scene
        self.bands = None if bands is None else [int(b) for b in bands]
        self.transform = transform
        self.cache: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        nb = scene.n_bands if bands is None else len(bands)
        total = len(indices) * scene.width * scene.height * nb * 4
        self.cached = total <= cache_gib * 2**30
        self.indices = list(indices)

    def _load(self, i: int):
        cube = self.scene.load_image(i, bands=self.bands)
        if self.transform is not None:
            cube = self.transform(cube)
        cube = np.asarray(cube, np.float32)
        valid = np.isfinite(cube).all(-1)
        img = torch.from_numpy(np.where(valid[..., None], cube, 0.0).astype(np.float32))
        return img, torch.from_numpy(valid)

    def get(self, i: int):
        if i in self.cache:
            return self.cache[i]
        out = self._load(i)
        if self.cached:
            self.cache[i] = out
        return out

    def preload(self, progress: bool = False) -> None:
        if not self.cached:
            return
        it = self.indices
        if progress:
            from tqdm import tqdm

            it = tqdm(it, desc="loading images", leave=False)
        for i in it:
            self.get(i)


# ----------------------------------------------------------------------------------------------
# scene description stored in model files
# ----------------------------------------------------------------------------------------------
def scene_description(scene, c2w: np.ndarray) -> dict:
    """JSON-ready description of the scene as trained (self-describing model files)."""
    intr = scene.intrinsics
    return {
        "name": scene.name,
        "root": str(Path(scene.root).resolve()),
        "wavelengths_nm": [float(w) for w in scene.wavelengths_nm],
        "fwhm_nm": None if scene.fwhm_nm is None else [float(w) for w in scene.fwhm_nm],
        "sun_zenith_deg": float(scene.sun_zenith_deg),
        "sun_azimuth_deg": float(scene.sun_azimuth_deg),
        "intrinsics": {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h},
        "downscale": int(getattr(scene, "downscale", 1)),
        "roi": getattr(scene, "roi", None),
        "split": scene.split_record(),
        "frames": [
            {
                "name": f.name,
                "split": f.split,
                "c2w": np.asarray(c2w[i], float).tolist(),
                "view_zenith_deg": float(f.view_zenith_deg),
                "view_azimuth_deg": float(f.view_azimuth_deg),
            }
            for i, f in enumerate(scene.frames)
        ],
    }


def cameras_from_description(desc: dict) -> list[Camera]:
    intr = desc["intrinsics"]
    K = np.array([[intr["fl_x"], 0, intr["cx"]], [0, intr["fl_y"], intr["cy"]], [0, 0, 1]], np.float64)
    return [camera_from_c2w(fr["name"], np.array(fr["c2w"]), K, intr["w"], intr["h"]) for fr in desc["frames"]]


def sun_dir_from_description(desc: dict) -> torch.Tensor:
    from brfgs.data.angles import direction_from_angles_deg

    return torch.as_tensor(np.asarray(direction_from_angles_deg(desc["sun_zenith_deg"], desc["sun_azimuth_deg"])), dtype=torch.float32)


def head_config(cfg: TrainConfig):
    """brfgs.brdf HeadConfig of a variant (None for the neural head)."""
    from brfgs.brdf.head import HeadConfig

    if cfg.variant == "brf":
        return HeadConfig(kind="hybrid", components=tuple(cfg.components))
    if cfg.variant in ("sh", "cir"):
        return HeadConfig(kind="sh", sh_degree=3)
    return None


# ----------------------------------------------------------------------------------------------
# loaded models (for evaluate / render)
# ----------------------------------------------------------------------------------------------
class LoadedModel:
    """A trained model file: Gaussians, appearance head, decoder and the scene description."""

    def __init__(self, path: str | Path):
        from brfgs.spectral.autoencoder import autoencoder_from_state

        tensors, meta = ckpt.load(path)
        self.path = Path(path)
        self.meta = meta
        self.cfg = TrainConfig.from_dict(meta["config"])
        self.scene = meta["scene"]
        params = ckpt.with_prefix(tensors, "param.")
        self.model = GaussianModel(params, meta["appearance"], meta["latent_dim"], meta["n_colors"])
        self.extra = ckpt.with_prefix(tensors, "extra.")
        self.decoder = autoencoder_from_state(tensors, meta, "decoder.") if "autoencoder" in meta else None
        self.neural = None
        if meta["appearance"] == "neural":
            self.neural = NeuralHead(meta["latent_dim"])
            self.neural.load_state_dict(ckpt.with_prefix(tensors, "neural."))
        self.head_cfg = head_config(self.cfg)
        self.cameras = cameras_from_description(self.scene)
        self.sun_dir = sun_dir_from_description(self.scene)
        self.wavelengths_nm = np.array(self.scene["wavelengths_nm"])
        self.cir_indices = tuple(meta["cir_indices"])
        self.cir_scale = np.array(meta["cir_scale"])

    @property
    def spectral(self) -> bool:
        return self.meta["appearance"] != "cir"

    @torch.no_grad()
    def render(self, cam: Camera, backend: str = "auto") -> dict:
        """{"cube": [H,W,B] reflectance (None for cir), "cir": [H,W,3], "alpha", "depth"} numpy."""
        feats = gaussian_features(self.model, cam, self.sun_dir, self.head_cfg, self.neural)
        out = rasterize_features(self.model, feats, cam, backend)
        from brfgs.data.cir import cir_composite

        if self.spectral:
            lat = composite_background(out.image, out.alpha, self.extra.get("bg_latent"))
            cube = decode_image(self.decoder, lat).numpy()
            cir = cir_composite(cube, self.cir_indices, self.cir_scale)
        else:
            img = composite_background(out.image, out.alpha, self.extra.get("bg_colors"))
            cube = None
            cir = img.clamp(0, 1).numpy()
        return {"cube": cube, "cir": cir, "alpha": out.alpha.numpy(), "depth": out.depth.numpy()}


# ----------------------------------------------------------------------------------------------
# the trainer
# ----------------------------------------------------------------------------------------------
class Trainer:
    """One training run in ``out_dir`` (see the module docstring)."""

    def __init__(self, scene_path, out_dir, cfg: TrainConfig, overwrite: bool = False, progress: bool = True,
                 callback=None, from_stage1: str | Path | None = None, log=print):
        self.scene_path = Path(scene_path)
        self.out = Path(out_dir)
        self.cfg = cfg.validate()
        self.overwrite = overwrite
        self.progress = progress
        self.callback = callback
        self.from_stage1 = Path(from_stage1) if from_stage1 else None
        self.log = log or (lambda *a, **k: None)
        self.model: GaussianModel | None = None
        self.extra: dict[str, torch.Tensor] = {}
        self.neural: NeuralHead | None = None
        self.decoder = None
        self.opt = NamedAdam({})
        self.dstate: DensifyState | None = None
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.phase = ""
        self.step = 0
        self.meta: dict = {}
        self.timings: dict[str, float] = {}
        self.history: list[tuple[str, int, float, float]] = []  # (phase, step, loss, psnr) of this session

    # -------------------------------------------------------------------------------- phases
    def phases(self) -> list[tuple[str, int]]:
        c = self.cfg
        if c.variant == "cir":
            return [("cir", c.total_steps)]
        if c.joint:
            return [("joint", c.total_steps)]
        return [("stage1", c.stage1_steps), ("stage2", c.stage2_steps)]

    # -------------------------------------------------------------------------------- entry
    def run(self) -> Path:
        """Train (or resume) to the end; returns the path of model.safetensors."""
        from brfgs.data import read_scene

        if self.cfg.threads > 0:
            torch.set_num_threads(self.cfg.threads)
            try:
                from brfgs.render import configure_threads

                configure_threads(self.cfg.threads)
            except Exception:
                pass
        self._prepare_out()
        self.scene = read_scene(self.scene_path, downscale=self.cfg.downscale, split_seed=self.cfg.split_seed,
                                value_range=tuple(self.cfg.value_range))
        last = self.out / LAST_CKPT
        t0 = time.perf_counter()
        if last.is_file():
            self._load_checkpoint(last)
            self.log(f"resuming {self.out} at {self.phase} step {self.step}")
        elif self.from_stage1 is not None:
            self._load_checkpoint(self.from_stage1, reuse_stage1=True)
            self._save_checkpoint()
        else:
            self._setup()
            self._save_checkpoint()
        self._write_run("running")
        names = [p for p, _ in self.phases()]
        try:
            while self.phase != "done":
                steps = dict(self.phases())[self.phase]
                tp = time.perf_counter()
                self._run_phase(self.phase, steps)
                self.timings[self.phase] = self.timings.get(self.phase, 0.0) + time.perf_counter() - tp
                nxt = names[names.index(self.phase) + 1] if names.index(self.phase) + 1 < len(names) else "done"
                if self.phase == "stage1":
                    self._save_checkpoint(self.out / STAGE1_CKPT)
                self._begin_phase(nxt)
                self._save_checkpoint()
        except KeyboardInterrupt:
            self._save_checkpoint()
            self._write_run("interrupted")
            self.log(f"interrupted: checkpoint saved at {self.phase} step {self.step}; rerun the same command to resume")
            raise
        self.timings["total_this_session"] = time.perf_counter() - t0
        path = self._save_model()
        self._write_run("finished")
        return path

    # -------------------------------------------------------------------------------- out dir
    def _prepare_out(self) -> None:
        run = self.out / RUN_FILE
        if run.is_file():
            status = json.loads(run.read_text()).get("status")
            if status == "finished" and not self.overwrite:
                raise UserError("a finished training run exists here; pass --overwrite to replace it "
                                "(or choose another output folder)", file=self.out)
            if self.overwrite:  # remove only what a training run writes
                for name in OWNED_OUTPUTS:
                    p = self.out / name
                    if p.is_dir():
                        shutil.rmtree(p)
                    elif p.exists():
                        p.unlink()
        elif self.out.exists() and any(self.out.iterdir()) and not (self.out / LAST_CKPT).exists():
            foreign = [p.name for p in self.out.iterdir() if p.name not in OWNED_OUTPUTS]
            if foreign:
                raise UserError(f"output folder is not empty and is not a brfgs run (contains {foreign[:5]}); "
                                "choose an empty or new folder", file=self.out)
        self.out.mkdir(parents=True, exist_ok=True)
        if (self.out / "config.json").is_file() and (self.out / LAST_CKPT).is_file():
            old = json.loads((self.out / "config.json").read_text())
            if old != json.loads(self.cfg.to_json()):
                diff = sorted(k for k in set(old) | set(self.cfg.to_dict()) if old.get(k) != json.loads(self.cfg.to_json()).get(k))
                raise UserError(f"this unfinished run was started with different options ({', '.join(diff)}); "
                                "rerun with the same options to resume, or pass --overwrite", file=self.out / "config.json")
        (self.out / "config.json").write_text(json.dumps(self.cfg.to_dict(), indent=1, sort_keys=True))

    def _write_run(self, status: str) -> None:
        info = {"status": status, "phase": self.phase, "step": self.step, "config": self.cfg.to_dict(),
                "scene": str(self.scene_path.resolve()), "timings_s": self.timings,
                "n_gaussians": self.model.n if self.model is not None else None,
                "model": MODEL_FILE if status == "finished" else None}
        tmp = self.out / (RUN_FILE + ".tmp")
        tmp.write_text(json.dumps(info, indent=1))
        tmp.replace(self.out / RUN_FILE)

    # -------------------------------------------------------------------------------- setup
    def _setup(self) -> None:
        """Band selection, initialisation, autoencoder and the initial Gaussians."""
        from brfgs.bands import select_bands
        from brfgs.data.cir import cir_band_indices, cir_scale
        from brfgs.init import initialize

        sc, cfg = self.scene, self.cfg
        t = time.perf_counter()
        (self.out / "split.json").write_text(json.dumps(sc.split_record(), indent=1))
        sel = select_bands(sc, strategy=cfg.band_strategy, top=cfg.top, progress=self.progress)
        (self.out / "bands.json").write_text(json.dumps(sel.to_json(), indent=1))
        bands = [int(b) for b in sel.selected]
        self.timings["bands"] = time.perf_counter() - t
        self.log(f"bands: {cfg.band_strategy} -> {[round(float(sc.wavelengths_nm[b]), 1) for b in bands]} nm")
        t = time.perf_counter()
        init = initialize(sc, bands, poses=cfg.poses, out_dir=self.out / "init", selection=sel, progress=self.progress)
        self.timings["init"] = time.perf_counter() - t
        self.log(f"init: {init.points.shape[0]} points ({init.report.get('poses', cfg.poses)})")
        cir_idx = cir_band_indices(sc.wavelengths_nm)
        cir_sc = cir_scale(sc)
        # stage 1 fits the selected bands and, by default, the CIR bands (green, red, NIR): the selected
        # bands make SfM reliable, the CIR bands carry the visible texture that the composites show
        s1 = sorted(set(bands) | {int(i) for i in cir_idx}) if cfg.stage1_cir_bands else bands
        self.meta = {
            "scene": scene_description(sc, init.c2w),
            "bands": bands,
            "stage1_bands": s1,
            "cir_indices": list(cir_idx),
            "cir_scale": [float(v) for v in cir_sc],
            "extent_m": scene_extent(init.points),
        }
        pts, cols = np.asarray(init.points, np.float64), np.asarray(init.colors, np.float64)
        if cfg.init_fill_points > 0:
            cover, seen = self._ground_footprints(pts, init.c2w)
            extra = surface_fill(pts, cfg.init_fill_points, cover_xy=cover, keep=seen)
            if extra.shape[0]:
                pts = np.concatenate([pts, extra], 0)
                cols = np.concatenate([cols, np.full((extra.shape[0], cols.shape[1]), np.nan)], 0)
            self.log(f"init: +{extra.shape[0]} surface-fill points")
        if s1 != bands:  # colours of the extra bands come from the images below
            cols = np.full((cols.shape[0], len(s1)), np.nan)
        self.model = init_from_points(pts, np.nan_to_num(cols), cfg.latent_dim, cfg.init_opacity)
        if cfg.init_fill_points > 0 or s1 != bands:  # colours of every Gaussian from the images it projects into
            with torch.no_grad():
                self.model.params["colors"].copy_(self._backprojected_targets("colors", encode=False))
        if cfg.stage1_sh_degree > 0:  # view-dependent stage-1 colours (3DGS-style SH rest terms)
            from brfgs.brdf.sh import num_sh_bases

            k = self.model["colors"].shape[1]
            self.model.params["colors_rest"] = torch.zeros(self.model.n, num_sh_bases(cfg.stage1_sh_degree) - 1, k,
                                                           requires_grad=True)
        self.dstate = DensifyState(self.model.n)
        bg = np.nanmean(init.colors, 0) if s1 == bands else self.model["colors"].detach().mean(0).numpy()  # [C]
        self.extra = {"bg_colors": torch.as_tensor(bg, dtype=torch.float32).requires_grad_(True)}
        # spectral autoencoder (not for the CIR-only baseline)
        if cfg.variant != "cir":
            t = time.perf_counter()
            self._train_autoencoder()
            self.timings["autoencoder"] = time.perf_counter() - t
        if cfg.variant == "cir" or cfg.joint:
            self._init_head()
        self.phase = self.phases()[0][0]
        self.step = 0

    def _ground_footprints(self, pts: np.ndarray, c2w: np.ndarray):
        """Where the training images see the ground: (xy [Q, 2] of their border rays on the plane at the
        points' median height, keep(xyz [M, 3]) -> bool [M]: inside at least one training image)."""
        from brfgs.data.cameras import pixel_rays, project_points

        sc = self.scene
        z0 = float(np.median(pts[:, 2]))
        cover = []
        for i in sc.train_indices:
            o, d = pixel_rays(c2w[i], sc.intrinsics)
            border = np.concatenate([o[0], o[-1], o[:, 0], o[:, -1]]), np.concatenate([d[0], d[-1], d[:, 0], d[:, -1]])
            down = border[1][:, 2] < -1e-3
            t = (z0 - border[0][down, 2]) / border[1][down, 2]
            cover.append((border[0][down] + t[:, None] * border[1][down])[:, :2])
        cover = np.concatenate(cover, 0) if cover else np.zeros((0, 2))

        def seen(xyz: np.ndarray) -> np.ndarray:
            ok = np.zeros(xyz.shape[0], bool)
            for i in sc.train_indices:
                uv, depth = project_points(xyz, c2w[i], sc.intrinsics)
                uv, depth = np.asarray(uv), np.asarray(depth)
                ok |= (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < sc.width) & (uv[:, 1] < sc.height)
            return ok

        return cover, seen

    def _train_stores(self):
        if not hasattr(self, "_stores"):
            self._stores = {}
        return self._stores

    def _stage1_bands(self) -> list[int]:
        """Band indices that stage 1 fits (runs made before stage1_cir_bands existed: the selected bands)."""
        return list(self.meta.get("stage1_bands", self.meta["bands"]))

    def store(self, kind: str) -> ImageStore:
        """Image store of the training frames: "colors" (stage-1 bands), "full" (all), "cir"."""
        stores = self._train_stores()
        if kind not in stores:
            sc = self.scene
            if kind == "colors":
                s = ImageStore(sc, sc.train_indices, bands=self._stage1_bands(), cache_gib=self.cfg.cache_gib)
            elif kind == "full":
                s = ImageStore(sc, sc.train_indices, bands=None, cache_gib=self.cfg.cache_gib)
            else:
                from brfgs.data.cir import cir_composite

                idx, scale = self.meta["cir_indices"], np.array(self.meta["cir_scale"])
                s = ImageStore(sc, sc.train_indices, bands=idx, cache_gib=self.cfg.cache_gib,
                               transform=lambda cube: cir_composite(cube, (0, 1, 2), scale))
            stores[kind] = s
        return stores[kind]

    def _train_autoencoder(self) -> None:
        from brfgs.spectral.autoencoder import AutoencoderConfig, evaluate_autoencoder, sample_pixels, train_autoencoder

        sc, cfg = self.scene, self.cfg
        full = self.store("full")
        loaders = [(lambda i=i: full.get(i)[0].numpy() * np.where(full.get(i)[1].numpy()[..., None], 1.0, np.nan))
                   for i in sc.train_indices]
        pix = sample_pixels(loaders, cfg.ae_max_pixels, cfg.seed)
        acfg = AutoencoderConfig(latent_dim=cfg.latent_dim, steps=cfg.ae_steps, batch_size=cfg.ae_batch,
                                 max_pixels=cfg.ae_max_pixels, seed=cfg.seed)
        self.decoder, hist = train_autoencoder(pix, acfg, progress=self.progress)
        report = {"config": acfg.__dict__, "loss_first": hist[0] if hist else None, "loss_last": hist[-1] if hist else None,
                  "train": evaluate_autoencoder(self.decoder, pix)}
        if sc.test_indices:
            test = [(lambda i=i: sc.load_image(i)) for i in sc.test_indices]
            report["test"] = evaluate_autoencoder(self.decoder, sample_pixels(test, min(cfg.ae_max_pixels, 50_000), cfg.seed + 1))
        (self.out / "autoencoder.json").write_text(json.dumps(report, indent=1))
        self.meta["autoencoder_report"] = report
        te = report.get("test", report["train"])
        self.log(f"autoencoder d={cfg.latent_dim}: test SAM {te['sam_mean_rad']:.4f} rad, RMSE {te['rmse']:.5f}")

    # -------------------------------------------------------------------------------- head init
    @torch.no_grad()
    def _projected_targets(self, kind: str) -> torch.Tensor:
        """Mean observed target [N, C] at each Gaussian centre over the training views (no occlusion test)."""
        means = self.model.means.detach()
        st = self.store(kind)
        cams = self.cameras()
        acc = None
        cnt = torch.zeros(means.shape[0])
        for i in self.scene.train_indices:
            img, valid = st.get(i)
            cam = cams[i]
            pc = means @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
            z = pc[:, 2]
            u = cam.K[0, 0] * pc[:, 0] / z.clamp_min(1e-6) + cam.K[0, 2]
            v = cam.K[1, 1] * pc[:, 1] / z.clamp_min(1e-6) + cam.K[1, 2]
            ui, vi = torch.floor(u).long(), torch.floor(v).long()
            ok = (z > 0) & (ui >= 0) & (vi >= 0) & (ui < cam.width) & (vi < cam.height)
            uic, vic = ui.clamp(0, cam.width - 1), vi.clamp(0, cam.height - 1)
            ok &= valid[vic, uic]
            vals = img[vic, uic]
            if acc is None:
                acc = torch.zeros(means.shape[0], vals.shape[1])
            acc += vals * ok[:, None]
            cnt += ok
        mean_all = (acc.sum(0) / cnt.sum().clamp_min(1))
        out = acc / cnt.clamp_min(1)[:, None]
        out[cnt == 0] = mean_all
        return out

    def _backprojected_targets(self, kind: str, encode: bool) -> torch.Tensor:
        """Per-Gaussian mean target [N, C] weighted by the rendering weights (occlusion-aware).

        For each training view, d/df of sum_p <image_p(f), t_p> is sum_p w_kp t_p, so one
        rasterization + backward per view accumulates sum_p w_kp t_p and sum_p w_kp (an extra
        channel of ones); the ratio is the blending-weighted mean of the pixels Gaussian k
        contributes to. Targets are latent-encoded first when ``encode``. Gaussians that no
        view sees fall back to the centre-projection mean (:meth:`_projected_targets`).
        """
        from brfgs.render import rasterize

        m = self.model
        st = self.store(kind)
        cams = self.cameras()
        means, quats, scales, opac = (m.means.detach(), m.quats.detach(), m.scales.detach(), m.opacities.detach())
        acc = None
        for i in self.scene.train_indices:
            img, valid = st.get(i)
            with torch.no_grad():
                t = self.decoder.encode(img) if encode else img
            t = torch.cat([t * valid[..., None], valid[..., None].float()], -1)  # [H, W, C+1]
            f = torch.zeros(m.n, t.shape[-1], requires_grad=True)
            cam = cams[i]
            with torch.enable_grad():
                out = rasterize(means, quats, scales, opac, f, cam.viewmat, cam.K, cam.width, cam.height,
                                backend=self.cfg.backend)
                (out.image * t).sum().backward()
            acc = f.grad.clone() if acc is None else acc + f.grad
        w = acc[:, -1:]
        res = acc[:, :-1] / w.clamp_min(1e-8)
        weak = w[:, 0] < 1e-3
        if weak.any():
            fallback = self._projected_targets(kind)
            if encode:
                with torch.no_grad():
                    fallback = self.decoder.encode(fallback)
            res[weak] = fallback[weak]
        return res.detach()

    def _init_head(self) -> None:
        """Appearance tensors of the variant, the view-independent part from projected observations."""
        from brfgs.brdf.head import init_head_params

        cfg, n = self.cfg, self.model.n
        if cfg.variant == "cir":
            base = self._backprojected_targets("cir", encode=False)
            params = init_head_params(head_config(cfg), n, 3, z_init=base)
            self.extra["bg_colors"] = base.mean(0)
        else:
            base = self._backprojected_targets("full", encode=True)
            self.extra["bg_latent"] = base.mean(0).detach()
            if cfg.variant == "neural":
                params = {"feat": base}
                torch.manual_seed(cfg.seed)
                self.neural = NeuralHead(cfg.latent_dim)
            else:
                hc = head_config(cfg)
                params = init_head_params(hc, n, cfg.latent_dim, z_init=base)
                if cfg.variant == "brf" and cfg.learn_normals and hc.needs_normals:
                    from brfgs.brdf.geometry import gaussian_normals

                    up = torch.zeros_like(self.model.means)
                    up[:, 2] = 1.0
                    params["normals"] = gaussian_normals(self.model.quats, self.model.scales, up).detach()
        self.model.set_head(params, cfg.variant)
        self.model.centred = cfg.centred_kernels and cfg.variant == "brf" and "iso" in cfg.components
        for v in self.extra.values():
            v.requires_grad_(True)

    def _begin_phase(self, name: str) -> None:
        if name == "stage2":
            self._init_head()
        self.phase = name
        self.step = 0

    # -------------------------------------------------------------------------------- cameras
    def cameras(self) -> list[Camera]:
        if not hasattr(self, "_cams"):
            self._cams = cameras_from_description(self.meta["scene"])
            self._sun = sun_dir_from_description(self.meta["scene"])
        return self._cams

    # -------------------------------------------------------------------------------- learning rates
    def _lrs(self, phase: str, step: int, steps: int) -> dict[str, float]:
        c = self.cfg
        ext = self.meta["extent_m"]
        geo = phase in ("stage1", "joint", "cir")
        lrs: dict[str, float] = {}
        if geo:
            frac = step / max(steps, 1)
            lr_m = math.exp((1 - frac) * math.log(c.lr_means * ext) + frac * math.log(c.lr_means_final * ext))
            lrs.update({"means": lr_m, "log_scales": c.lr_scales, "quats": c.lr_quats, "opacity_logits": c.lr_opacity})
        if phase == "stage1":
            lrs.update({"colors": c.lr_colors, "colors_rest": c.lr_colors / 20.0, "bg_colors": c.lr_background})
        if phase in ("stage2", "joint"):
            for k in ("z_iso", "z_vol", "z_geo", "sh", "feat"):
                lrs[k] = c.lr_latent
            lrs["z_spec"] = c.lr_spec
            lrs["rho_raw"] = c.lr_rho
            lrs["normals"] = c.lr_normals
            lrs["bg_latent"] = c.lr_background
            if self.neural is not None:
                for k, _ in self.neural.named_parameters():
                    lrs["neural." + k] = c.lr_neural
            if c.finetune_decoder:
                for k, _ in self.decoder.named_parameters():
                    lrs["decoder." + k] = c.lr_decoder
        if phase == "cir":
            lrs.update({"sh": c.lr_colors, "bg_colors": c.lr_background})
        return lrs

    def _all_params(self) -> dict[str, torch.Tensor]:
        p = dict(self.model.params)
        p.update(self.extra)
        if self.neural is not None:
            p.update({"neural." + k: v for k, v in self.neural.named_parameters()})
        if self.decoder is not None and self.cfg.finetune_decoder and self.phase in ("stage2", "joint"):
            p.update({"decoder." + k: v for k, v in self.decoder.named_parameters()})
        return p

    # -------------------------------------------------------------------------------- one step
    def _pick(self, phase: str = "") -> tuple[int, tuple[int, int, int, int] | None]:
        """Next training view (epoch-wise permutation) and an optional patch window.

        Patches of ``patch_px`` for large images; in the joint phase, square patches of about
        ``stage2_rays`` pixels (every pixel is decoded there, for the D-SSIM term).
        """
        tr = self.scene.train_indices
        if not getattr(self, "_perm", None):
            self._perm = torch.randperm(len(tr), generator=self.gen).tolist()
        i = tr[self._perm.pop()]
        W, H = self.scene.width, self.scene.height
        P = self.cfg.patch_px
        if phase == "joint" and self.cfg.stage2_rays > 0:
            side = max(int(math.sqrt(self.cfg.stage2_rays)), 16)
            P = min(P, side) if P > 0 else side
        if P > 0 and W * H > P * P:
            pw, ph = min(P, W), min(P, H)
            x0 = int(torch.randint(0, W - pw + 1, (1,), generator=self.gen))
            y0 = int(torch.randint(0, H - ph + 1, (1,), generator=self.gen))
            return i, (x0, y0, pw, ph)
        return i, None

    def _forward(self, phase: str, i: int, win):
        """(loss, psnr, render output) of one view for a phase."""
        cam = self.cameras()[i]
        c = self.cfg
        kind = {"stage1": "colors", "cir": "cir"}.get(phase, "full")
        target, valid = self.store(kind).get(i)
        if win is not None:
            x0, y0, w, h = win
            cam = cam.crop(x0, y0, w, h)
            target, valid = target[y0 : y0 + h, x0 : x0 + w], valid[y0 : y0 + h, x0 : x0 + w]
        backend = c.backend
        geo_phase = phase in ("stage1", "cir", "joint")
        surf = c.lambda_normal > 0 or c.lambda_depth_conc > 0 or c.lambda_depth_smooth > 0
        reg = geo_phase and surf and self.step >= int(c.normal_start * getattr(self, "_phase_steps", 0))
        if phase == "stage1":
            feats = stage1_colors(self.model, cam)
        elif phase == "cir":
            feats = gaussian_features(self.model, cam, self._sun, head_config(c))
        else:
            feats = gaussian_features(self.model, cam, self._sun, head_config(c), self.neural)
        nch = feats.shape[-1]
        if reg:  # depth + normal (+ depth²) channels for the surface priors
            geo_feats = [feats, camera_depth_normals(self.model, cam)]
            if c.lambda_depth_conc > 0:
                geo_feats.append(camera_depth_squared(self.model, cam))
            feats = torch.cat(geo_feats, -1)
        out = rasterize_features(self.model, feats, cam, backend)
        image = out.image[..., :nch]
        greg = None
        if geo_phase:
            greg = c.lambda_flat * flatten_loss(self.model["log_scales"]) if c.lambda_flat > 0 else None
            if reg:
                geo = out.image[..., nch:]  # [H, W, 4 or 5] depth, normal (, depth²)
                terms = []
                if c.lambda_normal > 0:
                    terms.append(c.lambda_normal * depth_normal_loss(geo[..., :4], out.alpha, cam.K))
                if c.lambda_depth_conc > 0:
                    terms.append(c.lambda_depth_conc * depth_concentration_loss(geo[..., [0, 4]], out.alpha))
                if c.lambda_depth_smooth > 0:
                    terms.append(c.lambda_depth_smooth * depth_smoothness_loss(geo[..., 0], out.alpha, target, valid))
                if terms:
                    greg = sum(terms) if greg is None else greg + sum(terms)
        if phase in ("stage1", "cir"):
            pred = composite_background(image, out.alpha, self.extra["bg_colors"])
            loss = stage1_loss(pred, target, valid, c.alpha_dssim)
            if greg is not None:
                loss = loss + greg
            return loss, masked_psnr(pred, target, valid), out
        if phase == "stage2" and c.lambda_normal_smooth > 0 and "normals" in self.model:
            greg = c.lambda_normal_smooth * normal_smoothness_loss(self.model["normals"], self._neighbours())
        lat = composite_background(image, out.alpha, self.extra["bg_latent"])
        h, w = lat.shape[:2]
        if phase == "stage2" and 0 < c.stage2_rays < h * w:
            # ray sampling: decode and score a random subset of the rendered pixels
            idx = torch.randperm(h * w, generator=self.gen)[: c.stage2_rays]
            pred = self.decoder.decode(lat.reshape(h * w, -1)[idx])  # [R, B]
            tgt, val = target.reshape(h * w, -1)[idx], valid.reshape(-1)[idx]
            loss = stage2_loss(pred, tgt, val, c.beta_cos)
            if greg is not None:
                loss = loss + greg
            return loss, masked_psnr(pred, tgt, val), out
        pred = decode_image(self.decoder, lat)
        loss = stage2_loss(pred, target, valid, c.beta_cos)
        if phase == "joint" and c.alpha_dssim > 0:
            sel = self._stage1_bands()
            loss = loss + c.alpha_dssim * (stage1_loss(pred[..., sel], target[..., sel], valid, 1.0))
        if greg is not None:
            loss = loss + greg
        return loss, masked_psnr(pred, target, valid), out

    def _neighbours(self, k: int = 8) -> torch.Tensor:
        """Indices [N, k] of each Gaussian's k nearest other Gaussians (stage 2: the means are frozen)."""
        n = self.model.n
        if getattr(self, "_nbr", None) is None or self._nbr.shape[0] != n:
            from scipy.spatial import cKDTree

            pts = self.model.means.detach().numpy()
            _, nbr = cKDTree(pts).query(pts, k=min(k, n - 1) + 1)
            self._nbr = torch.as_tensor(np.asarray(nbr).reshape(n, -1)[:, 1:], dtype=torch.long)
        return self._nbr

    def _run_phase(self, phase: str, steps: int) -> None:
        c = self.cfg
        self.cameras()
        if self.decoder is not None:
            self.decoder.requires_grad_(bool(c.finetune_decoder and phase in ("stage2", "joint")))
        densify = phase in ("stage1", "joint", "cir")
        self._phase_steps = steps
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=steps, initial=self.step, desc=phase, dynamic_ncols=True)
        log_path = self.out / "train_log.csv"
        new_log = not log_path.exists()
        with open(log_path, "a", newline="") as fh:
            w = csv.writer(fh)
            if new_log:
                w.writerow(["phase", "step", "loss", "psnr", "n_gaussians"])
            while self.step < steps:
                self.opt.lrs = self._lrs(phase, self.step, steps)
                i, win = self._pick(phase)
                loss, ps, out = self._forward(phase, i, win)
                params = self._all_params()
                NamedAdam.zero_grad(params)
                means2d = out.meta.get("means2d")
                if densify and means2d is not None and means2d.requires_grad and not means2d.is_leaf:
                    means2d.retain_grad()
                loss.backward()
                if densify:
                    ww = win[2] if win else self.scene.width
                    hh = win[3] if win else self.scene.height
                    accumulate(self.dstate, means2d, out.meta["visible"], ww, hh)
                self.opt.step(params)
                self.step += 1
                if densify:
                    self._maybe_refine(self.step, steps)
                lv = float(loss.detach())
                self.history.append((phase, self.step, lv, ps))
                if self.step % c.log_every == 0 or self.step == steps:
                    w.writerow([phase, self.step, f"{lv:.6g}", f"{ps:.4f}", self.model.n])
                if bar is not None:
                    bar.update(1)
                    if self.step % 10 == 0:
                        bar.set_postfix(loss=f"{lv:.4f}", psnr=f"{ps:.2f}", n=self.model.n)
                if self.step % c.checkpoint_every == 0 and self.step < steps:
                    fh.flush()
                    self._save_checkpoint()
                if self.callback is not None:
                    self.callback(phase, self.step)
        if bar is not None:
            bar.close()

    def _maybe_refine(self, step: int, steps: int | None = None) -> None:
        d = self.cfg.densify
        # densify at most over the first 3/4 of the phase (3DGS: 15k of 30k steps) and never reset
        # opacities after that: a late reset leaves the frozen stage-2 geometry nearly transparent
        stop = d.refine_stop if steps is None else min(d.refine_stop, int(0.75 * steps))
        if d.refine_start < step <= stop and step % d.refine_every == 0:
            cap = d.max_gaussians
            if self.cfg.max_gaussians_per_px > 0:
                cap = min(cap, int(self.cfg.max_gaussians_per_px * self.scene.width * self.scene.height))
            info = refine(self.model, self.opt, self.dstate, replace(d, max_gaussians=cap), self.meta["extent_m"], self.gen)
            if self.progress and step % (d.refine_every * 10) == 0:
                pass
            self._last_refine = info
        if d.reset_every > 0 and step % d.reset_every == 0 and step < stop:
            reset_opacity(self.model, self.opt, self.dstate, d)

    # -------------------------------------------------------------------------------- checkpoints
    def _state_tensors(self, with_optim: bool) -> dict[str, torch.Tensor]:
        from brfgs.spectral.autoencoder import autoencoder_state

        t = ckpt.prefixed(self.model.state(), "param.")
        t.update(ckpt.prefixed({k: v.detach() for k, v in self.extra.items()}, "extra."))
        if self.decoder is not None:
            t.update(autoencoder_state(self.decoder, "decoder.")[0])
        if self.neural is not None:
            t.update(ckpt.prefixed(self.neural.state_dict(), "neural."))
        if with_optim:
            t.update(self.opt.state_tensors("optim."))
            t.update(self.dstate.tensors("densify."))
            t["rng.torch"] = self.gen.get_state()
        return t

    def _meta(self, with_optim: bool) -> dict:
        m = dict(self.meta)
        m.update({"config": self.cfg.to_dict(), "appearance": self.model.appearance, "latent_dim": self.model.latent_dim,
                  "n_colors": self.model.n_colors, "phase": self.phase, "step": self.step, "timings_s": self.timings,
                  "n_gaussians": self.model.n})
        hc = head_config(self.cfg)
        m["head"] = hc.to_dict() if hc is not None else {"kind": "neural", "hidden": 64}
        if self.decoder is not None:
            m["autoencoder"] = json.dumps(self.decoder.describe())
        m["kernel_form"] = "centred" if getattr(self.model, "centred", False) else "eq12"
        if with_optim:
            m["optim"] = self.opt.state_meta()
            m["densify_resets"] = self.dstate.n_resets
            m["perm"] = list(getattr(self, "_perm", []) or [])
        return m

    def _save_checkpoint(self, path: Path | None = None) -> None:
        ckpt.save(path or self.out / LAST_CKPT, self._state_tensors(True), self._meta(True))

    def _save_model(self) -> Path:
        m = self._meta(False)
        m["phase"] = "done"
        m["kernel_form"] = "eq12"
        t = self._state_tensors(False)
        if getattr(self.model, "centred", False):
            from brfgs.model.render import uncentre

            for k, v in uncentre(self.model, head_config(self.cfg), self._sun).items():
                t["param." + k] = v.contiguous()
        return ckpt.save(self.out / MODEL_FILE, t, m)

    def _load_checkpoint(self, path: Path, reuse_stage1: bool = False) -> None:
        from brfgs.spectral.autoencoder import autoencoder_from_state

        tensors, meta = ckpt.load(path)
        saved_cfg = TrainConfig.from_dict(meta["config"])
        self.meta = {k: meta[k] for k in ("scene", "bands", "stage1_bands", "cir_indices", "cir_scale", "extent_m") if k in meta}
        if "autoencoder_report" in meta:
            self.meta["autoencoder_report"] = meta["autoencoder_report"]
        self.model = GaussianModel(ckpt.with_prefix(tensors, "param."), meta["appearance"], meta["latent_dim"], meta["n_colors"])
        self.model.centred = meta.get("kernel_form") == "centred"
        self.extra = {k: v.clone().requires_grad_(True) for k, v in ckpt.with_prefix(tensors, "extra.").items()}
        self.decoder = autoencoder_from_state(tensors, meta, "decoder.") if "autoencoder" in meta else None
        self.timings = dict(meta.get("timings_s", {}))
        if reuse_stage1:
            # start a new run (other variant) from the end of a stage-1 run
            at_end = meta["phase"] == "stage1" and int(meta["step"]) == saved_cfg.stage1_steps
            if saved_cfg.variant == "cir" or saved_cfg.joint or not at_end:
                raise UserError("not a stage-1 checkpoint (expected checkpoints/stage1.safetensors of a decoupled run)", file=path)
            if self.cfg.variant == "cir" or self.cfg.joint:
                raise UserError("--from-stage1 needs a decoupled spectral variant (brf, sh, neural)", field="from_stage1")
            if saved_cfg.latent_dim != self.cfg.latent_dim:
                raise UserError("latent_dim differs from the stage-1 run", field="latent_dim")
            self.dstate = DensifyState(self.model.n)
            (self.out / "split.json").write_text(json.dumps(self.meta["scene"]["split"], indent=1))
            self.meta["stage1_from"] = str(Path(path).resolve())
            self.timings = {k: v for k, v in self.timings.items() if k in ("bands", "init", "autoencoder", "stage1")}
            # continue the stage-1 run's random stream (view order, ray samples): with the same options,
            # a run started from a stage-1 checkpoint reproduces the continuous run exactly
            if "rng.torch" in tensors:
                self.gen.set_state(tensors["rng.torch"])
            self._perm = list(meta.get("perm", []))
            self._begin_phase("stage2")
            return
        if meta["appearance"] == "neural" and any(k.startswith("neural.") for k in tensors):
            self.neural = NeuralHead(meta["latent_dim"])
            self.neural.load_state_dict(ckpt.with_prefix(tensors, "neural."))
        self.opt = NamedAdam({})
        self.opt.load(tensors, meta["optim"], "optim.")
        self.dstate = DensifyState(self.model.n)
        self.dstate.load(tensors, meta.get("densify_resets", 0), "densify.")
        self.gen.set_state(tensors["rng.torch"])
        self._perm = list(meta.get("perm", []))
        self.phase = meta["phase"]
        self.step = int(meta["step"])
        for v in self.extra.values():
            v.requires_grad_(True)


def train(scene_path, out_dir, cfg: TrainConfig, overwrite: bool = False, progress: bool = True, callback=None,
          from_stage1=None, log=print) -> Path:
    """Train a model on ``scene_path`` into ``out_dir`` (resumes an unfinished run); returns model.safetensors."""
    return Trainer(scene_path, out_dir, cfg, overwrite=overwrite, progress=progress, callback=callback,
                   from_stage1=from_stage1, log=log).run()
