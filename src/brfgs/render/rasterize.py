"""``rasterize``: differentiable 3D Gaussian splatting of one camera, three backends."""

from __future__ import annotations

import os
from typing import NamedTuple

import numba
import torch
from torch import Tensor

from brfgs.errors import UserError
from brfgs.render import cpu_backend, cuda_backend, torch_backend
from brfgs.render._common import EPS2D, FAR_PLANE, NEAR_PLANE

BACKENDS = ("auto", "torch", "cpu", "cuda")
_threads_configured = False


class RenderOutput(NamedTuple):
    """Rendered planes of one camera.

    depth is the expected depth Σ w_i z_i / Σ w_i (0 where alpha = 0), z along the optical axis;
    normal is Σ w_i n_i (not normalised, not divided by alpha). meta: "means2d" [N, 2] px (its
    .grad after backward is the screen-space positional gradient, its .absgrad AbsGS's sum of the
    per-pixel gradients' absolute values), "radii" [N] int32 (px, 0 = not
    visible), "radii_xy" [N, 2] px, "visible" [N] bool, "depth_accum" [H, W] (Σ w_i z_i, m),
    "depths" [N] camera z (m), "conics" [N, 3] (cpu/torch), "backend".
    """

    image: Tensor  # [H, W, C] premultiplied (a background is the caller's: image + (1 − alpha)·bg)
    alpha: Tensor  # [H, W] 1 − final transmittance
    depth: Tensor  # [H, W] m
    normal: Tensor | None  # [H, W, 3] or None
    meta: dict


def configure_threads(n: int | None = None) -> int:
    """Set numba's and PyTorch's thread counts to ``n`` (default: $BRFGS_NUM_THREADS or all cores).

    The ``cpu`` backend alternates between numba kernels and small PyTorch ops, never both at
    once, so both pools get the same count; the pools do not overlap in time. Without a call,
    the first ``cpu`` render sets numba's count to torch's (or to $BRFGS_NUM_THREADS, applied to
    both). How long idle OpenMP threads spin before they sleep matters on a shared machine: the
    ``brfgs`` command sets GOMP_SPINCOUNT=1000 before torch is imported (BENCHMARKS.md, "OpenMP threads"). Returns ``n``.
    """
    global _threads_configured
    if n is None:
        env = os.environ.get("BRFGS_NUM_THREADS")
        n = int(env) if env else (os.cpu_count() or 1)
    n = max(1, min(int(n), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    torch.set_num_threads(n)
    _threads_configured = True
    return n


def _default_threads() -> None:
    """First use of the cpu backend without configure_threads: numba follows torch's count
    (or $BRFGS_NUM_THREADS); torch's own setting is left as the user made it."""
    global _threads_configured
    env = os.environ.get("BRFGS_NUM_THREADS")
    if env:
        configure_threads(int(env))
        return
    numba.set_num_threads(max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)))
    _threads_configured = True


def resolve_backend(
    backend: str,  # "auto" | "torch" | "cpu" | "cuda"
    device: torch.device,  # where the inputs live
) -> str:  # "torch" | "cpu" | "cuda"
    """'auto' → 'cuda' when the inputs live on a CUDA device (gsplat needed), else 'cpu'."""
    if backend not in BACKENDS:
        raise UserError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}", field="backend")
    if backend == "auto":
        if device.type == "cuda":
            backend = "cuda"
        else:
            return "cpu"
    if backend == "cuda":
        if not cuda_backend.available():
            raise UserError("backend 'cuda' needs a CUDA GPU visible to torch and gsplat installed "
                            "(pip install 'brfgs[cuda]')", field="backend")
    return backend


