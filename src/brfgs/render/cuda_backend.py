"""CUDA backend: gsplat's ``rasterization`` (gsplat ≥ 1.4 API) behind brfgs' ``rasterize`` interface.

brfgs already uses gsplat's camera convention (world-to-camera ``viewmat`` with OpenCV axes,
pinhole ``K``, pixel centres at +0.5, quaternions wxyz), so the wrapper only adds the camera
batch dimension, appends the normals as extra channels, asks for the expected depth
(``render_mode="RGB+ED"``) and passes ``absgrad`` through (gsplat's own AbsGS gradient).

Known differences from the ``torch``/``cpu`` backends (gsplat's kernels, not configurable):
gsplat clamps alpha at 0.999 (brfgs: 0.99), so pixels under very opaque Gaussian centres
differ; gsplat ≥ 1.5 bins by an opacity-aware box too (1.4: 3σ box, which drops the faint
3σ–3.3σ tails). ``meta["radii"]`` is gsplat's integer radius (max over x, y).
"""

from __future__ import annotations

import torch
from torch import Tensor

from brfgs.render._common import EPS2D, FAR_PLANE, NEAR_PLANE, TILE


def available() -> bool:
    """True when torch sees a CUDA device and gsplat is importable."""
    if not torch.cuda.is_available():
        return False
    try:
        import gsplat  # noqa: F401  (lazy: optional CUDA extension, brfgs[cuda]; absent on CPU machines)
    except Exception:
        return False
    return True


def rasterize_cuda(
    means: Tensor,  # [N, 3] m, world (CUDA)
    quats: Tensor,  # [N, 4] (w, x, y, z)
    scales: Tensor,  # [N, 3] m
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, C]
    viewmat: Tensor,  # [4, 4] world -> camera (OpenCV axes)
    K: Tensor,  # [3, 3] px
    width: int,  # px
    height: int,  # px
    normals: Tensor | None = None,  # [N, 3] or None
    absgrad: bool = False,  # gsplat's absgrad: meta["means2d"].absgrad after the backward pass
    meta_device: torch.device | None = None,  # where meta's tensors live (None: the GPU)
) -> tuple[Tensor, Tensor, Tensor, Tensor | None, dict]:  # image [H, W, C], alpha, depth [H, W], normal, meta
    """Render with gsplat's ``rasterization`` (expected depth, normals as extra channels, between
    brfgs' near and far planes). ``meta["means2d"]`` is a leaf [N, 2] of its own onto which the
    backward pass writes ``.grad`` and ``.absgrad`` (summed over backward passes); with
    ``meta_device`` (a model kept on the CPU) it, radii, visible and depths live there."""
    from gsplat import rasterization  # lazy: optional CUDA extension, brfgs[cuda]

    dev = means.device
    C = features.shape[1]
    colors = features if normals is None else torch.cat([features, normals], 1)  # [N, C(+3)]
    render, alphas, gmeta = rasterization(
        means, quats, scales, opacities, colors,
        viewmat.to(dev, means.dtype)[None], K.to(dev, means.dtype)[None], int(width), int(height),
        near_plane=NEAR_PLANE, far_plane=FAR_PLANE, eps2d=EPS2D, packed=False, tile_size=TILE,
        render_mode="RGB+ED", rasterize_mode="classic", absgrad=absgrad,
    )
    render = render[0]                   # [H, W, C(+3) + 1]
    alpha = alphas[0, ..., 0]            # [H, W]
    image = render[..., :C]
    normal = render[..., C:C + 3] if normals is not None else None
    depth = render[..., -1]              # expected depth Σ w z / Σ w
    m2d_b = gmeta["means2d"]             # [1, N, 2]
    # a leaf [N, 2] that receives the gradient of gsplat's batched tensor (on the GPU, or a CPU copy)
    means2d = m2d_b[0].detach().to(meta_device or m2d_b.device)
    if m2d_b.requires_grad:
        def _hook(grad, _view=means2d):
            g = grad[0].detach().to(_view.device)
            _view.grad = g.clone() if _view.grad is None else _view.grad + g
            ab = getattr(m2d_b, "absgrad", None)  # set by gsplat's backward before this hook runs
            if ab is not None:  # summed over backward passes, as .grad (and as the CPU backends do)
                ab = ab[0].detach().to(_view.device)
                prev = getattr(_view, "absgrad", None)
                _view.absgrad = ab.clone() if prev is None else prev + ab
            return grad

        m2d_b.register_hook(_hook)
    radii = gmeta["radii"][0]
    if radii.dim() == 2:                 # gsplat ≥ 1.5: [N, 2] (x, y); valid where both > 0
        visible = (radii > 0).all(dim=-1)
        radii = torch.where(visible, radii.max(dim=-1).values, torch.zeros_like(radii[:, 0]))
    else:                                # gsplat 1.4: [N]
        visible = radii > 0
    depths = gmeta.get("depths", None)
    if meta_device is not None:
        radii, visible = radii.to(meta_device), visible.to(meta_device)
        depths = None if depths is None else depths.detach().to(meta_device)
    meta = {"means2d": means2d, "radii": radii.to(torch.int32), "visible": visible,
            "depths": depths, "backend": "cuda", "gsplat_meta": gmeta}
    return image, alpha, depth, normal, meta
