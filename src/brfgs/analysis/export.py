"""Exports of a trained model: a 3DGS PLY that common splat viewers open, and the model file.

PLY layout (binary little endian, one ``vertex`` element per Gaussian), the full standard
3DGS attribute set first, in the order of the reference implementation (viewers such as
SuperSplat, the antimatter15 / mkkellogg web viewers and SIBR expect all of them):

    x y z                 centre μ_k (metres, ENU)
    nx ny nz              unit normal (axis of the smallest scale, facing up)
    f_dc_0 f_dc_1 f_dc_2  CIR colour as SH DC: (c − 0.5) / C0, C0 = 0.28209479; c is the CIR
                          composite (850/650/550 nm, scaled like the training data)
    f_rest_0..44          SH degree 1–3 coefficients, channel-major as in 3DGS
                          (f_rest_{15·channel + k − 1} for basis k = 1..15), see below
    opacity               logit of the opacity
    scale_0..2            log of the standard deviations (metres)
    rot_0..3              unit quaternion (w, x, y, z)

then the BRF parameters as extra properties: ``z_iso_0..d-1``, ``z_vol_*``, ``z_geo_*``,
``z_spec_*`` (latent kernel coefficients, eq. 12), ``roughness`` (ρ_k), and for the SH
baseline ``sh_*`` (latent SH coefficients). Viewers ignore properties they do not know.

Colours (``view_dependence``):

- ``"fit"`` (default) for a view-dependent model: the Gaussian's CIR colour is evaluated for
  ``n_directions`` view directions over the upper hemisphere (view zenith ≤ 80°) under the
  training sun, mirrored to the lower hemisphere (a viewer below the ground sees the colour
  of the mirrored direction), and fitted by least squares with real SH of degree 3 in the
  viewers' convention (the SH argument is the direction from the camera to the Gaussian,
  −ω_o, in the PLY's world frame). The BRF's view dependence (hotspot, glint) then shows in
  splat viewers, to the accuracy of a degree-3 fit. For the SH baseline in CIR space the
  coefficients are copied exactly (odd degrees negated for −ω_o); for the latent SH baseline
  the decoded CIR colour is fitted like any other model.
- ``"none"`` or a model without view dependence: f_dc is the colour at nadir view
  (ω_o = +z), f_rest all zero (viewers show that colour from everywhere).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from brfgs.analysis.renderer import BRFModel
from brfgs.errors import UserError

__all__ = ["SH_C0", "STANDARD_PROPERTIES", "N_SH_REST", "gaussian_cir_colours", "fit_cir_sh", "write_ply",
           "read_ply"]

SH_C0 = 0.28209479177387814
N_SH_REST = 15                       # degree-3 SH bases beyond DC, per colour channel
STANDARD_PROPERTIES = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                       + [f"f_rest_{i}" for i in range(3 * N_SH_REST)] + ["opacity"]
                       + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])
VIEW_DEPENDENCE = ("fit", "none")


def _cir_of(bm: BRFModel, idx: torch.Tensor, omega_o: torch.Tensor, omega_i: torch.Tensor) -> np.ndarray:
    """CIR colour [n, 3] (unclipped) of Gaussians ``idx`` for ω_o [n, 3]."""
    if bm.appearance == "cir" or bm.decoder is None:          # the head's output is the CIR colour itself
        return bm.gaussian_latent(omega_i, omega_o, idx).numpy()
    refl = bm.decode(bm.gaussian_latent(omega_i, omega_o, idx))
    return refl[:, list(bm.cir_indices)] / np.asarray(bm.cir_scale, float)[None]


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
        out[i:i + len(idx)] = np.clip(_cir_of(bm, idx, oo, omega_i), 0.0, 1.0)
    return out


def hemisphere_directions(n: int, max_zenith_deg: float = 80.0) -> np.ndarray:
    """``n`` unit directions [n, 3] (z > 0) spread evenly (Fibonacci spiral, equal solid angle)
    over the cap of zenith ≤ ``max_zenith_deg``; the first is nadir."""
    n = max(int(n), 1)
    cmin = np.cos(np.radians(max_zenith_deg))
    k = np.arange(n)
    cz = 1.0 - (1.0 - cmin) * k / max(n - 1, 1)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    r = np.sqrt(np.clip(1.0 - cz ** 2, 0.0, None))
    return np.stack([r * np.sin(phi), r * np.cos(phi), cz], 1)


def _sh_cir_exact(bm: BRFModel) -> tuple[np.ndarray, np.ndarray] | None:
    """(f_dc [N, 3], f_rest [N, 3, 15]) copied from a CIR-space SH head (no decoder), else None."""
    cfg = bm.head_cfg
    if cfg is None or cfg.kind != "sh" or not (bm.appearance == "cir" or bm.decoder is None):
        return None
    sh = bm.head_params()["sh"].detach().double().numpy()        # [N, K, 3], argument ω_o, no +0.5 offset
    if sh.shape[-1] != 3:
        return None
    k = sh.shape[1]
    fdc = sh[:, 0] - 0.5 / SH_C0
    rest = np.zeros((sh.shape[0], 3, N_SH_REST))
    deg = np.array([1, 1, 1, 2, 2, 2, 2, 2, 3, 3, 3, 3, 3, 3, 3])
    sign = np.where(deg % 2 == 1, -1.0, 1.0)                     # Y_l(−d) = (−1)^l Y_l(d)
    rest[:, :, : k - 1] = (sh[:, 1:] * sign[: k - 1, None]).transpose(0, 2, 1)
    return fdc, rest


@torch.no_grad()
def fit_cir_sh(bm: BRFModel, n_directions: int = 48, max_zenith_deg: float = 80.0, chunk: int = 2048
               ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Degree-3 SH fit of every Gaussian's view-dependent CIR colour (see the module docstring).

    Returns (f_dc [N, 3], f_rest [N, 3, 15] in the 3DGS channel-major layout, info): a viewer
    computes colour = clip(C0·f_dc + Σ_k Y_k(−ω_o)·f_rest[:, :, k−1] + 0.5, 0, 1) and gets the
    CIR colour of the model for view direction ω_o to the accuracy reported in ``info``
    (RMS and max residual over the sampled directions, colour units).
    """
    from brfgs.brdf.sh import sh_basis

    exact = _sh_cir_exact(bm)
    if exact is not None:
        return exact[0].astype(np.float32), exact[1].astype(np.float32), {"method": "copied (CIR SH head)"}
    up = hemisphere_directions(n_directions, max_zenith_deg)                       # ω_o, [K, 3]
    both = np.concatenate([up, up * np.array([1.0, 1.0, -1.0])])                   # mirrored below the ground
    basis = sh_basis(3, torch.from_numpy(-both)).numpy()                           # viewer argument −ω_o, [2K, 16]
    pinv = np.linalg.pinv(basis)                                                    # [16, 2K]
    kdir = len(up)
    omega_i = bm.sun_direction()
    n = bm.n_gaussians
    fdc = np.zeros((n, 3), np.float32)
    rest = np.zeros((n, 3, N_SH_REST), np.float32)
    sq, mx, cnt = 0.0, 0.0, 0
    oo_all = torch.from_numpy(up.astype(np.float32))
    for i in range(0, n, chunk):
        idx = torch.arange(i, min(n, i + chunk))
        m = int(idx.numel())
        oo = oo_all[None].expand(m, kdir, 3).reshape(-1, 3).contiguous()
        ii = idx[:, None].expand(m, kdir).reshape(-1)
        c = np.clip(_cir_of(bm, ii, oo, omega_i), 0.0, 1.0).reshape(m, kdir, 3) - 0.5   # viewer adds 0.5
        target = np.concatenate([c, c], 1)                                          # [m, 2K, 3]
        coef = np.einsum("jk,mkc->mjc", pinv, target)                               # [m, 16, 3]
        res = np.einsum("kj,mjc->mkc", basis, coef) - target
        sq += float((res[:, :kdir] ** 2).sum())
        mx = max(mx, float(np.abs(res[:, :kdir]).max()) if m else 0.0)
        cnt += res[:, :kdir].size
        fdc[i:i + m] = coef[:, 0]
        rest[i:i + m] = coef[:, 1:].transpose(0, 2, 1)
    info = {"method": "least-squares SH degree 3 fit of the CIR colour", "n_directions": kdir,
            "max_view_zenith_deg": max_zenith_deg, "mirrored_below_horizon": True,
            "rms_residual": float(np.sqrt(sq / max(cnt, 1))), "max_residual": mx}
    return fdc, rest, info


