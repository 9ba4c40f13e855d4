"""Toy models for the analysis tests (no training needed)."""

from __future__ import annotations

import numpy as np
import torch

from brfgs.brdf.head import HeadConfig, raw_from_roughness
from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.model import TrainedModel
from brfgs.model.gaussians import GaussianModel
from brfgs.spectral.autoencoder import SpectralAutoencoder
from brfgs.train.presets import preset


class IdentityDecoder:
    """decode(z) = z: the latent is the reflectance (d = B)."""

    def decode(self, z):
        return z.clone()


def carpet_model(half_m: float = 20.0, spacing_m: float = 1.0, n_bands: int = 4, *, z_left=None, z_right=None,
                 vol: float = 0.0, geo: float = 0.0, spec: float = 0.0, components=("iso", "vol", "geo", "spec"),
                 sun=(35.0, 150.0), height_fn=None, roughness: float = 0.3) -> TrainedModel:
    """Flat carpet of Gaussians at z = 0 over [-half, half]², spacing ``spacing_m``.

    Latent = reflectance (identity decoder). z_iso is ``z_left`` for x < 0 and ``z_right``
    for x >= 0; z_vol, z_geo, z_spec are the constants ``vol``, ``geo``, ``spec`` × z_iso.
    """
    xs = np.arange(-half_m + spacing_m / 2, half_m, spacing_m)
    X, Y = np.meshgrid(xs, xs, indexing="xy")
    Z = np.zeros_like(X) if height_fn is None else height_fn(X, Y)
    means = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1).astype(np.float32)
    n = len(means)
    zl = np.asarray(z_left if z_left is not None else np.linspace(0.1, 0.4, n_bands), np.float32)
    zr = np.asarray(z_right if z_right is not None else np.linspace(0.5, 0.2, n_bands), np.float32)
    ziso = np.where((means[:, 0] < 0)[:, None], zl[None], zr[None]).astype(np.float32)
    s = spacing_m * 0.7
    params = {
        "means": torch.from_numpy(means),
        "log_scales": torch.log(torch.tensor([s, s, 0.02])).repeat(n, 1).float(),
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(n, 1),
        "opacity_logits": torch.full((n,), 6.0),
        "colors": torch.zeros(n, 1),
        "z_iso": torch.from_numpy(ziso),
        "z_vol": torch.from_numpy(ziso * vol),
        "z_geo": torch.from_numpy(ziso * geo),
        "z_spec": torch.from_numpy(ziso * spec),
        "rho_raw": raw_from_roughness(torch.full((n,), roughness)).float(),
    }
    params = {k: v for k, v in params.items() if not (k.startswith("z_") and k[2:] not in components)}
    if "spec" not in components:
        params.pop("rho_raw")
    gm = GaussianModel(params, "brf", n_bands, 1)
    for v in gm.params.values():
        v.requires_grad_(False)
    intr = Intrinsics.from_fov(40.0, 32, 32)
    frames = []
    for k, (zen, az) in enumerate([(0.0, 0.0), (30.0, 0.0), (30.0, 120.0), (30.0, 240.0)]):
        frames.append({"name": f"v{k}", "split": "train" if k < 3 else "test",
                       "c2w": pose_from_view_angles(zen, az, 60.0).tolist(),
                       "view_zenith_deg": zen, "view_azimuth_deg": az})
    scene = {"name": "scene", "root": None, "wavelengths_nm": np.linspace(480.0, 860.0, n_bands).tolist(),
             "fwhm_nm": None, "sun_zenith_deg": float(sun[0]), "sun_azimuth_deg": float(sun[1]),
             "intrinsics": {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h},
             "downscale": 1, "roi": None, "split": {}, "frames": frames}
    return TrainedModel(gaussians=gm, head_cfg=HeadConfig(kind="hybrid", components=tuple(components)),
                        decoder=IdentityDecoder(), scene=scene, config={"variant": "brf"},
                        meta={"cir_indices": [n_bands - 1, n_bands // 2, 0], "cir_scale": [1.0, 1.0, 1.0]})


def linear_autoencoder(n_bands: int) -> SpectralAutoencoder:
    """A SpectralAutoencoder whose decoder is exactly the identity (d = B): linear path = I,
    convolutional residual zero (its last layer is zero-initialised), no normalisation."""
    ae = SpectralAutoencoder(n_bands, latent_dim=n_bands)
    with torch.no_grad():
        ae.dec_lin.weight.copy_(torch.eye(n_bands))
        ae.dec_lin.bias.zero_()
    ae.eval()
    return ae


def write_model_file(path, tm: TrainedModel, scene_root=None):
    """Write ``tm`` (identity decoder) as a model file: the same Gaussians, head, sun, cameras and CIR
    bands, a linear autoencoder whose decoder is the identity, zero backgrounds, tiny training options."""
    d = tm.gaussians.latent_dim
    nb = len(tm.wavelengths_nm)
    assert d == nb
    # options that match the tensors written: no stage-1 kernels, no learned normals
    cfg = preset("tiny", latent_dim=d, components=tuple(tm.head_cfg.components), stage1_kernels=False,
                 learn_normals=False)
    scene = dict(tm.scene, root=str(scene_root) if scene_root else "/nonexistent/scene")
    meta = {"cir_indices": list(tm.cir_indices), "cir_scale": [float(v) for v in tm.cir_scale], "phase": "done",
            "step": 0, "extent_m": 20.0}
    out = TrainedModel(gaussians=tm.gaussians, head_cfg=tm.head_cfg, decoder=linear_autoencoder(nb), scene=scene,
                       config=cfg.to_dict(), extra={"bg_latent": torch.zeros(d), "bg_colors": torch.zeros(tm.gaussians.n_colors)},
                       meta=meta)
    return out.save(path)
