"""A run's set-up: band selection, geometry initialisation, the spectral autoencoder, the
initial Gaussians (paper section 3.2) and the appearance heads' starting values."""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import Tensor

from brfgs.bands import select_bands
from brfgs.brdf.geometry import gaussian_normals
from brfgs.brdf.head import init_head_params
from brfgs.data.cir import cir_band_indices, cir_scale
from brfgs.data import atomic
from brfgs.data.pixels import FramePixels
from brfgs.errors import UserError
from brfgs.init import initialize
from brfgs.init.mvs import MVSConfig, dense_cloud, write_dense_ply
from brfgs.init.truth import surface_samples
from brfgs.model import DensifyState, init_from_points, scene_description, scene_extent, surface_fill
from brfgs.model.features import NeuralHead
from brfgs.model.layout import has_colors_kernels, has_irradiance_scales, has_learned_normals
from brfgs.model.rendering import rasterize_splats
from brfgs.model.shadows import pixel_visibility, sun_sky_light
from brfgs.spectral.autoencoder import AutoencoderConfig, evaluate_autoencoder, sample_pixels, train_autoencoder
from brfgs.spectral.fast_encode import encode_spectra
from brfgs.spectral.linear_basis import fit_linear_basis
from brfgs.train.config import TrainConfig
from brfgs.train.dense_depth import FILE as DENSE_DEPTH_FILE, save_dense_depths
from brfgs.train.images import TrainImages
from brfgs.train.phases import run_plan
from brfgs.train.run_folder import RunFolder
from brfgs.train.state import TrainState, head_config
from brfgs.train.targets import backprojected_reflectance, backprojected_targets, ground_footprints


def select_and_initialise(state: TrainState, scene, cfg: TrainConfig, folder: RunFolder, progress: bool, log):
    """Band selection and SfM / known-pose initialisation; fills ``state.meta``; returns the
    initialisation (points, colours, poses)."""
    t = time.perf_counter()
    folder.write_json("split.json", scene.split_record())
    sel = select_bands(scene, strategy=cfg.band_strategy, top=cfg.top, progress=progress)
    folder.write_json("bands.json", sel.to_json())
    bands = [int(b) for b in sel.selected]
    state.timings["bands"] = time.perf_counter() - t
    log(f"bands: {cfg.band_strategy} -> {[round(float(scene.wavelengths_nm[b]), 1) for b in bands]} nm")
    t = time.perf_counter()
    init = initialize(scene, bands, poses=cfg.poses, out_dir=folder.out / "init", selection=sel, progress=progress)
    state.timings["init"] = time.perf_counter() - t
    log(f"init: {init.points.shape[0]} points ({init.report.get('poses', cfg.poses)})"
        + (f"; {init.report['fallback']}" if init.report.get("fallback") else ""))
    cir_idx = cir_band_indices(scene.wavelengths_nm)
    # stage 1 fits the selected bands and, by default, the CIR bands (green, red, NIR): the selected
    # bands make SfM reliable, the CIR bands carry the visible texture that the composites show
    s1 = sorted(set(bands) | {int(i) for i in cir_idx}) if cfg.stage1_cir_bands else bands
    state.meta = {"scene": scene_description(scene, init.c2w), "bands": bands, "stage1_bands": s1,
                  "cir_indices": list(cir_idx), "cir_scale": [float(v) for v in cir_scale(scene)],
                  "extent_m": scene_extent(init.points)}
    return init


