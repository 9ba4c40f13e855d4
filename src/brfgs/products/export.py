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

Frame (``up``, :func:`ply_frame`): ``"z"`` (default) writes the scene's own frame, ENU metres,
z up. Splat viewers are y-up: ``"y"`` writes x = east, y = up, z = south (glTF's axes), and
``"-y"`` writes the 3DGS/COLMAP convention that SuperSplat and PlayCanvas's viewer expect
(x = east, y = down, z = north; they turn a PLY 180° about z on load, which puts +y up). Both
y frames are centred on the scene (the Gaussians' median) and optionally scaled: x' = s·R(x − c);
rotations (rot_*), normals and the SH colours (fitted in the rotated frame) follow R, log scales
add log s. ``export.json`` records R, c and s so positions map back to ENU metres.
"""

from __future__ import annotations

import hashlib
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement
from torch import Tensor

from brfgs.data.lock import releases_locks
from brfgs.analysis.output import prepare_output_dir
from brfgs.products.options import UP_AXES, VIEW_DEPENDENCE, VIEWER_TARGETS, ExportOptions  # noqa: F401  (re-exported)
from brfgs.brdf.geometry import gaussian_normals
from brfgs.brdf.head import roughness_from_raw
from brfgs.brdf.sh import sh_basis
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.data import atomic

__all__ = ["SH_C0", "STANDARD_PROPERTIES", "N_SH_REST", "VIEW_DEPENDENCE", "UP_AXES", "VIEWER_TARGETS", "PlyFrame",
           "ply_frame", "gaussian_cir_colours",
           "hemisphere_directions", "fit_cir_sh", "write_ply", "read_ply", "ExportOptions", "export_model"]

SH_C0 = 0.28209479177387814
N_SH_REST = 15                       # degree-3 SH bases beyond DC, per colour channel
STANDARD_PROPERTIES = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                       + [f"f_rest_{i}" for i in range(3 * N_SH_REST)] + ["opacity"]
                       + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])


@dataclass(frozen=True)
class PlyFrame:
    """The PLY's frame: x_ply = scale · R (x_enu − centre_m)."""

    up: str = "z"
    centre_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 1.0

    @property
    def angle_rad(self) -> float:
        return float(np.radians(UP_AXES[self.up]))

    @property
    def rotation(self) -> np.ndarray:  # [3, 3]
        c, s = np.cos(self.angle_rad), np.sin(self.angle_rad)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]).round(12)

    @property
    def quaternion(self) -> np.ndarray:  # [4] (w, x, y, z) of R
        return np.array([np.cos(self.angle_rad / 2), np.sin(self.angle_rad / 2), 0.0, 0.0])

    @property
    def is_identity(self) -> bool:
        return self.up == "z" and self.scale == 1.0 and not any(self.centre_m)

    def describe(self) -> dict:
        return {"up": self.up, "rotation_enu_to_ply": self.rotation.tolist(), "centre_m": list(self.centre_m),
                "scale": self.scale, "formula": "x_ply = scale * R @ (x_enu - centre_m)"}


def ply_frame(tm: TrainedModel, up: str = "z", scale: float = 1.0, centre: bool | None = None) -> PlyFrame:
    """The frame for ``up`` ("z", "y", "-y"); centred on the scene unless ``centre`` is False
    (default: centred for the y-up frames, not for "z")."""
    if up not in UP_AXES:
        raise UserError(f"expected one of {', '.join(UP_AXES)}, got {up!r}", field="--up")
    if not (np.isfinite(scale) and scale > 0):
        raise UserError(f"must be a positive number, got {scale!r}", field="--scale")
    centre = up != "z" if centre is None else centre
    c = tuple(float(v) for v in tm.scene_centre_m()) if centre else (0.0, 0.0, 0.0)
    return PlyFrame(up=up, centre_m=c, scale=float(scale))


