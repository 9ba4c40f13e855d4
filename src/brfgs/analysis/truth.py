"""The simulator's truth BRF of an ROI (simulated scenes) and the model's error against it.

On a simulated scene (``truth/scene.json``) the simulator renders the clean scene again for any
view direction (:func:`brfgs.sim.render_scene_views`); :func:`truth_brf` averages the pixels whose
*true* surface point lies in the ROI, as :func:`brfgs.analysis.brf.roi_brf` does for the model,
and :func:`brf_error` gives the per-band RMSE, mean bias and relative error of the model.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from brfgs.analysis.brf import ROIBRF
from brfgs.analysis.roi import ROI, points_in_roi, unproject_depth
from brfgs.data.cameras import Intrinsics
from brfgs.errors import UserError
from brfgs.sim.acquisition import render_scene_views

__all__ = ["has_simulator_truth", "simulator_sampler", "check_truth_spp", "truth_brf", "brf_error"]


def has_simulator_truth(scene_root: str | Path | None) -> bool:
    """True when ``scene_root`` is a simulated scene that the simulator can render again."""
    return scene_root is not None and (Path(scene_root) / "truth" / "scene.json").is_file()


def simulator_sampler(scene_root: str | Path) -> tuple[str, int]:
    """(Mitsuba sampler, spp) of a simulated scene (truth/scene.json); scenes written before
    the sampler option used "independent"."""
    path = Path(scene_root) / "truth" / "scene.json"
    try:
        cfg = json.loads(path.read_text()).get("config", {})
    except (OSError, ValueError, AttributeError):
        raise UserError("unreadable simulator configuration", file=path, field="config") from None
    return str(cfg.get("sampler", "independent")), int(cfg.get("spp", 0) or 0)


def check_truth_spp(scene_root: str | Path, spp: int | None, field: str = "--truth-spp") -> int | None:
    """``spp`` validated for the scene's sampler: a power of 4 (1, 4, 16, 64, 256, ...) for
    Mitsuba's low-discrepancy "ldsampler" (it would round other counts up silently), a power
    of two for "independent". None keeps the scene's own spp."""
    if spp is None:
        return None
    spp = int(spp)
    sampler, _ = simulator_sampler(scene_root)
    if spp < 1 or spp & (spp - 1):
        raise UserError(f"samples per pixel must be a power of two, got {spp}", field=field)
    if sampler == "ldsampler" and (spp.bit_length() - 1) % 2:
        raise UserError(f"this scene was simulated with the 'ldsampler' sampler, whose samples per pixel must be a "
                        f"power of 4 (1, 4, 16, 64, 256, ...), got {spp}", field=field)
    return spp


def truth_brf(
    scene_root: str | Path,
    roi: ROI,
    view_zenith_deg: ArrayLike,  # [D] deg
    view_azimuth_deg: ArrayLike,  # [D] deg
    band_idx: Sequence[int],  # [nb] band indices
    *,
    distance_m: float,
    size: int = 128,
    spp: int | None = None,
    progress: bool = False,
    chunk: int = 64,
) -> ROIBRF:
    """Truth BRF of ``roi``: the simulator renders the clean scene again from each direction
    (brfgs.sim.acquisition.render_scene_views: cameras at ``distance_m`` looking at the ROI
    centre, the acquisition's field of view, ``size`` pixels, ``spp`` samples per pixel —
    default the scene's; see :func:`check_truth_spp`) and the ROI is the set of pixels
    whose *true* surface point (ray-cast depth) lies in it. Directions are rendered ``chunk``
    at a time (the simulator builds the scene once per call)."""
    zen = np.atleast_1d(np.asarray(view_zenith_deg, float))
    az = np.atleast_1d(np.asarray(view_azimuth_deg, float))
    bi = [int(b) for b in np.atleast_1d(band_idx)]
    spp = check_truth_spp(scene_root, spp, field="spp")
    target = np.asarray(roi.centre_m, float)
    vals = np.full((zen.size, len(bi)), np.nan, np.float32)
    counts = np.zeros(zen.size, np.int64)
    wl = None
    chunk = max(1, int(chunk))
    for k0 in range(0, zen.size, chunk):
        dirs = [(zen[k], az[k]) for k in range(k0, min(zen.size, k0 + chunk))]
        r = render_scene_views(scene_root, dirs, size=size, spp=spp, bands=bi, distance_m=distance_m,
                               target_m=target, progress=progress)
        wl = r["wavelengths_nm"]
        intr = r["intrinsics"]
        if not isinstance(intr, Intrinsics):
            intr = Intrinsics(**intr)
        for j in range(len(dirs)):
            k = k0 + j
            depth = r["depth"][j].astype(float)
            sel = points_in_roi(roi, unproject_depth(np.where(depth > 0, depth, np.nan), r["c2w"][j], intr))
            refl = r["reflectance"][j]
            sel &= np.isfinite(refl).all(-1)
            counts[k] = int(sel.sum())
            if counts[k]:
                vals[k] = refl[sel].mean(0)
    return ROIBRF(zen, az, np.asarray(wl if wl is not None else []), vals, counts,
                  {"distance_m": distance_m, "size_px": size, "spp": spp, "target_m": target.tolist(),
                   "source": "simulator"})


def brf_error(
    model: np.ndarray,  # [D, nb]
    truth: np.ndarray,  # [D, nb]
    wavelengths_nm: Sequence[float],  # [nb]
) -> dict:
    """Per-band error of model BRF [D, nb] against truth [D, nb] over the directions where both
    are finite: RMSE, mean bias (model − truth) and mean relative error |model − truth| / truth."""
    m = np.asarray(model, float)
    t = np.asarray(truth, float)
    ok = np.isfinite(m).all(1) & np.isfinite(t).all(1)
    keys = [f"{w:.0f}" for w in wavelengths_nm]
    if not ok.any():
        return {"n_directions": 0, "rmse": {k: None for k in keys}, "mean_bias": {k: None for k in keys},
                "mean_relative_error": {k: None for k in keys}, "reason": "no direction where both are seen"}
    e = m[ok] - t[ok]
    return {"n_directions": int(ok.sum()),
            "rmse": {k: float(np.sqrt(np.mean(e[:, j] ** 2))) for j, k in enumerate(keys)},
            "mean_bias": {k: float(np.mean(e[:, j])) for j, k in enumerate(keys)},
            "mean_relative_error": {k: float(np.mean(np.abs(e[:, j]) / np.maximum(np.abs(t[ok, j]), 1e-6)))
                                    for j, k in enumerate(keys)}}