def dense_fill(state: TrainState, scene, cfg: TrainConfig, init, images: TrainImages, folder: RunFolder,
               log) -> np.ndarray:
    """About ``init_fill_points`` points [M, 3] from dense stereo of the training views in the
    stage-1 bands (:func:`brfgs.init.mvs.dense_cloud`); the cloud and its report go to OUT/init
    (dense.ply, dense.json)."""
    t = time.perf_counter()
    tr = scene.train_indices
    cloud = dense_cloud([images("colors").get(i)[0].numpy() for i in tr], [init.c2w[i] for i in tr],
                        scene.intrinsics, init.points, MVSConfig(max_points=cfg.init_fill_points))
    state.timings["dense"] = time.perf_counter() - t
    write_dense_ply(folder.out / "init" / "dense.ply", cloud.points, cloud.normals)
    save_dense_depths(folder.out / "init" / DENSE_DEPTH_FILE, [scene.frames[i].name for i in tr], cloud.depths)
    atomic.write_json(folder.out / "init" / "dense.json", cloud.report)
    log(f"init: dense stereo {cloud.report['stereo_points']} points, {cloud.report['hole_points']} more where it "
        f"left holes, thinned to {len(cloud.points)} ({state.timings['dense']:.0f} s)")
    return cloud.points


TRUTH_VOXEL_M = 0.05  # --init-fill truth: one true-surface sample per voxel of this size before the subset


def truth_fill(state: TrainState, scene, cfg: TrainConfig, folder: RunFolder, log) -> np.ndarray:
    """About ``init_fill_points`` points [M, 3] on a simulated scene's true surface (its truth depth maps
    of the training views, one point per 5 cm voxel, then a subset seeded by ``seed``); the truth depth
    maps become the dense-depth targets (OUT/init/dense_depths.npz). UserError without truth depth."""
    tr = list(scene.train_indices)
    pts = surface_samples(scene, tr)  # [S, 3] m
    if pts is None:
        raise UserError("--init-fill truth needs a simulated scene's truth depth maps",
                        file=(scene.truth_dir or scene.root / "truth") / "depth", field="init_fill")
    _, first = np.unique(np.floor(pts / TRUTH_VOXEL_M).astype(np.int64), axis=0, return_index=True)
    pts = pts[np.sort(first)]
    if len(pts) > cfg.init_fill_points:
        keep = np.random.default_rng(cfg.seed).choice(len(pts), cfg.init_fill_points, replace=False)
        pts = pts[np.sort(keep)]
    maps = {scene.frames[i].name: scene.truth_dir / "depth" / f"{scene.frames[i].name}.npy" for i in tr}
    maps = {name: path for name, path in maps.items() if path.is_file()}  # the maps surface_samples read
    save_dense_depths(folder.out / "init" / DENSE_DEPTH_FILE, list(maps), [np.load(path) for path in maps.values()])
    log(f"init: {len(pts)} points on the true surface, truth depth maps of {len(maps)} training views")
    return pts


def initial_gaussians(state: TrainState, scene, cfg: TrainConfig, init, images: TrainImages, folder: RunFolder,
                      log) -> None:
    """Gaussians at the sparse points (plus a surface fill), stage-1 colours from the images, the
    stage-1 kernel terms, and the stage-1 background."""
    bands, s1 = state.meta["bands"], state.meta["stage1_bands"]
    pts, cols = np.asarray(init.points, np.float64), np.asarray(init.colors, np.float64)
    if cfg.init_fill_points > 0:
        if cfg.init_fill == "mvs":
            extra = dense_fill(state, scene, cfg, init, images, folder, log)
        elif cfg.init_fill == "truth":
            extra = truth_fill(state, scene, cfg, folder, log)
        else:
            cover, seen = ground_footprints(scene, pts, init.c2w)
            extra = surface_fill(pts, cfg.init_fill_points, cover_xy=cover, keep=seen)
        if extra.shape[0]:
            pts = np.concatenate([pts, extra], 0)
            cols = np.concatenate([cols, np.full((extra.shape[0], cols.shape[1]), np.nan)], 0)
        log(f"init: +{extra.shape[0]} surface-fill points")
    if s1 != bands:  # colours of the extra bands come from the images below
        cols = np.full((cols.shape[0], len(s1)), np.nan)
    gm = init_from_points(pts, np.nan_to_num(cols), cfg.latent_dim, cfg.init_opacity)
    state.gaussians = gm
    if cfg.init_fill_points > 0 or s1 != bands:  # colours of every Gaussian from the images it projects into
        with torch.no_grad():
            gm.params["colors"].copy_(backprojected_targets(gm, images("colors"), state.cameras, scene.train_indices,
                                                            backend=cfg.backend, antialiased=cfg.antialias,
                                                            supersample=cfg.supersample))
    k = gm["colors"].shape[1]
    # stage-1 colours with eq. 12's kernels (CIR and joint runs have no stage-1 colours to extend)
    if has_colors_kernels(cfg.stage1_kernels, cfg.variant, cfg.joint):
        gm.params["colors_kernels"] = torch.zeros(gm.n, 2, k, requires_grad=True)
    state.densify = DensifyState(gm.n)
    bg = np.nanmean(init.colors, 0) if s1 == bands else gm["colors"].detach().mean(0).numpy()  # [C]
    state.extra = {"bg_colors": torch.as_tensor(bg, dtype=torch.float32).requires_grad_(True)}


