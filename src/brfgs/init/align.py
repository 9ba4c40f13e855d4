"""Similarity alignment of an SfM reconstruction to the scene's ENU frame (Umeyama 1991).

No pycolmap here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from brfgs.errors import UserError


@dataclass
class Similarity:
    """x' = scale · R x + t."""

    scale: float
    R: np.ndarray   # [3, 3]
    t: np.ndarray   # [3]

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Transform points [..., 3]."""
        return self.scale * np.asarray(x, float) @ self.R.T + self.t

    def apply_c2w(self, c2w: np.ndarray) -> np.ndarray:
        """Transform a camera-to-world [4, 4] (rotation part rotated, centre mapped)."""
        out = np.eye(4)
        out[:3, :3] = self.R @ np.asarray(c2w, float)[:3, :3]
        out[:3, 3] = self.apply(np.asarray(c2w, float)[:3, 3])
        return out

    def to_json(self) -> dict:
        return {"scale": float(self.scale), "R": self.R.tolist(), "t": self.t.tolist()}


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Similarity:
    """Least-squares similarity mapping ``src`` [N, 3] onto ``dst`` [N, 3] (Umeyama 1991, eqs 34–42)."""
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError("umeyama needs two [N, 3] arrays with N >= 3")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs ** 2).sum() / len(src)
    cov = xd.T @ xs / len(src)  # [3, 3]
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    scale = float(np.trace(np.diag(D) @ S) / var_s) if with_scale else 1.0
    if not np.isfinite(scale) or scale <= 0:
        raise UserError("cannot align the reconstruction: the camera centres used are degenerate "
                        "(coincident or collinear)", field="poses")
    t = mu_d - scale * R @ mu_s
    return Similarity(scale, R, t)


def umeyama_robust(src: np.ndarray, dst: np.ndarray, rel_tol: float = 0.05, iters: int = 5) -> tuple[Similarity, np.ndarray]:
    """Umeyama refitted on inliers: a pair whose residual exceeds ``rel_tol`` × (spread of ``dst``)
    and 3× the median residual is dropped (a mis-registered view must not skew the alignment).
    Returns (similarity, inlier mask [N])."""
    dst = np.asarray(dst, float)
    src = np.asarray(src, float)
    keep = np.ones(len(src), bool)
    spread = float(np.sqrt(((dst - dst.mean(0)) ** 2).sum(1).mean()))
    sim = umeyama(src, dst)
    for _ in range(iters):
        res = np.linalg.norm(sim.apply(src) - dst, axis=1)
        new = (res <= max(rel_tol * spread, 3.0 * np.median(res[keep]))) | (res <= 1e-12)
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
        sim = umeyama(src[keep], dst[keep])
    return sim, keep