@torch.no_grad()
def write_ply(path: str | Path, bm: BRFModel, colours: np.ndarray | None = None, *, view_dependence: str = "fit",
              n_directions: int = 48, info: dict | None = None) -> Path:
    """Write the Gaussians of ``bm`` as a 3DGS PLY with BRF extras (see the module docstring).

    ``colours`` [N, 3] in [0, 1]: explicit view-independent colours (f_rest zero).
    ``info``: a dict that receives how the colours were made (method, fit residuals).
    """
    from plyfile import PlyData, PlyElement

    from brfgs.brdf.geometry import gaussian_normals

    if view_dependence not in VIEW_DEPENDENCE:
        raise UserError(f"view dependence must be one of {', '.join(VIEW_DEPENDENCE)}, got {view_dependence!r}",
                        field="--view-dependence")
    info = {} if info is None else info

    m = bm.model
    n = m.n
    means = m.means.detach().float()
    quats = m.quats.detach().float()
    qn = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    log_scales = m.params["log_scales"].detach().float()
    up = torch.tensor([0.0, 0.0, 1.0]).expand(n, 3)
    normals = gaussian_normals(quats, log_scales.exp(), up)
    rest = np.zeros((n, 3, N_SH_REST), np.float32)
    view_dep = bm.appearance == "neural" or (bm.head_cfg is not None and bm.head_cfg.view_dependent)
    if colours is None and view_dependence == "fit" and view_dep:
        fdc, rest, fit = fit_cir_sh(bm, n_directions=n_directions)
        info.update(fit)
    else:
        if colours is None:
            colours = gaussian_cir_colours(bm)
            info["method"] = "colour at nadir view (no view dependence)"
        else:
            info["method"] = "colours given (no view dependence)"
        fdc = (np.asarray(colours, np.float32) - 0.5) / SH_C0
    cols: dict[str, np.ndarray] = {}
    for j, k in enumerate("xyz"):
        cols[k] = means[:, j].numpy()
    for j, k in enumerate(("nx", "ny", "nz")):
        cols[k] = normals[:, j].numpy()
    for j in range(3):
        cols[f"f_dc_{j}"] = fdc[:, j]
    for c in range(3):
        for k in range(N_SH_REST):
            cols[f"f_rest_{c * N_SH_REST + k}"] = rest[:, c, k]
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
    if "sh" in m.params and m.params["sh"].dim() == 3:
        sh = m.params["sh"].detach().float().numpy()
        for k in range(sh.shape[1]):
            for j in range(sh.shape[2]):
                cols[f"sh_{k}_{j}"] = sh[:, k, j]
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
    comments = [f"brfgs BRF-GS export: scene {bm.scene_name}",
                f"f_dc/f_rest = CIR (850/650/550 nm) colour as SH degree 3: {info['method']}",
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
