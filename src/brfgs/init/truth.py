"""Checks of an initialisation against a simulated scene's ``truth/`` (never used to build it).

- camera-centre error: ‖c_est − c_true‖ per view, relative to the camera distance ‖c_true − o‖
  (o = ENU origin, the scene centre), where c_true is the pose in transforms.json
  (or ``truth/cameras.json`` when the simulator writes separate true poses);
- point-to-surface distance: every truth depth map (``truth/depth/<name>.npy``, metres along
  the optical axis) is unprojected to surface samples; the distance of a sparse point to the
  surface is its distance to the plane fitted (PCA) to its 8 nearest surface samples,
  reported relative to the median camera distance as well.
"""

from __future__ import annotations

import json

import numpy as np
from scipy.spatial import cKDTree

from brfgs.data.cameras import pixel_rays

MAX_SURFACE_SAMPLES = 2_000_000


def _truth_c2w(scene) -> list[np.ndarray]:
    p = scene.truth_dir / "cameras.json" if scene.truth_dir is not None else None
    if p is not None and p.is_file():
        try:
            data = json.loads(p.read_text())
            by_name = {f["name"]: np.asarray(f["c2w"], float) for f in data.get("frames", [])}
            if all(f.name in by_name for f in scene.frames):
                return [by_name[f.name] for f in scene.frames]
        except (ValueError, KeyError, TypeError):
            pass
    return [np.asarray(f.c2w, float) for f in scene.frames]


def surface_samples(scene, views: list[int] | None = None) -> np.ndarray | None:
    """World points [S, 3] unprojected from the truth depth maps (None when there are none)."""
    if scene.truth_dir is None or not (scene.truth_dir / "depth").is_dir():
        return None
    views = list(range(len(scene.frames))) if views is None else views
    full = scene.full_intrinsics or scene.intrinsics
    truth_c2w = _truth_c2w(scene)
    chunks = []
    paths = [(i, scene.truth_dir / "depth" / f"{scene.frames[i].name}.npy") for i in views]
    paths = [(i, p) for i, p in paths if p.is_file()]
    if not paths:
        return None
    for i, p in paths:
        depth = np.load(p).astype(np.float64)
        if depth.shape == (full.h, full.w):
            intr = full
        elif depth.shape == (scene.height, scene.width):
            intr = scene.intrinsics
        else:
            continue
        n_total = depth.size * len(paths)
        stride = max(1, int(np.ceil(np.sqrt(n_total / MAX_SURFACE_SAMPLES))))
        o, d = pixel_rays(truth_c2w[i], intr)
        fwd = -truth_c2w[i][:3, 2]
        o, d, depth = o[::stride, ::stride], d[::stride, ::stride], depth[::stride, ::stride]
        ok = np.isfinite(depth) & (depth > 0)
        t = depth[ok] / (d[ok] @ fwd)
        chunks.append(o[ok] + t[:, None] * d[ok])
    return np.concatenate(chunks) if chunks else None


def point_to_surface_m(points: np.ndarray, samples: np.ndarray, k: int = 8) -> np.ndarray:
    """Distance [P] of each point to the plane through its ``k`` nearest surface samples."""
    points = np.asarray(points, float)
    if len(points) == 0:
        return np.zeros(0)
    _, nn = cKDTree(samples).query(points, k=k)
    nb = samples[nn]  # [P, k, 3]
    mu = nb.mean(1)
    cov = np.einsum("pki,pkj->pij", nb - mu[:, None], nb - mu[:, None])
    _, vecs = np.linalg.eigh(cov)
    normal = vecs[:, :, 0]  # smallest eigenvalue
    return np.abs(np.einsum("pi,pi->p", points - mu, normal))


def truth_checks(scene, c2w_est: list, points: np.ndarray) -> dict | None:
    """The "truth" section of init_report.json, or None when the scene has no truth/."""
    if scene.truth_dir is None:
        return None
    truth = _truth_c2w(scene)
    centre_true = np.array([c[:3, 3] for c in truth])
    dist = np.linalg.norm(centre_true, axis=1)  # camera distance to the scene centre (ENU origin)
    errs, rel, per_view = [], [], {}
    for i, c in enumerate(c2w_est):
        if c is None:
            continue
        e = float(np.linalg.norm(np.asarray(c)[:3, 3] - centre_true[i]))
        errs.append(e)
        rel.append(e / dist[i])
        per_view[scene.frames[i].name] = e / dist[i]
    out = {
        "camera_distance_m_median": float(np.median(dist)),
        "camera_centre_error_m": {"median": float(np.median(errs)) if errs else None,
                                  "max": float(np.max(errs)) if errs else None},
        "camera_centre_error_rel": {"median": float(np.median(rel)) if rel else None,
                                    "max": float(np.max(rel)) if rel else None},
        "camera_centre_error_rel_per_view": per_view,
        "views_above_1pct": [n for n, v in per_view.items() if v > 0.01],
        "definitions": {
            "camera_centre_error_rel": "|c_est - c_true| / |c_true - scene centre| per registered view",
            "point_to_surface": "distance of each sparse point to the plane through its 8 nearest samples of "
                                "the surface unprojected from truth/depth; rel = / median camera distance",
        },
    }
    samples = surface_samples(scene)
    if samples is None or len(points) == 0:
        out["point_to_surface_m"] = None
        out["point_to_surface_m_reason"] = "no truth/depth maps" if samples is None else "no sparse points"
        return out
    d = point_to_surface_m(points, samples)
    med_dist = float(np.median(dist))
    out["point_to_surface_m"] = {"median": float(np.median(d)), "p90": float(np.percentile(d, 90)),
                                 "mean": float(d.mean())}
    out["point_to_surface_rel"] = {"median": float(np.median(d)) / med_dist,
                                   "p90": float(np.percentile(d, 90)) / med_dist}
    out["surface_samples"] = int(len(samples))
    return out