def _check(name: str, t, shape: tuple, dtype: torch.dtype | None = None) -> None:
    """UserError unless ``t`` is a tensor of ``shape`` (None: any size) and, if given, ``dtype``."""
    if not isinstance(t, torch.Tensor):
        raise UserError(f"{name} must be a torch tensor", field=name)
    if t.dim() != len(shape) or any(s is not None and t.shape[i] != s for i, s in enumerate(shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise UserError(f"{name} has shape {list(t.shape)}, expected {want}", field=name)
    if dtype is not None and t.dtype != dtype:
        raise UserError(f"{name} has dtype {t.dtype}, expected {dtype} like means", field=name)


class _Splats(NamedTuple):
    """The per-Gaussian inputs of one render (see :func:`rasterize`)."""

    means: Tensor  # [N, 3] m
    quats: Tensor  # [N, 4]
    scales: Tensor  # [N, 3] m
    opacities: Tensor  # [N]
    features: Tensor  # [N, C]
    normals: Tensor | None  # [N, 3] or None


def _check_inputs(g: _Splats, viewmat, K) -> None:
    """UserError for a wrong type, shape or dtype of any input of :func:`rasterize`."""
    means = g.means
    N = means.shape[0] if isinstance(means, torch.Tensor) and means.dim() == 2 else None
    _check("means", means, (None, 3))
    dt = means.dtype
    if dt not in (torch.float32, torch.float64):
        raise UserError(f"means has dtype {dt}, expected float32 or float64", field="means")
    _check("quats", g.quats, (N, 4), dt)
    _check("scales", g.scales, (N, 3), dt)
    _check("opacities", g.opacities, (N,), dt)
    _check("features", g.features, (N, None), dt)
    _check("viewmat", viewmat, (4, 4))
    _check("K", K, (3, 3))
    if g.normals is not None:
        _check("normals", g.normals, (N, 3), dt)


def normalised_depth(depth_accum: Tensor, alpha: Tensor) -> Tensor:
    """Expected depth Σ w z / Σ w [H, W] (m) from Σ w z and alpha [H, W]; 0 where alpha = 0."""
    return torch.where(alpha > 0, depth_accum / alpha.clamp_min(1e-10), torch.zeros_like(alpha))


def rasterize(
    means: Tensor,  # [N, 3] m, world (ENU)
    quats: Tensor,  # [N, 4] (w, x, y, z), any norm
    scales: Tensor,  # [N, 3] m, > 0
    opacities: Tensor,  # [N] in (0, 1)
    features: Tensor,  # [N, C] any C
    viewmat: Tensor,  # [4, 4] world -> camera, OpenCV axes
    K: Tensor,  # [3, 3] pinhole, px (pixel centres at +0.5)
    width: int,  # px
    height: int,  # px
    backend: str = "auto",  # "auto" | "torch" | "cpu" | "cuda"
    normals: Tensor | None = None,  # [N, 3] composited like features, or None
    absgrad: bool = False,  # also set meta["means2d"].absgrad in the backward pass (AbsGS)
) -> RenderOutput:
    """Render N Gaussians into one camera with 3DGS semantics (see ``brfgs.render``).

    EWA splatting (Kerbl et al. 2023, eqs 5–6) of the Gaussians G_k of the paper's eq. 10, whose
    ``features`` (e.g. latent spectra z_k, eq. 12) are alpha-composited front to back in depth
    order between the near and far planes ``render._common.NEAR_PLANE`` / ``FAR_PLANE``
    (0.01 m, 1e10 m). All tensors share the dtype of ``means`` (float32 or float64); outputs are
    described in :class:`RenderOutput`. Gradients flow to means, quats, scales, opacities,
    features and normals. For anti-aliased splatting pass the opacities through
    :func:`antialias_opacities` first (same for every backend). With ``absgrad`` the backward
    pass also sets ``meta["means2d"].absgrad`` [N, 2]: Σ over pixels of |∂L_p/∂x|, |∂L_p/∂y|, the
    screen-space gradient of AbsGS (Ye et al. 2024; gsplat's ``absgrad=True``). The image is
    premultiplied; a background is composited by the caller (``brfgs.model.rendering.composite_background``).
    """
    g = _Splats(means, quats, scales, opacities, features, normals)
    _check_inputs(g, viewmat, K)
    width, height = int(width), int(height)
    if width <= 0 or height <= 0:
        raise UserError(f"image size {width}x{height} must be positive", field="width/height")
    be = resolve_backend(backend, means.device)
    if be == "cuda":
        return _rasterize_cuda(g, viewmat, K, width, height, absgrad)
    if means.device.type != "cpu":
        raise UserError(f"backend {be!r} needs CPU tensors, got device {means.device}", field="backend")
    return _rasterize_cpu(be, g, viewmat, K, width, height, absgrad)


def antialias_opacities(
    means: Tensor,  # [N, 3] m, world
    quats: Tensor,  # [N, 4] (w, x, y, z)
    scales: Tensor,  # [N, 3] m
    opacities: Tensor,  # [N]
    viewmat: Tensor,  # [4, 4] world -> camera
    K: Tensor,  # [3, 3] px
    width: int,  # px
    height: int,  # px
) -> Tensor:  # [N] opacities for this camera
    """Mip-Splatting's 2D mip filter (Yu et al. 2024, eq. 9; gsplat's ``rasterize_mode="antialiased"``):
    o' = o · sqrt(det Σ2D / det(Σ2D + 0.3 I)), Σ2D the projected covariance before the low-pass.

    The low-pass widens a sub-pixel Gaussian to about a pixel; without the factor it then covers
    that pixel with its full opacity, so a Gaussian fitted to near-nadir views (where it spans
    pixels) brightens and thickens where a view sees it smaller (oblique or distant views).
    With it, the integral of o·G over the image is the same with and without the low-pass: the
    splat acts as a box-filtered (anti-aliased) footprint. Gaussians behind the camera keep o.
    """
    _, in_depth, cov2 = torch_backend.camera_cov2d(means, quats, scales, viewmat.detach().to(torch.float64),
                                                   K.detach().to(torch.float64), width, height, NEAR_PLANE, FAR_PLANE)
    a, b, c = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]  # [N] px²
    det_raw = (a * c - b * b).clamp_min(1e-20)
    det_blur = (a + EPS2D) * (c + EPS2D) - b * b
    comp = torch.sqrt(det_raw / det_blur)  # [N] in (0, 1)
    return opacities * torch.where(in_depth, comp, torch.ones_like(comp))


def _rasterize_cuda(g: _Splats, viewmat: Tensor, K: Tensor, width: int, height: int,
                    absgrad: bool) -> RenderOutput:
    """gsplat on the GPU. CPU inputs (an explicit backend="cuda", a model kept on the CPU) are moved
    there and the outputs and meta back, differentiably: only the rasterization runs on the GPU."""
    home = g.means.device
    if home.type != "cuda":
        dev = torch.device("cuda")
        g = _Splats(*(None if t is None else t.to(dev) for t in g))
    image, alpha, depth, normal, meta = cuda_backend.rasterize_cuda(
        g.means, g.quats, g.scales, g.opacities, g.features, viewmat, K, width, height,
        normals=g.normals, absgrad=absgrad, meta_device=None if home.type == "cuda" else home)
    if home.type != "cuda":
        image, alpha, depth = image.to(home), alpha.to(home), depth.to(home)
        normal = None if normal is None else normal.to(home)
    return RenderOutput(image, alpha, depth, normal, meta)


def _rasterize_cpu(be: str, g: _Splats, viewmat: Tensor, K: Tensor, width: int, height: int,
                   absgrad: bool) -> RenderOutput:
    """The ``cpu`` (numba) or ``torch`` backend: project, composite features, depth and normals."""
    if be == "cpu":
        mod = cpu_backend
        if not _threads_configured:
            _default_threads()
    else:
        mod = torch_backend
    C = g.features.shape[1]
    viewmat = viewmat.detach().to(torch.float64)
    K = K.detach().to(torch.float64)
    proj = mod.project(g.means, g.quats, g.scales, g.opacities, viewmat, K, width, height, NEAR_PLANE, FAR_PLANE)
    parts = [g.features, proj.depths[:, None]]
    if g.normals is not None:
        parts.append(g.normals)
    colors = torch.cat(parts, 1)                                   # [N, C + 1 (+3)]
    planes, alpha = mod.raster(proj, g.opacities, colors, width, height, absgrad)
    image = planes[..., :C]
    depth_accum = planes[..., C]
    normal = planes[..., C + 1:C + 4] if g.normals is not None else None
    depth = normalised_depth(depth_accum, alpha)
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    radii_xy = proj.radii_xy.detach()
    radii = torch.ceil(radii_xy.max(dim=1).values).to(torch.int32)
    meta = {"means2d": means2d, "radii": radii, "radii_xy": radii_xy, "visible": proj.visible,
            "depths": proj.depths, "depth_accum": depth_accum, "conics": proj.conics, "backend": be}
    return RenderOutput(image, alpha, depth, normal, meta)
