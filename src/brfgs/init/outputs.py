"""Files of ``brfgs init``: sparse points (PLY), cameras, the report (JSON and Markdown), bands."""

from __future__ import annotations

import zlib  # noqa: F401  (before anything that may pull pycolmap; file writing needs a sane zlib)
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from brfgs.data import atomic

__all__ = ["DEFINITIONS", "write_points_ply", "write_outputs", "write_tracks", "read_tracks", "report_markdown",
           "strategies_table", "fmt_or_na"]

# The report's definitions of its numbers (init_report.json "definitions", init_report.md).
DEFINITIONS = {
    "mean_detected_features_per_view": "SIFT keypoints per view on the 8-bit stretched selected bands, pooled "
                                       "over bands with duplicates (< 1.5 px from a stronger keypoint with a "
                                       "descriptor less than 0.5 rad away) removed, before the max_features cap",
    "putative_matches": "COLMAP exhaustive SIFT matches over all view pairs (ratio test 0.8, max distance 0.7, "
                        "cross check)",
    "verified_matches": "inlier matches of the two-view geometries accepted by COLMAP's RANSAC verification "
                        "(essential/fundamental/homography, 4 px, >= min_inliers)",
    "matching_success_rate": "verified_matches / putative_matches",
    "mean_track_length": "mean number of views observing a sparse point",
    "mean_reprojection_error_px": "mean over observations of the pixel distance to the projected point "
                                  "with the final cameras",
    "rectify": "SfM with settings.rectify: features of views tilted more than 10 deg from nadir are detected on a "
               "copy rotated virtually to nadir (pure-rotation homography from the transforms.json orientation) "
               "and mapped back to the image; the geometry columns of this report then count those features. "
               "The Table 2 strategy rows always use plain SIFT on the images, as in the paper",
}


def write_points_ply(path: Path, points, colors, wavelengths_nm, band_indices, track_length=None,
                     error_px=None) -> None:
    """Binary PLY: x, y, z (float32, m, ENU), red/green/blue (uint8 stretch of up to 3 bands for viewing),
    refl_<band index> (float32 reflectance per selected band), track_length, error_px."""
    pts = np.asarray(points, np.float32).reshape(-1, 3)
    cols = np.asarray(colors, np.float32).reshape(len(pts), -1)
    dtype = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    dtype += [(f"refl_{int(b)}", "f4") for b in band_indices]
    dtype += [("track_length", "i4"), ("error_px", "f4")]
    v = np.zeros(len(pts), dtype=dtype)
    v["x"], v["y"], v["z"] = pts.T
    rgb = cols[:, :3] if cols.shape[1] >= 3 else np.repeat(cols[:, :1], 3, axis=1)
    if len(pts):
        hi = np.nanpercentile(rgb, 99, axis=0) if np.isfinite(rgb).any() else np.ones(3)
        hi = np.where(np.isfinite(hi) & (hi > 0), hi, 1.0)
        u8 = np.clip(np.nan_to_num(rgb / hi) * 255, 0, 255).astype(np.uint8)
        v["red"], v["green"], v["blue"] = u8.T
    for j, b in enumerate(band_indices):
        v[f"refl_{int(b)}"] = cols[:, j]
    if track_length is not None:
        v["track_length"] = track_length
    if error_px is not None:
        v["error_px"] = error_px
    comments = ["brfgs sparse points (ENU metres)",
                "bands " + " ".join(f"{int(b)}:{float(w):.2f}nm" for b, w in zip(band_indices, wavelengths_nm))]
    with atomic.atomic_path(path) as tmp:
        PlyData([PlyElement.describe(v, "vertex")], comments=comments).write(str(tmp))


def write_outputs(out: Path, scene, res, selection=None) -> None:
    """OUT/points.ply, tracks.npz (each observation's frame and point index, when known), cameras.json,
    sparse/0 (the cameras and points as a COLMAP model), init_report.{json,md} and (with
    ``selection``) bands.json of an :class:`brfgs.init.api.InitResult`."""
    out.mkdir(parents=True, exist_ok=True)
    wl = [float(scene.wavelengths_nm[i]) for i in res.band_indices]
    write_points_ply(out / "points.ply", res.points, res.colors, wl, res.band_indices, res.track_length,
                     res.error_px)
    if res.obs_frame is not None:
        write_tracks(out / "tracks.npz", res.obs_frame, res.obs_point, [f.name for f in scene.frames])
    intr = scene.intrinsics
    cams = {"convention": "nerfstudio transform_matrix: OpenGL camera-to-world, ENU metres",
            "poses": res.report.get("poses"),
            "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h,
            "frames": [{"name": f.name, "transform_matrix": res.c2w[i].tolist(), "registered": bool(res.registered[i])}
                       for i, f in enumerate(scene.frames)]}
    atomic.write_json(out / "cameras.json", cams)
    # lazy: pycolmap stays out of `import brfgs.init` (it must follow zlib; see brfgs.init)
    from brfgs.init.colmap_io import write_colmap_model

    write_colmap_model(out / "sparse" / "0", intr, [f.name for f in scene.frames], res.c2w, res.registered, res.points)
    atomic.write_json(out / "init_report.json", res.report)
    atomic.write_text(out / "init_report.md", report_markdown(res.report))
    if selection is not None:
        atomic.write_json(out / "bands.json", selection.to_json())


