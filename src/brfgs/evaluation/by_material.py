"""Accuracy by surface material on simulated scenes, and how surface-like the model is there.

A simulated scene's ``truth/materials/<view>.npy`` labels every pixel with the material its
centre ray hits. :func:`view_pixels` gathers, per material, each held-out pixel's CIR squared
error and spectral angle against the clean truth, the model's rendered opacity α, the spread of
the blended depths along the pixel's ray and the signed error of the expected depth;
:func:`summarise` pools them over views (and rings) into:

- ``psnr`` (dB): CIR PSNR of the material's pixels (pooled squared error, data range 1);
- ``sam`` (rad): mean spectral angle of its pixels (null for the CIR variant);
- ``error_share``: its part of all the pooled CIR squared error (sums to 1 over materials);
- ``alpha``: median rendered opacity (1: an opaque surface; below it the learned background
  shows through);
- ``depth_spread_m``: median standard deviation of the blended depths along the ray,
  sqrt(E_w[t²] − E_w[t]²) (0 for one opaque surface; a translucent stack of layers blurs the
  texture of an oblique view by about spread · tan θ_v);
- ``depth_error_m``: median of (rendered expected depth − true depth) along the optical axis;
- ``normal_error_deg``: median angle between the model's normal map (as ``brfgs render`` gives
  it: the Gaussians' smallest axes, blended) and the normal of the true depth map, on pixels
  whose four neighbours are of the same material (a central difference across an edge is no
  surface normal).

When the maps are finer than the rendered images (``--downscale``), a pixel counts only when its
whole block has one material (pure pixels); depths are block means.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from brfgs.evaluation.metrics import spectral_angle
from brfgs.analysis.roi import read_materials_json
from brfgs.errors import UserError
from brfgs.model import TrainedModel, render
from brfgs.model.camera import Camera
from brfgs.render.geometry import normals_from_depth

DEFINITIONS = ("pixels of each simulator material (truth/materials, pure pixels), pooled over the views: psnr (CIR, "
               "pooled squared error), sam (mean, rad), error_share (of all pooled CIR squared error), alpha (median "
               "rendered opacity), depth_spread_m (median sd of the blended depths along the ray, where alpha >= 0.5), "
               "depth_error_m (median rendered expected depth - true depth, where alpha >= 0.5), "
               "normal_error_deg (median angle between the rendered normal map and the true depth's normal, "
               "where alpha >= 0.5 and the 4 neighbours are of the same material)")
KEYS = ("se", "sam", "alpha", "spread", "dz", "dn")   # per-pixel values gathered per material
MIN_ALPHA = 0.5                                 # depth statistics only where the model is mostly opaque


def has_materials(truth_dir: Path | None) -> bool:
    """True when ``truth_dir`` holds material maps and their table."""
    return truth_dir is not None and (Path(truth_dir) / "materials.json").is_file() and (
        Path(truth_dir) / "materials").is_dir()


def material_names(truth_dir: Path) -> dict[int, str]:
    """{material id: name} of a simulated scene (truth/materials.json)."""
    return read_materials_json(Path(truth_dir))


def _load_map(path: Path) -> np.ndarray:
    """A truth map [H', W'] (.npy); UserError naming the file when it cannot be read."""
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise UserError(f"unreadable truth map ({exc})", file=path) from None
    if arr.ndim != 2:
        raise UserError(f"a truth map must be 2-D [H, W], got shape {arr.shape}", file=path)
    return arr


def image_grid_crop(scene, full_shape: tuple[int, ...]) -> tuple[slice, slice]:
    """The rows and columns of a full-resolution truth map [H, W] that the scene's images cover: its ROI,
    cut to whole blocks of its downscale factor."""
    f = scene.downscale
    x0, y0, w, h = scene.roi if scene.roi is not None else (0, 0, full_shape[1], full_shape[0])
    return slice(y0, y0 + h // f * f), slice(x0, x0 + w // f * f)


def truth_maps(scene, i: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray | None] | None:
    """(material ids [H', W'], true depth [H', W'] m or None) of frame ``i`` on the pixel grid of the
    images before downscaling (the scene's ROI cropped: H' = downscale · H for images of ``shape``
    [H, W]), or None when the scene has no map for it (or no truth/materials.json), the frame has a
    camera of its own (its maps are in the raw, distorted pixels) or the map is not on the images' grid."""
    td = scene.truth_dir
    if not has_materials(td) or scene.frames[i].camera is not None:
        return None
    mp = td / "materials" / f"{scene.frames[i].name}.npy"
    if not mp.is_file():
        return None
    mat = _load_map(mp)
    dp = td / "depth" / f"{scene.frames[i].name}.npy"
    dep = _load_map(dp) if dp.is_file() else None
    f = scene.downscale
    crop = image_grid_crop(scene, mat.shape)
    mat, dep = mat[crop], None if dep is None else dep[crop]
    if mat.shape != (shape[0] * f, shape[1] * f):
        return None
    return mat, None if dep is None or dep.shape != mat.shape else dep


