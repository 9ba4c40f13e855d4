"""Constants and small helpers shared by the rasterizer backends.

All backends implement the same 3DGS semantics (Kerbl et al. 2023, as in gsplat):

* EWA projection: Σ' = J W Σ Wᵀ Jᵀ + 0.3·I (the 0.3 px² low-pass), with the Jacobian's
  x/z and y/z clamped to 1.3× the half field of view (gsplat's ``lim_x``/``lim_y``).
* A Gaussian is *visible* when near < z < far, its 2D covariance is positive definite,
  its opacity exceeds 1/255 and its footprint meets the image.
* Footprint ("radius"): the axis-aligned box of the ellipse where o·exp(-σ) ≥ 1/255,
  i.e. σ ≤ ln(255·o). Binning by this opacity-aware box makes the image independent of
  the tiling: every pixel/Gaussian pair with α ≥ 1/255 is composited.
* Compositing front to back in depth order (stable sort: ties by Gaussian index):
  α = min(0.99, o·exp(-σ)), σ = ½(a·dx² + c·dy²) + b·dx·dy with the conic (a, b, c) and
  dx = pixel centre − mean (pixel centres at +0.5); pairs with α < 1/255 are skipped; a
  pixel stops before the Gaussian that would bring its transmittance below 1e-4.
"""

from __future__ import annotations

from typing import Any

# NOTE: the numba kernels freeze these constants at compile time and numba's on-disk cache
# only watches _numba_kernels.py and _numba_project.py: after changing a constant here, touch both (or delete
# src/brfgs/render/__pycache__) so that the kernels recompile.

TILE = 16                 # tile edge in pixels
EPS2D = 0.3               # low-pass added to the 2D covariance, px²
ALPHA_MIN = 1.0 / 255.0   # pairs with a smaller alpha are skipped
ALPHA_MAX = 0.99          # alpha clamp
T_MIN = 1e-4              # a pixel stops before its transmittance falls below this
NEAR_PLANE = 0.01         # metres
FAR_PLANE = 1e10          # metres
CLAMP_FOV = 1.3           # Jacobian clamp, multiple of the half field of view (gsplat)
# Margins that make the footprint box a safe superset of the α ≥ 1/255 ellipse.
EXTENT_REL = 1e-6
EXTENT_ABS = 1e-6


def fov_limits(
    K: Any,  # [3, 3] px: tensor, array or nested lists
    width: int,  # px
    height: int,  # px
) -> tuple[float, float, float, float]:  # lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos
    """Bounds of x/z and y/z in the EWA Jacobian: 1.3× the half field of view (gsplat)."""
    fx, fy, cx, cy = float(K[0][0]), float(K[1][1]), float(K[0][2]), float(K[1][2])
    tan_x = 0.5 * width / fx
    tan_y = 0.5 * height / fy
    return (cx / fx + (CLAMP_FOV - 1.0) * tan_x, (width - cx) / fx + (CLAMP_FOV - 1.0) * tan_x,
            cy / fy + (CLAMP_FOV - 1.0) * tan_y, (height - cy) / fy + (CLAMP_FOV - 1.0) * tan_y)


def n_tiles(
    width: int,  # px
    height: int,  # px
) -> tuple[int, int]:  # tiles along x, along y
    """Number of 16×16 tiles covering the image."""
    return (width + TILE - 1) // TILE, (height + TILE - 1) // TILE