def write_tracks(path: Path, obs_frame, obs_point, frame_names: list[str]) -> None:
    """NPZ of the sparse points' tracks: ``obs_frame`` [O] (index into ``frame_names``), ``obs_point``
    [O] (row of points.ply) and ``frame_names`` [F]."""
    with atomic.atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, obs_frame=np.asarray(obs_frame, np.int32), obs_point=np.asarray(obs_point, np.int32),
                                frame_names=np.asarray(frame_names, dtype=str))


def read_tracks(path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(obs_frame [O], obs_point [O], frame_names) of :func:`write_tracks`."""
    with np.load(path, allow_pickle=False) as z:
        return z["obs_frame"].astype(np.int64), z["obs_point"].astype(np.int64), [str(n) for n in z["frame_names"]]


def fmt_or_na(x, spec=".3g") -> str:
    """``format(x, spec)``, or "n/a" for None."""
    return "n/a" if x is None else format(x, spec)


def _bands_text(b: dict) -> str:
    pairs = list(zip(b["indices"], b["wavelengths_nm"]))
    if len(pairs) <= 12:
        return ", ".join(f"{i} ({w:.1f} nm)" for i, w in pairs)
    return f"{len(pairs)} bands, {pairs[0][1]:.0f}-{pairs[-1][1]:.0f} nm"


def report_markdown(r: dict) -> str:
    g = r["geometry"]
    lines = [f"# Initialisation report: {r['scene']}", "",
             f"- poses: **{r['poses']}** (requested {r['poses_requested']})"
             + (f"; SfM failed, fell back to transforms.json poses: {r['fallback']}" if r.get("fallback") else ""),
             f"- bands ({r['bands']['strategy'] or 'given'}): {_bands_text(r['bands'])}",
             f"- registered views: {r['registered_views']} / {r['views']}"
             + (f" (not registered: {', '.join(r['unregistered_views'])})" if r["unregistered_views"] else ""),
             f"- sparse points: {r['points']}, mean track length {fmt_or_na(r['mean_track_length'])}, "
             f"mean reprojection error {fmt_or_na(r['mean_reprojection_error_px'])} px",
             f"- detected features per view: {fmt_or_na(g['mean_detected_features_per_view'], '.1f')}; "
             f"matching success rate {fmt_or_na(g['matching_success_rate'], '.1%')} "
             f"({g['verified_matches']} verified / {g['putative_matches']} putative matches)"]
    if r.get("alignment"):
        a = r["alignment"]
        lines.append(f"- alignment to ENU: scale {a['scale']:.4g}, centre residual median "
                     f"{a['residual_m']['median']:.3g} m, max {a['residual_m']['max']:.3g} m")
    t = r.get("truth")
    if t:
        lines += ["", "## Against truth", "",
                  f"- camera-centre error: median {fmt_or_na(t['camera_centre_error_rel']['median'], '.3%')}, "
                  f"max {fmt_or_na(t['camera_centre_error_rel']['max'], '.3%')} of the camera distance "
                  f"({t['camera_distance_m_median']:.3g} m)"
                  + (f"; views above 1%: {', '.join(t['views_above_1pct'])}" if t.get("views_above_1pct") else
                     "; no view above 1%")]
        if t.get("point_to_surface_m"):
            lines.append(f"- point-to-surface distance: median {t['point_to_surface_m']['median']:.4g} m "
                         f"= {t['point_to_surface_rel']['median']:.3%} of the camera distance "
                         f"(p90 {t['point_to_surface_rel']['p90']:.3%})")
        else:
            lines.append(f"- point-to-surface distance: n/a ({t.get('point_to_surface_m_reason')})")
    if r.get("strategies"):
        lines += ["", "## Band-selection strategies (paper Table 2, geometry columns)", "", strategies_table(r["strategies"])]
    lines += ["", "## Definitions", ""] + [f"- {k}: {v}" for k, v in r["definitions"].items()]
    return "\n".join(lines) + "\n"


def strategies_table(rows: list[dict]) -> str:
    """Markdown table of the Table 2 geometry columns."""
    out = ["| Strategy | Bands (nm) | Detected features / view | Matching success rate | Verified matches |",
           "|---|---|---|---|---|"]
    for row in rows:
        wl = row["wavelengths_nm"]
        wl_s = ", ".join(f"{w:.0f}" for w in wl) if len(wl) <= 4 else f"{len(wl)} bands ({wl[0]:.0f}-{wl[-1]:.0f})"
        out.append(f"| {row['label']} | {wl_s} | {row['mean_detected_features_per_view']:.0f} | "
                   f"{fmt_or_na(row['matching_success_rate'], '.1%')} | {row['verified_matches']} |")
    return "\n".join(out)