def ray_depth_moments(model: TrainedModel, cam: Camera,
                      backend: str = "auto") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(alpha [H, W], expected depth [H, W] m, depth spread [H, W] m, normal map [H, W, 3]: unit,
    world, 0 where nothing) of ``cam``'s rays: the
    camera depths t of the Gaussians rasterized with their squares, E_w[t] and
    sqrt(E_w[t²] − E_w[t]²) over the blending weights w (NaN where α = 0). The depths are taken
    relative to the median depth of the Gaussians in front of the camera, so that the float32
    moments do not cancel (t² of 100 m depths would leave ~3 cm of resolution)."""
    means = model.frozen()["means"]
    vm = cam.viewmat.to(means.dtype)
    t_all = means @ vm[2, :3] + vm[2, 3]  # [N] m
    front = t_all[t_all > 0]
    ref = float(front.median()) if front.numel() else 0.0

    def features(idx: torch.Tensor, omega_o: torch.Tensor) -> torch.Tensor:  # [n, 2]: t − ref, (t − ref)²
        d = t_all[idx] - ref
        return torch.stack([d, d * d], -1)

    rv = render(model, cam, features=features, decode=False, normals=True, backend=backend)
    m = rv.image.numpy().astype(np.float64)  # [H, W, 2] premultiplied
    a = rv.alpha.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        d1 = np.where(a > 0, m[..., 0] / a, np.nan)
        d2 = np.where(a > 0, m[..., 1] / a, np.nan)
    return rv.alpha, d1 + ref, np.sqrt(np.clip(d2 - d1 * d1, 0.0, None)), rv.normal


def normal_error_deg(normal_world: np.ndarray, viewmat: np.ndarray, K: np.ndarray, true_depth_m: np.ndarray,
                     ids: np.ndarray) -> np.ndarray:  # [H, W] deg
    """Angle (deg) between a normal map [H, W, 3] (unit, world axes, facing the camera, 0 where
    nothing) and the normal of the true depth [H, W] (m along the optical axis, same grid, camera
    ``viewmat`` [4, 4] world -> camera, intrinsics ``K`` [3, 3]); NaN where either is undefined or a
    4-neighbour's material id (``ids`` [H, W]) differs from the pixel's."""
    nt, ok = normals_from_depth(torch.as_tensor(true_depth_m, dtype=torch.float64),
                                torch.as_tensor(K, dtype=torch.float64))
    n_cam = np.asarray(normal_world, np.float64) @ np.asarray(viewmat, np.float64)[:3, :3].T  # [H, W, 3]
    same = np.zeros(ids.shape, bool)
    c = ids[1:-1, 1:-1]
    same[1:-1, 1:-1] = (ids[:-2, 1:-1] == c) & (ids[2:, 1:-1] == c) & (ids[1:-1, :-2] == c) & (ids[1:-1, 2:] == c)
    cos = np.clip((n_cam * nt.numpy()).sum(-1), -1.0, 1.0)
    keep = ok.numpy() & same & (np.linalg.norm(n_cam, axis=-1) > 0.5)
    return np.where(keep, np.degrees(np.arccos(cos)), np.nan)


def _block(arr: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(block mean [h, w], block is uniform [h, w]) of a map [H, W] reduced to ``shape`` [h, w]."""
    H, W = arr.shape
    h, w = shape
    if (H, W) == (h, w):
        return arr, np.ones(shape, bool)
    if H % h or W % w or H // h != W // w:
        raise ValueError(f"map of shape {arr.shape} is not an integer multiple of {shape}")
    f = H // h
    b = arr.reshape(h, f, w, f).astype(np.float64)
    return b.mean((1, 3)), b.min((1, 3)) == b.max((1, 3))


