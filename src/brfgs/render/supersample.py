"""Pixels as area integrals: render on a grid ``s`` times finer and average each s × s block.

A sensor pixel (and the simulator's truth, rendered with many samples per pixel) integrates the
radiance over its footprint on the ground. 3DGS evaluates each Gaussian at the pixel centre,
widened by a fixed 0.3 px² dilation. Gaussians fitted that way to near-nadir views render a
different pixel integral at 58°, where the ground is foreshortened to half and each pixel's
footprint is larger. Supersampling replaces the point sample by a box integral over the pixel
(``s²`` samples on a regular grid, each at the centre of its sub-pixel), the same function of the
scene in every view. Mip-Splatting's 2D filter (``antialias_opacities``) approximates the same
box with one Gaussian.

The rasterizer's pixel centres lie at +0.5 (``brfgs.render``), so scaling the first two rows of
K by ``s`` maps each pixel [x, x + 1) onto the sub-pixels [s·x, s·x + s) exactly.
"""

from __future__ import annotations

from torch import Tensor

from brfgs.render.rasterize import RenderOutput, normalised_depth


def fine_intrinsics(K: Tensor, factor: int) -> Tensor:
    """K [3, 3] (px) of the grid ``factor`` times finer: fx, fy, cx, cy scaled (pixel centres at +0.5)."""
    Kf = K.clone()
    Kf[:2] *= factor
    return Kf


def box_mean(x: Tensor, factor: int) -> Tensor:
    """[H·s, W·s, ...] -> [H, W, ...]: the mean of each s × s block (s = ``factor``)."""
    h, w = x.shape[0] // factor, x.shape[1] // factor
    return x.reshape(h, factor, w, factor, *x.shape[2:]).mean(dim=(1, 3))


def box_downsample(out: RenderOutput, factor: int) -> RenderOutput:
    """A render on the fine grid -> the pixel integrals of the coarse grid.

    image, alpha and normal (premultiplied / unnormalised sums) are block means; depth is the
    block mean of Σ w z divided by the block's alpha, as the rasterizer normalises it. meta keeps
    the fine grid's per-Gaussian entries, all in fine pixels ("means2d" and its gradient, "radii",
    "radii_xy", "conics"), and adds ``meta["supersample"] = factor``: the unit they are in, which
    the densification reads to convert the gradient.
    """
    if factor == 1:
        return out
    alpha = box_mean(out.alpha, factor)  # [H, W]
    accum = out.meta["depth_accum"] if "depth_accum" in out.meta else out.depth * out.alpha
    accum = box_mean(accum, factor)  # [H, W] Σ w z, m
    depth = normalised_depth(accum, alpha)
    meta = dict(out.meta, depth_accum=accum, supersample=factor)
    normal = None if out.normal is None else box_mean(out.normal, factor)
    return RenderOutput(box_mean(out.image, factor), alpha, depth, normal, meta)