def _quat_mul(a: Tensor, b: Tensor) -> Tensor:  # [4] ⊗ [N, 4] -> [N, 4], (w, x, y, z)
    w1, x1, y1, z1 = a.unbind(-1)
    w2, x2, y2, z2 = b.unbind(-1)
    return torch.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def _cir_of(
    tm: TrainedModel,
    idx: Tensor,  # [n] long
    omega_o: Tensor,  # [n, 3] unit, toward the camera
    omega_i: Tensor,  # [3] unit, toward the sun
) -> np.ndarray:  # [n, 3]
    """CIR colour [n, 3] (unclipped) of Gaussians ``idx`` for ω_o [n, 3]."""
    if tm.appearance == "cir" or tm.decoder is None:          # the head's output is the CIR colour itself
        return tm.gaussian_latent(omega_i, omega_o, idx).numpy()
    refl = tm.decode(tm.gaussian_latent(omega_i, omega_o, idx))
    return refl[:, list(tm.cir_indices)] / np.asarray(tm.cir_scale, float)[None]


@torch.no_grad()
def gaussian_cir_colours(tm: TrainedModel, chunk: int = 1 << 15) -> np.ndarray:  # [N, 3]
    """CIR colour [N, 3] in [0, 1] of every Gaussian: its decoded reflectance for a nadir view
    (ω_o = +z) under the training sun, bands 850/650/550 nm divided by the CIR scale."""
    n = tm.n_gaussians
    up = torch.tensor([0.0, 0.0, 1.0])
    omega_i = tm.sun_direction()
    out = np.zeros((n, 3), np.float32)
    idx_all = torch.arange(n)
    for i in range(0, n, chunk):
        idx = idx_all[i:i + chunk]
        oo = up.expand(int(idx.numel()), 3).contiguous()
        out[i:i + len(idx)] = np.clip(_cir_of(tm, idx, oo, omega_i), 0.0, 1.0)
    return out


def hemisphere_directions(n: int, max_zenith_deg: float = 80.0) -> np.ndarray:  # [n, 3]
    """``n`` unit directions [n, 3] (z > 0) spread evenly (Fibonacci spiral, equal solid angle)
    over the cap of zenith ≤ ``max_zenith_deg``; the first is nadir."""
    n = max(int(n), 1)
    cmin = np.cos(np.radians(max_zenith_deg))
    k = np.arange(n)
    cz = 1.0 - (1.0 - cmin) * k / max(n - 1, 1)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    r = np.sqrt(np.clip(1.0 - cz ** 2, 0.0, None))
    return np.stack([r * np.sin(phi), r * np.cos(phi), cz], 1)