def view_pixels(
    material: np.ndarray,  # [H', W'] int material ids (H' = f·H)
    render_cir: np.ndarray,  # [H, W, 3]
    truth_cir: np.ndarray,  # [H, W, 3]
    valid: np.ndarray,  # [H, W] bool
    alpha: np.ndarray,  # [H, W]
    depth_m: np.ndarray,  # [H, W] expected depth (NaN where nothing)
    spread_m: np.ndarray,  # [H, W]
    true_depth_m: np.ndarray | None = None,  # [H', W'] m along the optical axis
    render_cube: np.ndarray | None = None,  # [H, W, B]
    truth_cube: np.ndarray | None = None,  # [H, W, B]
    normal_view: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,  # normal map [H, W, 3], viewmat, K
) -> dict[int, dict[str, np.ndarray]]:
    """{material id: {key: per-pixel values [n]}} of one view (keys :data:`KEYS`; "sam" absent
    without cubes; "spread", "dz" and "dn" NaN where α < :data:`MIN_ALPHA`, "dz" and "dn" NaN
    without true depth, "dn" also without ``normal_view``: :func:`normal_error_deg`)."""
    shape = valid.shape
    mat_mean, pure = _block(material, shape)
    ids = np.rint(mat_mean).astype(np.int64)
    ok = valid & pure & np.isfinite(render_cir).all(-1) & np.isfinite(truth_cir).all(-1)
    se = ((np.asarray(render_cir, np.float64) - truth_cir) ** 2).mean(-1)  # [H, W]
    sam = None if render_cube is None or truth_cube is None else spectral_angle(render_cube, truth_cube)
    solid = alpha >= MIN_ALPHA
    spread = np.where(solid, spread_m, np.nan)
    dz, dn = np.full(shape, np.nan), np.full(shape, np.nan)
    if true_depth_m is not None:
        td, _ = _block(np.asarray(true_depth_m, np.float64), shape)
        dz = np.where(solid & (td > 0), depth_m - td, np.nan)
        if normal_view is not None:
            dn = np.where(solid, normal_error_deg(*normal_view, td, ids), np.nan)  # impure pixels are not in ok
    out = {}
    for k in np.unique(ids[ok]):
        sel = ok & (ids == k)
        vals = {"se": se[sel], "alpha": np.asarray(alpha, np.float64)[sel], "spread": spread[sel], "dz": dz[sel],
                "dn": dn[sel]}
        if sam is not None:
            vals["sam"] = sam[sel]
        out[int(k)] = vals
    return out


def _stats(vals: dict[str, np.ndarray], total_se: float) -> dict:
    """The summary of one material's pooled pixels (module docstring)."""
    mse = float(vals["se"].mean())

    def med(key):
        v = vals.get(key)
        v = v[np.isfinite(v)] if v is not None else v
        return None if v is None or v.size == 0 else float(np.median(v))

    return {"n_pixels": int(vals["se"].size),
            "psnr": float("inf") if mse == 0 else float(-10 * np.log10(mse)),
            "sam": None if "sam" not in vals else float(np.mean(vals["sam"])),
            "error_share": float(vals["se"].sum() / total_se) if total_se > 0 else None,
            "alpha": med("alpha"), "depth_spread_m": med("spread"), "depth_error_m": med("dz"),
            "normal_error_deg": med("dn")}


def summarise(views: list[dict[int, dict[str, np.ndarray]]], names: dict[int, str]) -> dict:
    """{material name: statistics} pooled over ``views`` (outputs of :func:`view_pixels`), the
    largest share of the error first."""
    pooled: dict[int, dict[str, list]] = {}
    for v in views:
        for k, vals in v.items():
            p = pooled.setdefault(k, {})
            for key, arr in vals.items():
                p.setdefault(key, []).append(arr)
    cat = {k: {key: np.concatenate(parts) for key, parts in p.items()} for k, p in pooled.items()}
    total = float(sum(c["se"].sum() for c in cat.values()))
    out = {names.get(k, str(k)): _stats(c, total) for k, c in cat.items()}
    return dict(sorted(out.items(), key=lambda kv: -(kv[1]["error_share"] or 0.0)))