def fit_autoencoder(state: TrainState, scene, cfg: TrainConfig, images: TrainImages, folder: RunFolder,
                    progress: bool, log) -> None:
    """Fit the spectral decoder on pixels of the training views and report on test pixels: the
    autoencoder (eq. 9) or, with ``spectral_basis`` linear, the linear basis (PCA noise-weighted by the
    scene's dark-frame σ_b, :func:`brfgs.spectral.linear_basis.fit_linear_basis`)."""
    full = images("full")
    loaders = [(lambda i=i: full.for_sampling(i)) for i in scene.train_indices]   # held, or read by row blocks
    pix = sample_pixels(loaders, cfg.ae_max_pixels, cfg.seed)
    if cfg.spectral_basis == "linear":
        if cfg.latent_dim > pix.shape[1]:
            raise UserError(f"a linear basis of {cfg.latent_dim} components needs at least as many bands (the scene "
                            f"has {pix.shape[1]})", field="latent_dim")
        state.decoder, hist = fit_linear_basis(pix, cfg.latent_dim, scene.dark_sigma, seed=cfg.seed), []
        acfg = {"spectral_basis": "linear", "latent_dim": cfg.latent_dim, "pixels": int(pix.shape[0]),
                "noise_weights": f"dark_sigma ({scene.dark_sigma_source})"}
    else:
        acfg = AutoencoderConfig(latent_dim=cfg.latent_dim, steps=cfg.ae_steps, batch_size=cfg.ae_batch,
                                 max_pixels=cfg.ae_max_pixels, seed=cfg.seed)
        state.decoder, hist = train_autoencoder(pix, acfg, progress=progress)
        acfg = acfg.__dict__
    state.decoder.requires_grad_(cfg.finetune_decoder)      # frozen: decoding takes the fused kernels
    report = {"config": acfg, "loss_first": hist[0] if hist else None, "loss_last": hist[-1] if hist else None,
              "train": evaluate_autoencoder(state.decoder, pix)}
    if scene.test_indices:
        test = [FramePixels(scene, i) for i in scene.test_indices]                 # read by row blocks
        report["test"] = evaluate_autoencoder(state.decoder, sample_pixels(test, min(cfg.ae_max_pixels, 50_000), cfg.seed + 1))
    folder.write_json("autoencoder.json", report)
    state.meta["autoencoder_report"] = report
    te = report.get("test", report["train"])
    name = "linear basis" if cfg.spectral_basis == "linear" else "autoencoder"
    log(f"{name} d={cfg.latent_dim}: test SAM {te['sam_mean_rad']:.4f} rad, RMSE {te['rmse']:.5f}")


