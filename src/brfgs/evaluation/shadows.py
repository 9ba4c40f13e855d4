"""Cast shadows against the truth of simulated scenes.

The model's direct-sun visibility of each evaluated view (:mod:`brfgs.model.shadows`: the Gaussians
seen from the sun, under the sun the view is rendered with) against ``truth/sun_visibility/<name>.npy``
(the simulator's ray test toward the sun: 1 lit, 0 shadowed, 255 nothing hit). A pixel is in shadow
when its visibility is below 0.5 (the truth block-averaged first when the scene is read downscaled);
pixels the model does not cover (opacity < 0.1) or where the truth hits nothing are left out.
Scores pool the pixels of all views: the shadow class's intersection over union, the accuracy, and
the shadow share of each.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from brfgs.evaluation.by_material import image_grid_crop, truth_maps
from brfgs.model import TrainedModel
from brfgs.model.camera import Camera
from brfgs.model.view import sun_visibility_map

__all__ = ["DEFINITION", "truth_visibility", "canopy_pixels", "ShadowScores"]

DEFINITION = ("direct-sun visibility of the model's geometry (a sun camera, brfgs.model.shadows) vs "
              "truth/sun_visibility; shadow = visibility < 0.5; pixels with model opacity >= 0.1 where the truth "
              "hits a surface; iou of the shadow class and accuracy pooled over the views' pixels; cast: without "
              "pixels showing leaves (a crown's sub-pixel self-shading)")


def truth_visibility(scene, i: int, shape: tuple[int, int]) -> np.ndarray | None:  # [H, W] in [0, 1] or NaN
    """Frame ``i``'s true direct-sun visibility on the images' grid ``shape`` (the ROI cropped, blocks of
    the scene's downscale averaged; NaN where nothing is hit), or None when the scene has none for it
    (no truth, a frame with a camera of its own, or another grid)."""
    td = scene.truth_dir
    if td is None or scene.frames[i].camera is not None:
        return None
    p = Path(td) / "sun_visibility" / f"{scene.frames[i].name}.npy"
    if not p.is_file():
        return None
    try:
        raw = np.load(p, allow_pickle=False)
    except (OSError, ValueError):
        return None
    if raw.ndim != 2:
        return None
    f = scene.downscale
    raw = raw[image_grid_crop(scene, raw.shape)]
    if raw.shape != (shape[0] * f, shape[1] * f):
        return None
    v = np.where(raw == 255, np.nan, np.clip(raw.astype(np.float64), 0, 1))
    return v.reshape(shape[0], f, shape[1], f).mean(axis=(1, 3))


def canopy_pixels(scene, i: int, shape: tuple[int, int]) -> np.ndarray | None:  # [H, W] bool
    """Pixels of frame ``i`` that show a leaf material (``"bsdf": "leaf"`` in truth/materials.json) in any
    of their sub-pixels before downscaling, or None without material maps. Inside a crown the truth's
    visibility is a sub-pixel speckle of leaves shading leaves, which no splat model resolves at the
    images' resolution: scores without these pixels are those of the cast shadows."""
    maps = truth_maps(scene, i, shape)
    if maps is None:
        return None
    try:
        table = json.loads((Path(scene.truth_dir) / "materials.json").read_text(encoding="utf-8"))["materials"]
        leaf = [int(k) for k, v in table.items() if isinstance(v, dict) and v.get("bsdf") == "leaf"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    f = scene.downscale
    return np.isin(maps[0], leaf).reshape(shape[0], f, shape[1], f).any(axis=(1, 3))


class ShadowScores:
    """Pooled pixel counts of the model's shadows against the truth, over views rendered under any suns
    (each sun's Gaussian visibilities computed once: :meth:`TrainedModel.sun_visibility`)."""

    def __init__(self, model: TrainedModel, backend: str = "auto"):
        self.model, self.backend = model, backend
        self.counts = np.zeros(4, np.int64)                  # both shadow, model only, truth only, both lit
        self.counts_cast = np.zeros(4, np.int64)             # the same without canopy pixels

    def add(self, cam: Camera, sun_zenith_deg: float, sun_azimuth_deg: float, truth: np.ndarray,
            canopy: np.ndarray | None = None) -> None:
        """Score one view (``truth`` [H, W] from :func:`truth_visibility`, ``canopy`` [H, W] from
        :func:`canopy_pixels`)."""
        vis = self.model.sun_visibility(sun_zenith_deg, sun_azimuth_deg, backend=self.backend)  # [N]
        pred = sun_visibility_map(self.model, cam, vis, backend=self.backend)  # [H, W]
        ok = np.isfinite(pred) & np.isfinite(truth)
        self.counts += _counts(pred[ok] < 0.5, truth[ok] < 0.5)
        if canopy is not None:
            ok &= ~canopy
            self.counts_cast += _counts(pred[ok] < 0.5, truth[ok] < 0.5)

    def summary(self) -> dict | None:
        """{"iou", "accuracy", "shadow_share_truth", "shadow_share_model", "n_pixels", "cast": the same
        without canopy pixels (or None), "definition"}, or None without pixels."""
        out = _scores(self.counts)
        if out is not None:
            out["cast"] = _scores(self.counts_cast)
            out["definition"] = DEFINITION
        return out


def _counts(ps: np.ndarray, ts: np.ndarray) -> np.ndarray:  # [4]
    return np.array([(ps & ts).sum(), (ps & ~ts).sum(), (~ps & ts).sum(), (~ps & ~ts).sum()], np.int64)


def _scores(counts: np.ndarray) -> dict | None:
    both, model_only, truth_only, lit = (int(c) for c in counts)
    n = both + model_only + truth_only + lit
    if n == 0:
        return None
    union = both + model_only + truth_only
    return {"iou": None if union == 0 else round(both / union, 4), "accuracy": round((both + lit) / n, 4),
            "shadow_share_truth": round((both + truth_only) / n, 4),
            "shadow_share_model": round((both + model_only) / n, 4), "n_pixels": n}
