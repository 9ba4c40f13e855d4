"""``rasterize``: differentiable 3D Gaussian splatting of one camera, three backends."""

from __future__ import annotations

import os
from typing import NamedTuple

import torch

from brfgs.errors import UserError
from brfgs.render._common import FAR_PLANE, NEAR_PLANE

BACKENDS = ("auto", "torch", "cpu", "cuda")
_threads_configured = False


class RenderOutput(NamedTuple):
    """Rendered planes of one camera.

    image [H, W, C]; alpha [H, W] (1 − final transmittance);
    depth [H, W] expected depth in metres, Σ w_i z_i / Σ w_i (0 where alpha = 0), z along the
    optical axis; normal [H, W, 3] Σ w_i n_i (not normalised, not divided by alpha) or None;
    meta: dict with "means2d" [N, 2] (pixels; its .grad after backward is the screen-space
    positional gradient), "radii" [N] int32 (px, 0 = not visible), "radii_xy" [N, 2],
    "visible" [N] bool, "depth_accum" [H, W] (Σ w_i z_i), "depths" [N] camera z, "backend".
    """

    image: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    normal: torch.Tensor | None
    meta: dict


def configure_threads(n: int | None = None) -> int:
    """Set numba's and PyTorch's thread counts to ``n`` (default: $BRFGS_NUM_THREADS or all cores).

    The ``cpu`` backend alternates between numba kernels and small PyTorch ops, never both at
    once, so both pools get the same count; the pools do not overlap in time. Without a call,
    the first ``cpu`` render sets numba's count to torch's (or to $BRFGS_NUM_THREADS, applied to
    both). On a machine shared with other jobs, start the process with OMP_WAIT_POLICY=PASSIVE
    (before torch is imported): idle OpenMP threads then sleep instead of spinning, which was
    1.2–3.4× faster in wall time at load average ~12 on 2 cores (BENCHMARKS). Returns ``n``.
    """
    global _threads_configured
    import numba

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
    import numba

    env = os.environ.get("BRFGS_NUM_THREADS")
    if env:
        configure_threads(int(env))
        return
    numba.set_num_threads(max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)))
    _threads_configured = True


def resolve_backend(backend: str, device: torch.device) -> str:
    """'auto' → 'cuda' when the inputs live on a CUDA device (gsplat needed), else 'cpu'."""
    if backend not in BACKENDS:
        raise UserError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}", field="backend")
    if backend == "auto":
        if device.type == "cuda":
            backend = "cuda"
        else:
            return "cpu"
    if backend == "cuda":
        from brfgs.render import cuda_backend

        if not cuda_backend.available():
            raise UserError("backend 'cuda' needs a CUDA GPU visible to torch and gsplat installed "
                            "(pip install 'brfgs[cuda]')", field="backend")
    return backend


def _check(name, t, shape, dtype=None):
    if not isinstance(t, torch.Tensor):
        raise UserError(f"{name} must be a torch tensor", field=name)
    if t.dim() != len(shape) or any(s is not None and t.shape[i] != s for i, s in enumerate(shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise UserError(f"{name} has shape {list(t.shape)}, expected {want}", field=name)
    if dtype is not None and t.dtype != dtype:
        raise UserError(f"{name} has dtype {t.dtype}, expected {dtype} like means", field=name)


def rasterize(means, quats, scales, opacities, features, viewmat, K, width, height, backend="auto",
              normals=None, background=None, near_plane=NEAR_PLANE, far_plane=FAR_PLANE) -> RenderOutput:
    """Render N Gaussians into one camera with 3DGS semantics (see ``brfgs.render``).

    means [N,3] (m, world ENU), quats [N,4] (wxyz, any norm), scales [N,3] (m, > 0),
    opacities [N] (0..1), features [N,C] (any C), viewmat [4,4] world-to-camera (OpenCV axes),
    K [3,3] pinhole (pixel centres at +0.5), width/height in pixels, normals [N,3] or None,
    background [C] or None (added as (1 − alpha)·background).
    Gradients flow to means, quats, scales, opacities, features and normals.
    """
    N = means.shape[0] if isinstance(means, torch.Tensor) and means.dim() == 2 else None
    _check("means", means, (None, 3))
    dt = means.dtype
    if dt not in (torch.float32, torch.float64):
        raise UserError(f"means has dtype {dt}, expected float32 or float64", field="means")
    _check("quats", quats, (N, 4), dt)
    _check("scales", scales, (N, 3), dt)
    _check("opacities", opacities, (N,), dt)
    _check("features", features, (N, None), dt)
    _check("viewmat", viewmat, (4, 4))
    _check("K", K, (3, 3))
    if normals is not None:
        _check("normals", normals, (N, 3), dt)
    C = features.shape[1]
    if background is not None:
        _check("background", background, (C,), dt)
    width, height = int(width), int(height)
    if width <= 0 or height <= 0:
        raise UserError(f"image size {width}x{height} must be positive", field="width/height")
    be = resolve_backend(backend, means.device)

    if be == "cuda":
        from brfgs.render.cuda_backend import rasterize_cuda

        if means.device.type != "cuda":  # explicit backend="cuda" with CPU tensors: move (differentiably)
            dev = torch.device("cuda")
            means, quats, scales, opacities, features = (t.to(dev) for t in (means, quats, scales, opacities, features))
            normals = None if normals is None else normals.to(dev)
            background = None if background is None else background.to(dev)

        image, alpha, depth, normal, meta = rasterize_cuda(
            means, quats, scales, opacities, features, viewmat, K, width, height,
            normals=normals, near=near_plane, far=far_plane)
        if background is not None:
            image = image + (1 - alpha)[..., None] * background
        return RenderOutput(image, alpha, depth, normal, meta)

    if means.device.type != "cpu":
        raise UserError(f"backend {be!r} needs CPU tensors, got device {means.device}", field="backend")
    if be == "cpu":
        from brfgs.render import cpu_backend as mod

        if not _threads_configured:
            _default_threads()
    else:
        from brfgs.render import torch_backend as mod

    viewmat = viewmat.detach().to(torch.float64)
    K = K.detach().to(torch.float64)
    proj = mod.project(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane)
    parts = [features, proj.depths[:, None]]
    if normals is not None:
        parts.append(normals)
    colors = torch.cat(parts, 1)                                   # [N, C + 1 (+3)]
    planes, alpha = mod.raster(proj, opacities, colors, width, height)
    image = planes[..., :C]
    depth_accum = planes[..., C]
    normal = planes[..., C + 1:C + 4] if normals is not None else None
    if background is not None:
        image = image + (1 - alpha)[..., None] * background
    depth = torch.where(alpha > 0, depth_accum / alpha.clamp_min(1e-10), torch.zeros_like(alpha))
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    radii_xy = proj.radii_xy.detach()
    radii = torch.ceil(radii_xy.max(dim=1).values).to(torch.int32)
    meta = {"means2d": means2d, "radii": radii, "radii_xy": radii_xy, "visible": proj.visible,
            "depths": proj.depths, "depth_accum": depth_accum, "conics": proj.conics, "backend": be}
    return RenderOutput(image, alpha, depth, normal, meta)