@torch.no_grad()
def view_light(state: TrainState, i: int, backend: str = "auto", cam=None) -> Tensor:  # [H, W, B]
    """The sun and sky illumination (1 − f_b) V + f_b of training view ``i``'s pixels (those ``cam`` sees:
    a window's camera; default the view's), V the Gaussians' direct-sun visibility under its sun blended
    by the view (the background lit), f_b its sky's."""
    g, cam = state.gaussians, state.cameras[i] if cam is None else cam
    out = rasterize_splats(g.means.detach(), g.quats.detach(), g.scales.detach(), g.opacities.detach(),
                           state.sun_visibility(i)[:, None], cam, backend, state.cfg.antialias,
                           supersample=state.cfg.supersample)
    return sun_sky_light(state.diffuse_fraction(i), pixel_visibility(out.image[..., 0], out.alpha))


def init_head(state: TrainState, cfg: TrainConfig, scene, images: TrainImages) -> None:
    """Appearance tensors of the variant, the view-independent part from back-projected observations."""
    gm, n, cams = state.gaussians, state.gaussians.n, state.cameras
    if cfg.variant == "cir":
        base = backprojected_targets(gm, images("cir"), cams, scene.train_indices, backend=cfg.backend,
                                     antialiased=cfg.antialias, supersample=cfg.supersample)
        params = init_head_params(head_config(cfg), n, 3, z_init=base)
        state.extra["bg_colors"] = base.mean(0)
    else:
        if cfg.shadows:  # the lit surface's reflectance: each view's image over its sun and sky light
            refl = backprojected_reflectance(gm, images("full"), cams, scene.train_indices,
                                             lambda i, cam: view_light(state, i, cfg.backend, cam), backend=cfg.backend,
                                             antialiased=cfg.antialias, supersample=cfg.supersample)
            base = encode_spectra(state.decoder, refl)
        else:
            base = backprojected_targets(gm, images("full"), cams, scene.train_indices,
                                         encode=lambda img: encode_spectra(state.decoder, img),
                                         backend=cfg.backend, antialiased=cfg.antialias, supersample=cfg.supersample)
        state.extra["bg_latent"] = base.mean(0).detach()
        if has_irradiance_scales(cfg.variant, cfg.learn_irradiance):  # log of each frame's irradiance scale
            state.extra["log_irradiance"] = torch.zeros(len(state.cameras))
        if cfg.variant == "neural":
            params = {"feat": base}
            torch.manual_seed(cfg.seed)
            state.neural = NeuralHead(cfg.latent_dim)
        else:
            hc = head_config(cfg)
            params = init_head_params(hc, n, cfg.latent_dim, z_init=base)
            if has_learned_normals(cfg.variant, cfg.learn_normals, hc):
                up = torch.zeros_like(gm.means)
                up[:, 2] = 1.0
                params["normals"] = gaussian_normals(gm.quats, gm.scales, up).detach()
    gm.set_head(params, cfg.variant)
    gm.centred = cfg.centred_kernels and cfg.variant == "brf" and "iso" in cfg.components
    for v in state.extra.values():
        v.requires_grad_(True)


def run_setup(state: TrainState, scene, cfg: TrainConfig, folder: RunFolder, progress: bool, log) -> TrainImages:
    """The whole set-up of a new run; leaves ``state`` at the first phase, step 0."""
    init = select_and_initialise(state, scene, cfg, folder, progress, log)
    images = TrainImages(scene, state.stage1_bands(), state.meta["cir_indices"], state.meta["cir_scale"], cfg.cache_gib)
    initial_gaussians(state, scene, cfg, init, images, folder, log)
    if cfg.variant != "cir":  # spectral decoder (not for the CIR-only baseline)
        t = time.perf_counter()
        fit_autoencoder(state, scene, cfg, images, folder, progress, log)
        state.timings["autoencoder"] = time.perf_counter() - t
    if cfg.variant == "cir" or cfg.joint:
        init_head(state, cfg, scene, images)
    state.phase = run_plan(cfg)[0][0]
    state.step = 0
    return images
