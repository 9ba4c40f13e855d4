"""The Gaussian parameter container (paper eqs. 10-11) and its initialisation.

A :class:`GaussianModel` is a plain dict of named leaf tensors, all with N rows:

=================  ===========  ============================================================
name               shape        meaning
=================  ===========  ============================================================
means              [N, 3]       centre mu_k (metres, ENU)
log_scales         [N, 3]       log of the Gaussian's standard deviations (metres)
quats              [N, 4]       rotation (w, x, y, z), normalised when used
opacity_logits     [N]          o_k = sigmoid(logit)
colors             [N, k]       stage-1 reflectance in the k geometry-reliable bands
colors_kernels     [N, 2, k]    optional K_Ross and K_Li coefficients of the stage-1 colours
z_iso .. z_spec    [N, d]       latent kernel coefficients (eq. 11-12), appearance "brf"
rho_raw            [N]          roughness (brfgs.brdf.head.roughness_from_raw)
sh                 [N, 16, c]   SH coefficients (appearance "sh": c = d; "cir": c = 3)
feat               [N, d]       per-Gaussian feature of the neural baseline
=================  ===========  ============================================================

Which appearance tensors exist depends on ``appearance`` ("brf", "sh", "neural", "cir").
Densification and pruning (:mod:`brfgs.model.densify`) act on every tensor row-wise.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch
from scipy.spatial import Delaunay, cKDTree
from torch import Tensor

from brfgs.init.mvs import height_field

GEOMETRY_KEYS = ("means", "log_scales", "quats", "opacity_logits")
# kept when the appearance head is replaced: the stage-1 colours
KEPT_KEYS = ("colors", "colors_kernels")
APPEARANCES = ("brf", "sh", "neural", "cir")


def inverse_sigmoid(x: Tensor | float) -> Tensor:  # same shape as x
    """logit(x) = log(x / (1 - x)), float32."""
    x = torch.as_tensor(x, dtype=torch.float32)
    return torch.log(x / (1 - x))


class GaussianModel:
    """Named per-Gaussian tensors; see the module docstring for the layout."""

    def __init__(self, params: dict[str, torch.Tensor], appearance: str, latent_dim: int, n_colors: int):
        if appearance not in APPEARANCES:
            raise ValueError(f"appearance must be one of {APPEARANCES}, got {appearance!r}")
        self.params = {k: v.detach().clone().requires_grad_(True) for k, v in params.items()}
        self.appearance = appearance
        self.latent_dim = int(latent_dim)
        self.n_colors = int(n_colors)
        self.centred = False  # hybrid head in the centred training form (brfgs.model.features.centred_hybrid_latent)

    # -- views -----------------------------------------------------------------
    def __getitem__(self, key: str) -> torch.Tensor:
        return self.params[key]

    def __contains__(self, key: str) -> bool:
        return key in self.params

    @property
    def n(self) -> int:
        return int(self.params["means"].shape[0])

    @property
    def means(self) -> torch.Tensor:
        return self.params["means"]

    @property
    def scales(self) -> torch.Tensor:
        """Standard deviations [N, 3] m."""
        return torch.exp(self.params["log_scales"])

    @property
    def quats(self) -> torch.Tensor:
        return self.params["quats"]

    @property
    def opacities(self) -> torch.Tensor:
        """Opacities [N]."""
        return torch.sigmoid(self.params["opacity_logits"])

    def state(self) -> dict[str, torch.Tensor]:
        """Detached copies of every tensor (for checkpoints)."""
        return {k: v.detach().contiguous().clone() for k, v in self.params.items()}

    def replace(self, new: dict[str, torch.Tensor]) -> None:
        """Replace tensors (after densification) with fresh leaves."""
        self.params = {k: v.detach().contiguous().requires_grad_(True) for k, v in new.items()}

    # -- appearance tensors ----------------------------------------------------
    def set_head(self, head_params: dict[str, torch.Tensor], appearance: str) -> None:
        """Replace the appearance tensors by ``head_params`` (brfgs.brdf.head.init_head_params
        names: z_iso.., rho_raw, sh, color; or "feat" for the neural baseline)."""
        for k in list(self.params):
            if k not in GEOMETRY_KEYS and k not in KEPT_KEYS:
                del self.params[k]
        for k, v in head_params.items():
            self.params[k] = v.detach().float().clone().requires_grad_(True)
        self.appearance = appearance


def knn_scale(
    points: np.ndarray,  # [P, 3] m
    k: int = 3,
) -> np.ndarray:  # [P] m
    """RMS distance to the k nearest neighbours of each point [P] (3DGS initial scale)."""
    p = np.asarray(points, np.float64)
    if p.shape[0] < 2:
        return np.ones(p.shape[0])
    kk = min(k + 1, p.shape[0])
    d, _ = cKDTree(p).query(p, k=kk)
    d = d[:, 1:]
    out = np.sqrt((d**2).mean(1))
    med = np.median(out[out > 0]) if (out > 0).any() else 1.0
    return np.where(out > 0, out, med)


def init_from_points(
    points: np.ndarray,  # [P, 3] m (ENU)
    colors: np.ndarray,  # [P, k] or [P] reflectance
    latent_dim: int,
    init_opacity: float = 0.1,
    scale_mult: float = 1.0,
) -> GaussianModel:
    """Gaussians at sparse points ``[P, 3]`` with stage-1 colours ``[P, k]`` (reflectance).

    Scales are isotropic, the RMS distance to the 3 nearest neighbours; rotations identity;
    opacity ``init_opacity``. Appearance tensors are added later (:meth:`GaussianModel.set_head`).
    """
    pts = np.asarray(points, np.float32)
    col = np.asarray(colors, np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
        raise ValueError(f"points must be [P, 3] with P > 0, got {pts.shape}")
    if col.ndim == 1:
        col = col[:, None]
    if col.shape[0] != pts.shape[0]:
        raise ValueError(f"colors rows {col.shape[0]} != points rows {pts.shape[0]}")
    col = np.where(np.isfinite(col), col, np.nanmedian(col, axis=0, keepdims=True))
    n = pts.shape[0]
    s = np.log(knn_scale(pts) * scale_mult).astype(np.float32)
    params = {
        "means": torch.from_numpy(pts),
        "log_scales": torch.from_numpy(np.repeat(s[:, None], 3, 1)),
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(n, 1),
        "opacity_logits": torch.full((n,), float(inverse_sigmoid(init_opacity))),
        "colors": torch.from_numpy(col),
    }
    return GaussianModel(params, "brf", latent_dim, col.shape[1])


def scene_extent(points: np.ndarray) -> float:  # points [P, 3] m -> m
    """Half the diagonal of the 2-98 percentile box of the points (metres); the 3DGS 'scene scale'."""
    p = np.asarray(points, np.float64)
    lo = np.percentile(p, 2, axis=0)
    hi = np.percentile(p, 98, axis=0)
    return float(max(0.5 * math.sqrt(((hi - lo) ** 2).sum()), 1e-3))


def surface_fill(
    points: np.ndarray,  # [P, 3] m
    n_target: int,
    cover_xy: np.ndarray | None = None,  # [Q, 2] m
    keep: Callable[[np.ndarray], np.ndarray] | None = None,  # xyz [M, 3] -> bool [M]
) -> np.ndarray:  # [M, 3] m
    """Extra points [M, 3] on a 2.5-D surface through the sparse points (denser start for short schedules).

    The sparse points' heights z(x, y) are interpolated linearly over their Delaunay
    triangulation (nearest sparse point outside it). A regular xy grid of about ``n_target``
    nodes covers the box of ``cover_xy`` [Q, 2] (e.g. the ground footprints of the training
    images, so every pixel sees a Gaussian from the start) or, without it, the convex hull
    of the points (2-98 percentile box). ``keep(xyz [M, 3]) -> bool [M]`` drops nodes (e.g.
    those no training view sees). Suited to UAV scenes seen from above; 3D structure beyond a
    height field is left to densification.
    """
    p = np.asarray(points, np.float64)
    if n_target <= 0 or p.shape[0] < 4:
        return np.zeros((0, 3))
    xy = p[:, :2]
    try:
        tri = Delaunay(xy)
    except Exception:  # degenerate (collinear) points
        return np.zeros((0, 3))
    if cover_xy is not None and len(cover_xy):
        c = np.asarray(cover_xy, np.float64)
        lo, hi = c.min(0), c.max(0)
    else:
        lo = np.percentile(xy, 2, axis=0)
        hi = np.percentile(xy, 98, axis=0)
    area = float(np.prod(np.maximum(hi - lo, 1e-6)))
    z_at = height_field(p)  # nodes outside the hull only exist with cover_xy: they take the nearest height
    n_grid = n_target
    g = None
    for _ in range(4):  # grid spacing so that about n_target nodes survive the filters
        step = math.sqrt(area / n_grid)
        gx = np.arange(lo[0] + step / 2, hi[0], step)
        gy = np.arange(lo[1] + step / 2, hi[1], step)
        g = np.stack(np.meshgrid(gx, gy, indexing="xy"), -1).reshape(-1, 2)
        if cover_xy is None:
            g = g[tri.find_simplex(g) >= 0]
        if g.shape[0] == 0:
            return np.zeros((0, 3))
        z = z_at(g)
        ok = np.isfinite(z)
        g = np.concatenate([g[ok], z[ok, None]], 1)
        if keep is not None:
            g = g[np.asarray(keep(g), bool)]
        if g.shape[0] >= 0.8 * n_target or g.shape[0] == 0:
            break
        n_grid = int(n_grid * n_target / max(g.shape[0], 1)) + 1
    return g
