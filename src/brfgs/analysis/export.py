"""Exports of a trained model: a 3DGS PLY that common splat viewers open, and the model file.

PLY layout (binary little endian, one ``vertex`` element per Gaussian), the standard 3DGS
attributes first:

    x y z                 centre μ_k (metres, ENU)
    nx ny nz              unit normal (axis of the smallest scale, facing up)
    f_dc_0 f_dc_1 f_dc_2  CIR colour as SH DC: (c − 0.5) / C0, C0 = 0.28209479; c is the CIR
                          composite (850/650/550 nm, scaled like the training data) of the
                          Gaussian's decoded reflectance at nadir view under the training sun
    opacity               logit of the opacity
    scale_0..2            log of the standard deviations (metres)
    rot_0..3              unit quaternion (w, x, y, z)

then the BRF parameters as extra properties: ``z_iso_0..d-1``, ``z_vol_*``, ``z_geo_*``,
``z_spec_*`` (latent kernel coefficients, eq. 12) and ``roughness`` (ρ_k). Viewers ignore
properties they do not know. Without SH rest coefficients viewers show degree-0 colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from brfgs.analysis.renderer import BRFModel
from brfgs.errors import UserError

__all__ = ["SH_C0", "STANDARD_PROPERTIES", "gaussian_cir_colours", "write_ply", "read_ply"]

SH_C0 = 0.28209479177387814
STANDARD_PROPERTIES = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
                       + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])


@torch.no_grad()
def gaussian_cir_colours(bm: BRFModel, chunk: int = 1 << 15) -> np.ndarray:
    """CIR colour [N, 3] in [0, 1] of every Gaussian: its decoded reflectance for a nadir view
    (ω_o = +z) under the training sun, bands 850/650/550 nm divided by the CIR scale."""
    n = bm.n_gaussians
    up = torch.tensor([0.0, 0.0, 1.0])
    omega_i = bm.sun_direction()
    out = np.zeros((n, 3), np.float32)
    idx_all = torch.arange(n)
    for i in range(0, n, chunk):
        idx = idx_all[i:i + chunk]
        oo = up.expand(int(idx.numel()), 3).contiguous()
        if bm.appearance == "cir" or bm.decoder is None:
            from brfgs.brdf.head import evaluate_head

            rgb = evaluate_head(bm.head_cfg, bm.head_params(idx), None, omega_i, oo).numpy()
        else:
            refl = bm.decode(bm.gaussian_latent(omega_i, oo, idx))
            rgb = refl[:, list(bm.cir_indices)] / np.asarray(bm.cir_scale, float)[None]
        out[i:i + len(idx)] = np.clip(rgb, 0.0, 1.0)
    return out


@torch.no_grad()
def write_ply(path: str | Path, bm: BRFModel, colours: np.ndarray | None = None) -> Path:
    """Write the Gaussians of ``bm`` as a 3DGS PLY with BRF extras (see the module docstring)."""
    from plyfile import PlyData, PlyElement

    from brfgs.brdf.geometry import gaussian_normals

    m = bm.model
    n = m.n
    means = m.means.detach().float()
    quats = m.quats.detach().float()
    qn = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    log_scales = m.params["log_scales"].detach().float()
    up = torch.tensor([0.0, 0.0, 1.0]).expand(n, 3)
    normals = gaussian_normals(quats, log_scales.exp(), up)
    if colours is None:
        colours = gaussian_cir_colours(bm)
    fdc = (np.asarray(colours, np.float32) - 0.5) / SH_C0
    cols: dict[str, np.ndarray] = {}
    for j, k in enumerate("xyz"):
        cols[k] = means[:, j].numpy()
    for j, k in enumerate(("nx", "ny", "nz")):
        cols[k] = normals[:, j].numpy()
    for j in range(3):
        cols[f"f_dc_{j}"] = fdc[:, j]
    cols["opacity"] = m.params["opacity_logits"].detach().float().numpy()
    for j in range(3):
        cols[f"scale_{j}"] = log_scales[:, j].numpy()
    for j in range(4):
        cols[f"rot_{j}"] = qn[:, j].numpy()
    for c in ("iso", "vol", "geo", "spec"):
        key = f"z_{c}"
        if key in m.params:
            z = m.params[key].detach().float().numpy()
            for j in range(z.shape[1]):
                cols[f"{key}_{j}"] = z[:, j]
    if "rho_raw" in m.params and bm.head_cfg is not None:
        from brfgs.brdf.head import roughness_from_raw

        cols["roughness"] = roughness_from_raw(m.params["rho_raw"].detach().float(), bm.head_cfg.rho_min).numpy()
    arr = np.empty(n, dtype=[(k, "<f4") for k in cols])
    for k, v in cols.items():
        arr[k] = np.asarray(v, np.float32)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    el = PlyElement.describe(arr, "vertex")
    comments = [f"brfgs BRF-GS export: scene {bm.scene_name}", "f_dc = CIR (850/650/550 nm) colour as SH DC",
                f"wavelengths_nm {bm.wavelengths_nm.min():.1f}-{bm.wavelengths_nm.max():.1f} "
                f"({len(bm.wavelengths_nm)} bands); z_* are latent (decode with the model file)"]
    PlyData([el], text=False, byte_order="<", comments=comments).write(str(tmp))
    tmp.replace(path)
    return path


def read_ply(path: str | Path) -> dict[str, np.ndarray]:
    """{property: [N] float32} of a PLY's ``vertex`` element (any 3DGS-style file)."""
    from plyfile import PlyData

    path = Path(path)
    if not path.is_file():
        raise UserError("PLY file not found", file=path)
    try:
        ply = PlyData.read(str(path))
        v = ply["vertex"].data
    except Exception as exc:
        raise UserError(f"not a readable PLY with a 'vertex' element ({exc})", file=path) from None
    return {name: np.asarray(v[name]) for name in v.dtype.names}