def _sh_cir_exact(tm: TrainedModel) -> tuple[np.ndarray, np.ndarray] | None:
    """(f_dc [N, 3], f_rest [N, 3, 15]) copied from a CIR-space SH head (no decoder), else None."""
    cfg = tm.head_cfg
    if cfg is None or cfg.kind != "sh" or not (tm.appearance == "cir" or tm.decoder is None):
        return None
    sh = tm.head_params()["sh"].detach().double().numpy()        # [N, K, 3], argument ω_o, no +0.5 offset
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
def fit_cir_sh(tm: TrainedModel, n_directions: int = 48, max_zenith_deg: float = 80.0, chunk: int = 2048,
               rotation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Degree-3 SH fit of every Gaussian's view-dependent CIR colour (see the module docstring).

    Returns (f_dc [N, 3], f_rest [N, 3, 15] in the 3DGS channel-major layout, info): a viewer
    computes colour = clip(C0·f_dc + Σ_k Y_k(−ω_o)·f_rest[:, :, k−1] + 0.5, 0, 1) and gets the
    CIR colour of the model for view direction ω_o to the accuracy reported in ``info``
    (RMS and max residual over the sampled directions, colour units). ``rotation`` [3, 3]: the
    PLY frame's R (ENU → PLY); the SH argument is then R(−ω_o), the direction in the PLY's frame.
    """
    rot = np.eye(3) if rotation is None else np.asarray(rotation, float)
    exact = _sh_cir_exact(tm) if np.allclose(rot, np.eye(3)) else None
    if exact is not None:
        return exact[0].astype(np.float32), exact[1].astype(np.float32), {"method": "copied (CIR SH head)"}
    up = hemisphere_directions(n_directions, max_zenith_deg)                       # ω_o, [K, 3]
    both = np.concatenate([up, up * np.array([1.0, 1.0, -1.0])])                   # mirrored below the ground
    basis = sh_basis(3, torch.from_numpy(-both @ rot.T)).numpy()                   # viewer argument R(−ω_o), [2K, 16]
    pinv = np.linalg.pinv(basis)                                                    # [16, 2K]
    kdir = len(up)
    omega_i = tm.sun_direction()
    n = tm.n_gaussians
    fdc = np.zeros((n, 3), np.float32)
    rest = np.zeros((n, 3, N_SH_REST), np.float32)
    sq, mx, cnt = 0.0, 0.0, 0
    oo_all = torch.from_numpy(up.astype(np.float32))
    for i in range(0, n, chunk):
        idx = torch.arange(i, min(n, i + chunk))
        m = int(idx.numel())
        oo = oo_all[None].expand(m, kdir, 3).reshape(-1, 3).contiguous()
        ii = idx[:, None].expand(m, kdir).reshape(-1)
        c = np.clip(_cir_of(tm, ii, oo, omega_i), 0.0, 1.0).reshape(m, kdir, 3) - 0.5   # viewer adds 0.5
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


def _ply_colours(tm: TrainedModel, colours: np.ndarray | None, view_dependence: str, n_directions: int,
                 info: dict, frame: PlyFrame) -> tuple[np.ndarray, np.ndarray]:
    """(f_dc [N, 3], f_rest [N, 3, 15]) of the PLY (see the module docstring); ``info`` gets the method."""
    view_dep = tm.appearance == "neural" or (tm.head_cfg is not None and tm.head_cfg.view_dependent)
    if colours is None and view_dependence == "fit" and view_dep:
        fdc, rest, fit = fit_cir_sh(tm, n_directions=n_directions, rotation=frame.rotation)
        info.update(fit)
        return fdc, rest
    if colours is None:
        colours = gaussian_cir_colours(tm)
        info["method"] = "colour at nadir view (no view dependence)"
    else:
        info["method"] = "colours given (no view dependence)"
    return (np.asarray(colours, np.float32) - 0.5) / SH_C0, np.zeros((tm.n_gaussians, 3, N_SH_REST), np.float32)


def _ply_columns(tm: TrainedModel, fdc: np.ndarray, rest: np.ndarray, frame: PlyFrame) -> dict[str, np.ndarray]:
    """{property: [N]} in PLY order: the standard 3DGS set (in ``frame``), then the BRF parameters."""
    m = tm.gaussians
    quats = m.quats.detach().float()
    qn = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    log_scales = m.params["log_scales"].detach().float()
    normals = gaussian_normals(quats, log_scales.exp(), torch.tensor([0.0, 0.0, 1.0]).expand(m.n, 3))
    rot = torch.as_tensor(frame.rotation, dtype=torch.float64)
    means = frame.scale * (m.means.detach().double() - torch.as_tensor(frame.centre_m, dtype=torch.float64)) @ rot.T
    normals = (normals.double() @ rot.T).float()
    qn = _quat_mul(torch.as_tensor(frame.quaternion, dtype=torch.float64), qn.double()).float()
    log_scales = log_scales + float(np.log(frame.scale))
    cols: dict[str, np.ndarray] = {}
    for j, k in enumerate("xyz"):
        cols[k] = means[:, j].float().numpy()
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
        if f"z_{c}" in m.params:
            z = m.params[f"z_{c}"].detach().float().numpy()
            cols.update({f"z_{c}_{j}": z[:, j] for j in range(z.shape[1])})
    if "sh" in m.params and m.params["sh"].dim() == 3:
        sh = m.params["sh"].detach().float().numpy()
        cols.update({f"sh_{k}_{j}": sh[:, k, j] for k in range(sh.shape[1]) for j in range(sh.shape[2])})
    if "rho_raw" in m.params and tm.head_cfg is not None:
        cols["roughness"] = roughness_from_raw(m.params["rho_raw"].detach().float(), tm.head_cfg.rho_min).numpy()
    return cols


@torch.no_grad()
def write_ply(
    path: str | Path,
    tm: TrainedModel,
    colours: np.ndarray | None = None,  # [N, 3] in [0, 1]
    *,
    view_dependence: str = "fit",
    n_directions: int = 48,
    info: dict | None = None,
    frame: PlyFrame | None = None,
) -> Path:
    """Write the Gaussians of ``tm`` as a 3DGS PLY with BRF extras (see the module docstring).

    ``colours`` [N, 3] in [0, 1]: explicit view-independent colours (f_rest zero).
    ``info``: a dict that receives how the colours were made (method, fit residuals).
    ``frame``: the PLY's frame (default: ENU metres, as the model).
    """
    frame = PlyFrame() if frame is None else frame
    if view_dependence not in VIEW_DEPENDENCE:
        raise UserError(f"view dependence must be one of {', '.join(VIEW_DEPENDENCE)}, got {view_dependence!r}",
                        field="--view-dependence")
    info = {} if info is None else info
    fdc, rest = _ply_colours(tm, colours, view_dependence, n_directions, info, frame)
    cols = _ply_columns(tm, fdc, rest, frame)
    arr = np.empty(tm.n_gaussians, dtype=[(k, "<f4") for k in cols])
    for k, v in cols.items():
        arr[k] = np.asarray(v, np.float32)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    el = PlyElement.describe(arr, "vertex")
    comments = [f"brfgs BRF-GS export: scene {tm.scene_name}",
                f"f_dc/f_rest = CIR (850/650/550 nm) colour as SH degree 3: {info['method']}",
                f"wavelengths_nm {tm.wavelengths_nm.min():.1f}-{tm.wavelengths_nm.max():.1f} "
                f"({len(tm.wavelengths_nm)} bands); z_* are latent (decode with the model file)",
                f"frame: up {frame.up}, x_ply = {frame.scale:g} * R (x_enu - {list(frame.centre_m)})"]
    with atomic.atomic_path(path) as tmp:
        PlyData([el], text=False, byte_order="<", comments=comments).write(str(tmp))
    return path


def read_ply(path: str | Path) -> dict[str, np.ndarray]:
    """{property: [N] float32} of a PLY's ``vertex`` element (any 3DGS-style file)."""
    path = Path(path)
    if not path.is_file():
        raise UserError("PLY file not found", file=path)
    try:
        ply = PlyData.read(str(path))
        v = ply["vertex"].data
    except Exception as exc:
        raise UserError(f"not a readable PLY with a 'vertex' element ({exc})", file=path) from None
    return {name: np.asarray(v[name]) for name in v.dtype.names}


# ----------------------------------------------------------------------------------------
# the export command


def _copy_model_file(src: Path, dst: Path) -> None:
    """Copy the model file atomically (nothing when ``dst`` is ``src``)."""
    if dst.resolve() != src.resolve():
        shutil.copyfile(src, dst.with_name(dst.name + ".tmp"))
        dst.with_name(dst.name + ".tmp").replace(dst)


@releases_locks
def export_model(run: str | Path, out: str | Path, opts: ExportOptions | None = None) -> dict:
    """``brfgs export``: write OUT/gaussians.ply (:func:`write_ply`), a copy of the model file that
    loads on its own (OUT/model.safetensors) and OUT/export.json; returns what export.json holds."""
    opts = (ExportOptions() if opts is None else opts).validate()
    tm = TrainedModel.load(run)
    out = prepare_output_dir(Path(out), "export.json", opts.overwrite, tm.scene_root)
    src = Path(tm.source)
    frame = ply_frame(tm, opts.up, opts.scale, opts.centre)
    colour_info: dict = {}
    t0 = time.perf_counter()
    ply = write_ply(out / "gaussians.ply", tm, view_dependence=opts.view_dependence, n_directions=opts.sh_directions,
                    info=colour_info, frame=frame)
    t_ply = time.perf_counter() - t0
    dst = out / "model.safetensors"
    _copy_model_file(src, dst)
    TrainedModel.load(dst)  # the copy loads on its own (no scene needed)
    info = {"source": str(src), "ply": ply.name, "model": dst.name,
            "model_sha256": hashlib.sha256(dst.read_bytes()).hexdigest(),
            "n_gaussians": tm.n_gaussians, "latent_dim": tm.gaussians.latent_dim, "bands": len(tm.wavelengths_nm),
            "ply_properties": "x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2 rot_0..3 (standard 3DGS) "
                              "+ z_iso_*, z_vol_*, z_geo_*, z_spec_*, roughness (BRF-GS) or sh_<k>_<j> (SH baseline)",
            "ply_colours": {"space": "CIR composite (850/650/550 nm as R/G/B, scaled like the training data)",
                            "sun_zenith_deg": tm.sun_zenith_deg, "sun_azimuth_deg": tm.sun_azimuth_deg,
                            **colour_info},
            "ply_frame": frame.describe(),
            "timings_s": {"ply": t_ply},
            "model_format": "safetensors + JSON metadata (brfgs-gaussians/1); loading never executes code"}
    atomic.write_json(out / "export.json", info)
    return info
