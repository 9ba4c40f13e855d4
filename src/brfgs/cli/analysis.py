"""``brfgs render | brf | products | export``: analysis of a trained model (brfgs.analysis).

All four read a trained model (a run folder with model.safetensors, or the model file
itself) without the training scene; ``brf`` reads the scene (for observations and, on
simulated scenes, truth) when it is available.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer

from brfgs.errors import UserError

RunArg = typer.Argument(..., help="Run folder of `brfgs train` (with model.safetensors) or a model file.",
                        show_default=False)
BackendOpt = typer.Option("auto", "--backend", help="Rasterizer backend: auto | torch | cpu | cuda.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="No progress bars.")
OverwriteOpt = typer.Option(False, "--overwrite", help="Replace the results of an earlier run of this command in --out.")


def _run_dir(run: Path) -> Path:
    return run if run.is_dir() else run.parent


def _prepare_out(out: Path, marker: str, overwrite: bool, scene_root: str | None) -> Path:
    from brfgs.cli._options import check_output_dir

    check_output_dir(out, Path(scene_root) if scene_root and Path(scene_root).exists() else None,
                     overwrite=overwrite, marker=marker)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _floats_opt(text: str, field: str, n: int | None = None) -> list[float]:
    try:
        vals = [float(t) for t in str(text).split(",") if t.strip()]
    except ValueError:
        raise UserError(f"expected comma-separated numbers, got {text!r}", field=field) from None
    if not vals or not all(math.isfinite(v) for v in vals):
        raise UserError(f"expected finite numbers, got {text!r}", field=field)
    if n is not None and len(vals) != n:
        raise UserError(f"expected {n} numbers, got {len(vals)}", field=field)
    return vals


def _sun(bm, sun_zenith, sun_azimuth):
    from brfgs.analysis.views import check_azimuth_deg, check_zenith_deg

    sz = bm.sun_zenith_deg if sun_zenith is None else check_zenith_deg(sun_zenith, "--sun-zenith")
    sa = bm.sun_azimuth_deg if sun_azimuth is None else check_azimuth_deg(sun_azimuth, "--sun-azimuth")
    return sz, sa


# ------------------------------------------------------------------------------------------ render
def render_cmd(
    run: Path = RunArg,
    view_zenith: float = typer.Option(..., "--view-zenith", help="View zenith (deg, 0 = nadir, < 90)."),
    view_azimuth: float = typer.Option(..., "--view-azimuth", help="View azimuth (deg, clockwise from north, "
                                       "direction from the target toward the sensor)."),
    sun_zenith: float = typer.Option(None, "--sun-zenith", help="Sun zenith (deg) (default: the training sun)."),
    sun_azimuth: float = typer.Option(None, "--sun-azimuth", help="Sun azimuth (deg) (default: the training sun)."),
    distance: float = typer.Option(None, "--distance", help="Camera distance to the target (m) "
                                   "(default: median distance of the training cameras)."),
    target: str = typer.Option(None, "--target", metavar="X,Y,Z", help="Point looked at (ENU m) "
                               "(default: median Gaussian position)."),
    size: str = typer.Option(None, "--size", metavar="W[,H]", help="Image size in pixels (default: training size)."),
    fov: float = typer.Option(None, "--fov", help="Horizontal field of view (deg) (default: training camera's)."),
    path: str = typer.Option(None, "--path", help="'orbit' (all azimuths at --view-zenith) or 'sweep' "
                             "(through nadir in the plane of --view-azimuth, up to --view-zenith): PNG sequence + GIF."),
    frames: int = typer.Option(36, "--frames", min=2, help="Frames of --path."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: RUN/analysis/render_z<Z>_a<A>)."),
    repeat: int = typer.Option(1, "--repeat", min=1, help="Render this many times; timings report the median "
                               "of the calls after the first (which also loads compiled kernels)."),
    backend: str = BackendOpt,
    overwrite: bool = OverwriteOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Render the model from any view: ENVI cube, CIR PNG, depth and normal maps (PNG + .npy), timing."""
    import numpy as np

    from brfgs.analysis import plots, views
    from brfgs.analysis.renderer import load_model, render_view
    from brfgs.data.cir import cir_composite
    from brfgs.data.cube_io import write_envi

    vz = views.check_zenith_deg(view_zenith, "--view-zenith")
    va = views.check_azimuth_deg(view_azimuth, "--view-azimuth")
    if path is not None and path not in ("orbit", "sweep"):
        raise UserError(f"--path must be 'orbit' or 'sweep', got {path!r}", field="--path")
    bm = load_model(run)
    sz, sa = _sun(bm, sun_zenith, sun_azimuth)
    tr = bm.intrinsics
    if size is None:
        w, h = tr.w, tr.h
    else:
        wh = _floats_opt(size, "--size")
        if len(wh) not in (1, 2) or any(v != int(v) or v < 1 or v > 8192 for v in wh):
            raise UserError("expected W or W,H in pixels (1..8192)", field="--size")
        w, h = int(wh[0]), int(wh[-1])
    fov_deg = fov if fov is not None else math.degrees(2 * math.atan(0.5 * tr.w / tr.fl_x))
    tgt = bm.scene_centre_m() if target is None else np.array(_floats_opt(target, "--target", 3))
    dist = bm.typical_distance_m() if distance is None else distance
    if out is None:
        tag = f"render_z{vz:g}_a{va:g}" + (f"_{path}" if path else "")
        out = _run_dir(run) / "analysis" / tag
    _prepare_out(out, "render.json", overwrite, bm.scene_root)

    def one(z, a):
        c2w, intr = views.view_camera(z, a, dist, tgt, size=(w, h), fov_deg=fov_deg)
        return c2w, intr, render_view(bm, c2w, intr, sun_zenith_deg=sz, sun_azimuth_deg=sa, backend=backend)

    def cir_of(rv):
        if rv.cube is not None:
            return cir_composite(rv.cube, bm.cir_indices, bm.cir_scale)
        return np.clip(rv.latent[..., :3], 0, 1)

    info = {"model": bm.source, "scene": bm.scene_name, "sun_zenith_deg": sz, "sun_azimuth_deg": sa,
            "distance_m": dist, "target_m": [float(v) for v in tgt], "fov_deg": fov_deg, "width": w, "height": h,
            "n_gaussians": bm.n_gaussians}
    if path is None:
        times = []
        for _ in range(repeat):
            c2w, intr, rv = one(vz, va)
            times.append(rv.timings_s)
        wl = bm.wavelengths_nm
        files = {}
        if rv.cube is not None:
            files["cube"] = str(write_envi(out / "cube.hdr", rv.cube, wl, bm.fwhm_nm,
                                           extra={"description": f"brfgs render view {vz:g}/{va:g} sun {sz:g}/{sa:g}"}))
        files["cir_png"] = str(plots.save_rgb_png(out / "cir.png", cir_of(rv)))
        np.save(out / "depth.npy", rv.depth.astype(np.float32))
        np.save(out / "alpha.npy", rv.alpha.astype(np.float32))
        files["depth_png"] = str(plots.save_depth_png(out / "depth.png", rv.depth, rv.alpha))
        if rv.normal is not None:
            np.save(out / "normal.npy", rv.normal.astype(np.float32))
            files["normal_png"] = str(plots.save_normal_png(out / "normal.png", rv.normal))
        warm = times[1:] if len(times) > 1 else times   # the first call also loads numba's compiled kernels
        med = {k: float(np.median([t[k] for t in warm])) for k in times[0]}
        info.update({"view_zenith_deg": vz, "view_azimuth_deg": va, "c2w": c2w.tolist(),
                     "intrinsics": {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy,
                                    "w": intr.w, "h": intr.h},
                     "timings_s": {"median": med, "first": times[0], "all": times, "repeat": repeat,
                                   "median_over": "calls after the first" if len(times) > 1 else "the only call"},
                     "files": files,
                     "depth": "metres along the optical axis (0 where nothing is rendered)",
                     "normal": "unit world (ENU) normals facing the camera, 0 where nothing is rendered"})
        (out / "render.json").write_text(json.dumps(info, indent=1))
        typer.echo(f"rendered {w}x{h}, {len(bm.wavelengths_nm)} bands in {med['total_s'] * 1000:.0f} ms "
                   f"({'median of ' + str(len(warm)) + ' warm calls' if repeat > 1 else 'first call'}) -> {out}")
        return
    seq = views.orbit_path(vz, frames, va) if path == "orbit" else views.zenith_sweep_path(va, vz, frames)
    from PIL import Image

    (out / "frames").mkdir(exist_ok=True)
    imgs, rows, times = [], [], []
    it = seq
    if not quiet:
        from tqdm import tqdm

        it = tqdm(seq, desc=path)
    for k, (z, a) in enumerate(it):
        c2w, intr, rv = one(z, a)
        p = plots.save_rgb_png(out / "frames" / f"frame_{k:03d}.png", cir_of(rv))
        imgs.append(Image.open(p).convert("RGB"))
        rows.append({"frame": k, "view_zenith_deg": z, "view_azimuth_deg": a, "file": str(p)})
        times.append(rv.timings_s["total_s"])
    imgs[0].save(out / f"{path}.gif", save_all=True, append_images=imgs[1:], duration=100, loop=0)
    info.update({"path": path, "frames": rows, "timings_s": {"median_total_s": float(np.median(times))},
                 "gif": str(out / f"{path}.gif")})
    (out / "render.json").write_text(json.dumps(info, indent=1))
    typer.echo(f"rendered {len(seq)} frames ({np.median(times) * 1000:.0f} ms each) -> {out / (path + '.gif')}")


# ------------------------------------------------------------------------------------------ brf
def _resolve_roi(spec, bm, scene, backend):
    """ROISpec -> ROI (PolygonROI / PointSetROI)."""
    import numpy as np

    from brfgs.analysis import roi as R
    from brfgs.analysis.renderer import render_view

    if spec.kind == "polygon":
        r = R.PolygonROI(spec.polygon_xy_m, name=spec.name, polygons=spec.polygons, source=spec.source or {})
        means = bm.model.means.detach().double().numpy()
        lo, hi = means[:, :2].min(0), means[:, :2].max(0)
        v = r.all_vertices_xy_m
        if (v[:, 0].max() < lo[0] or v[:, 0].min() > hi[0] or v[:, 1].max() < lo[1] or v[:, 1].min() > hi[1]):
            src = (spec.source or {}).get("file")
            raise UserError(f"the polygon (x {v[:, 0].min():.6g}..{v[:, 0].max():.6g}, y {v[:, 1].min():.6g}.."
                            f"{v[:, 1].max():.6g}) lies outside the model (x {lo[0]:.1f}..{hi[0]:.1f}, "
                            f"y {lo[1]:.1f}..{hi[1]:.1f} m); ROI coordinates are the scene's local ENU metres, "
                            "not longitude/latitude or projected map coordinates",
                            file=src, field="coordinates" if src else "--roi")
        r.set_surface_height(means)
        return r
    if spec.kind in ("box", "mask"):
        fr = bm.frame(spec.view)
        c2w = np.asarray(fr["c2w"], float)
        intr = bm.intrinsics
        rv = render_view(bm, c2w, intr, decode=False, want_normals=False, backend=backend)
        if spec.kind == "box":
            c0, r0, c1, r1 = spec.box
            if c0 < 0 or r0 < 0 or c1 > intr.w or r1 > intr.h:
                raise UserError(f"box {spec.box} lies outside the {intr.w}x{intr.h} view {spec.view!r}", field="--roi")
            mask = np.zeros((intr.h, intr.w), bool)
            mask[r0:r1, c0:c1] = True
        else:
            mask = R.load_mask(spec.mask_path, (intr.h, intr.w))
        mask &= rv.alpha >= 0.5
        return R.roi_from_view_mask(mask, rv.depth, c2w, intr, name=spec.name,
                                    source={"kind": spec.kind, "view": spec.view,
                                            "box": list(spec.box) if spec.box else None,
                                            "mask": str(spec.mask_path) if spec.mask_path else None})
    # material of a simulated scene
    if scene is None or scene.truth_dir is None:
        raise UserError("a material ROI needs the simulated scene with its truth/ folder (pass --scene)",
                        field="--roi")
    frames = [f for f in scene.frames if f.view_zenith_deg <= 25.0] or scene.frames
    pts, fp = R.material_points(scene.truth_dir, spec.material, frames, scene.intrinsics)
    return R.PointSetROI(pts, tol_xy_m=1.5 * fp, tol_z_m=max(2.0, 4.0 * fp), name=spec.name,
                         source={"kind": "material", "material": spec.material, "frames": [f.name for f in frames]})


def _open_scene(bm, scene_path: Path | None, required: bool):
    from brfgs.data import read_scene

    root = scene_path if scene_path is not None else (Path(bm.scene_root) if bm.scene_root else None)
    if root is None or not (root / "transforms.json").is_file():
        if scene_path is not None:
            raise UserError("not a scene folder (no transforms.json)", file=scene_path, field="--scene")
        if required:
            raise UserError("the training scene is needed here; pass --scene", field="--scene")
        return None
    sc_meta = bm.meta.get("scene", {})
    kw = {}
    if sc_meta.get("roi") is not None:
        kw["roi"] = sc_meta["roi"]
    split_seed = int(bm.meta.get("config", {}).get("split_seed", 0)) if isinstance(bm.meta.get("config"), dict) else 0
    return read_scene(root, downscale=int(sc_meta.get("downscale", 1) or 1), split_seed=split_seed, **kw)


def brf_cmd(
    run: Path = RunArg,
    roi: str = typer.Option(..., "--roi", help="polygon:X1,Y1;X2,Y2;... (ENU m) | FILE.geojson (or geojson:FILE): "
                            "a Polygon/MultiPolygon geometry, Feature or FeatureCollection (union) with "
                            "coordinates in the scene's local ENU metres (x east, y north; not lon/lat; a 'crs' "
                            "member other than a local/ENU one is refused) | box:VIEW:C0,R0,C1,R1 | "
                            "mask:VIEW:FILE(.npy/.png) | material:NAME (simulated scenes)."),
    roi_name: str = typer.Option(None, "--roi-name", help="Name used in file names and titles."),
    bands: str = typer.Option("480,680,760,860", "--bands", help="Wavelengths (nm) of the curves and maps."),
    scene: Path = typer.Option(None, "--scene", help="Scene folder for observations/truth "
                               "(default: the training scene, when it still exists)."),
    step: float = typer.Option(2.5, "--step", min=0.1, help="Principal-plane step (deg)."),
    max_zenith: float = typer.Option(75.0, "--max-zenith", min=1.0, max=85.0, help="Largest view zenith (deg)."),
    polar_azimuths: int = typer.Option(60, "--polar-azimuths", min=4, help="Azimuth sectors of the polar map."),
    polar_zeniths: int = typer.Option(24, "--polar-zeniths", min=2, help="Zenith rings of the polar map."),
    no_polar: bool = typer.Option(False, "--no-polar", help="Skip the polar maps."),
    min_alpha: float = typer.Option(0.5, "--min-alpha", min=0.0, max=1.0,
                                    help="Pixels count for the ROI only where the accumulated opacity is at least this."),
    distance: float = typer.Option(None, "--distance", min=1.0, help="ROI camera distance (m) (default: the "
                                   "training cameras' median distance, at least 8 ROI radii)."),
    size: int = typer.Option(None, "--size", min=8, max=1024, help="Pixels of the square ROI camera (the ROI fills "
                             "~90 percent of it) (default: the training images' pixel footprint on the ground)."),
    truth_render: bool = typer.Option(True, "--truth-render/--no-truth-render",
                                      help="On simulated scenes (truth/scene.json), render the truth again with the "
                                      "simulator along the principal plane and on a coarse polar grid, and report "
                                      "the model's BRF error per band (slow: about 0.3-1 s per direction)."),
    truth_step: float = typer.Option(10.0, "--truth-step", min=1.0, help="Principal-plane step (deg) of the truth renders."),
    truth_size: int = typer.Option(128, "--truth-size", min=16, help="Pixels of the principal-plane truth renders "
                                   "(acquisition FOV)."),
    truth_polar_azimuths: int = typer.Option(12, "--truth-polar-azimuths", min=1,
                                             help="Azimuth sectors of the truth polar grid (coarse: each direction is "
                                             "a simulator render)."),
    truth_polar_zeniths: int = typer.Option(6, "--truth-polar-zeniths", min=1,
                                            help="Zenith rings of the truth polar grid."),
    truth_polar_size: int = typer.Option(64, "--truth-polar-size", min=16,
                                         help="Pixels of the polar truth renders (acquisition FOV)."),
    truth_spp: int = typer.Option(16, "--truth-spp", min=1, help="Samples per pixel of all truth renders: a power "
                                  "of 4 (1, 4, 16, 64, 256) for scenes simulated with the default 'ldsampler', a "
                                  "power of two for older 'independent' scenes."),
    max_plane_offset: float = typer.Option(20.0, "--max-plane-offset",
                                           help="Observations within this azimuth (deg) of the principal plane are plotted."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: RUN/analysis/brf_<roi name>)."),
    threads: int = typer.Option(1, "--threads", min=0, help="PyTorch threads in the sampling loops "
                                "(0 = leave as is; 1 is fastest for small ROI cameras)."),
    backend: str = BackendOpt,
    overwrite: bool = OverwriteOpt,
    quiet: bool = QuietOpt,
) -> None:
    """BRF of a region: principal-plane curves, polar maps, spectra vs observations (and truth), CSVs.

    On a simulated scene (truth/scene.json) the simulator renders the truth again for the principal
    plane and a coarse polar grid (polar_truth.png/.csv); per-band RMSE and mean bias of the model
    against it are in brf.json and truth_error.csv.
    """
    import time

    import numpy as np

    from brfgs.analysis import brf as B
    from brfgs.analysis import plots
    from brfgs.analysis.renderer import load_model, torch_threads
    from brfgs.analysis.roi import parse_roi_spec
    from brfgs.analysis.views import principal_plane_directions

    spec = parse_roi_spec(roi, roi_name)
    wls = _floats_opt(bands, "--bands")
    bm = load_model(run)
    if not bm.spectral:
        raise UserError("this model has no spectra (CIR variant); BRF analysis needs a spectral model", file=run)
    bi = bm.band_indices(wls)
    sc = _open_scene(bm, scene, required=(spec.kind == "material"))
    do_truth = sc is not None and truth_render and B.has_simulator_truth(sc.root)
    if do_truth:
        B.check_truth_spp(sc.root, truth_spp, field="--truth-spp")
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in spec.name)
    out = out if out is not None else _run_dir(run) / "analysis" / f"brf_{safe}"
    _prepare_out(out, "brf.json", overwrite, bm.scene_root)
    progress = not quiet
    timings = {}
    t0 = time.perf_counter()
    with torch_threads(threads or None):
        region = _resolve_roi(spec, bm, sc, backend)
        (out / "roi.json").write_text(json.dumps(region.describe(), indent=1))
        timings["roi_s"] = time.perf_counter() - t0
        wl_sel = bm.wavelengths_nm[bi]
        summary: dict = {"model": bm.source, "scene": bm.scene_name, "roi": region.describe(),
                         "bands_nm": [float(w) for w in wl_sel], "sun_zenith_deg": bm.sun_zenith_deg,
                         "sun_azimuth_deg": bm.sun_azimuth_deg, "files": {}}

        # principal plane
        t = time.perf_counter()
        s, pp = B.principal_plane(bm, region, bi, max_zenith_deg=max_zenith, step_deg=step, size=size,
                                  distance_m=distance, backend=backend, progress=progress, min_alpha=min_alpha)
        timings["principal_plane_s"] = time.perf_counter() - t
        peaks = {f"{w:.0f}": B.curve_peak(s, pp.values[:, j]) for j, w in enumerate(wl_sel)}
        summary["principal_plane"] = {"peak_signed_zenith_deg": peaks, "hotspot_signed_zenith_deg": bm.sun_zenith_deg,
                                      "specular_signed_zenith_deg": -bm.sun_zenith_deg,
                                      "camera": pp.extra, "min_pixels": int(pp.n_pixels.min()),
                                      "directions_without_roi_pixels": int((pp.n_pixels == 0).sum()),
                                      "min_alpha": min_alpha}
        if (pp.n_pixels == 0).any():
            typer.echo(f"warning: the ROI is not seen (no pixel with opacity >= {min_alpha:g} whose surface point "
                       f"lies in it) in {int((pp.n_pixels == 0).sum())} of {len(s)} principal-plane directions; "
                       "see --min-alpha and the model's opacity", err=True)

        # observations (all frames of the model), truth where the scene has it
        obs = []
        if sc is not None:
            t = time.perf_counter()
            obs = B.frame_observations(bm, region, sc, backend=backend, progress=progress, min_alpha=min_alpha)
            timings["observations_s"] = time.perf_counter() - t
        near = B.nearest_to_plane(obs, max_offset_deg=max_plane_offset)
        obs_x = [o.signed_zenith_deg for o in near if o.observed is not None]
        obs_v = np.array([o.observed[bi] for o in near if o.observed is not None]).reshape(-1, len(bi))
        tru = [o for o in near if o.truth is not None]
        tru_x = [o.signed_zenith_deg for o in tru]
        tru_v = np.array([o.truth[bi] for o in tru]).reshape(-1, len(bi))
        rows = [[float(x)] + [float(v) for v in pp.values[k]] + [int(pp.n_pixels[k])] for k, x in enumerate(s)]
        plots.write_csv(out / "principal_plane.csv", ["signed_view_zenith_deg"] + [f"brf_{w:.0f}nm" for w in wl_sel]
                        + ["n_pixels"], rows)
        plots.write_csv(out / "principal_plane_observations.csv",
                        ["frame", "split", "signed_view_zenith_deg", "plane_offset_deg", "n_pixels"]
                        + [f"observed_{w:.0f}nm" for w in wl_sel] + [f"reconstructed_{w:.0f}nm" for w in wl_sel]
                        + [f"truth_{w:.0f}nm" for w in wl_sel],
                        [[o.name, o.split, o.signed_zenith_deg, o.plane_offset_deg, o.n_pixels]
                         + ([float(v) for v in o.observed[bi]] if o.observed is not None else [float("nan")] * len(bi))
                         + [float(v) for v in o.reconstructed[bi]]
                         + ([float(v) for v in o.truth[bi]] if o.truth is not None else [float("nan")] * len(bi))
                         for o in near])
        truth_s = truth_v = None
        truth_bands = [sc.band_index_nearest(w) for w in wl_sel] if do_truth else []
        truth_errors = []                                   # rows of truth_error.csv
        if do_truth:
            t = time.perf_counter()
            n_t = int(round(2 * max_zenith / truth_step)) + 1
            truth_s = np.linspace(-max_zenith, max_zenith, n_t)
            tz, ta = principal_plane_directions(truth_s, bm.sun_azimuth_deg)
            tb = B.truth_brf(sc.root, region, tz, ta, truth_bands, distance_m=pp.extra["distance_m"],
                             size=truth_size, spp=truth_spp, progress=progress)
            truth_v = tb.values
            timings["truth_render_s"] = time.perf_counter() - t
            model_at = np.stack([np.interp(truth_s, s, pp.values[:, j]) for j in range(len(bi))], 1)
            err = B.brf_error(model_at, truth_v, wl_sel)
            summary["principal_plane"]["vs_truth_render"] = {
                **err, "step_deg": truth_step, "size_px": truth_size, "spp": truth_spp,
                "model": "principal-plane curve interpolated to the truth directions",
                "truth_peak_signed_zenith_deg": {f"{w:.0f}": B.curve_peak(truth_s, truth_v[:, j])
                                                 for j, w in enumerate(wl_sel)}}
            truth_errors += [["principal_plane", float(w), err["n_directions"], err["rmse"][f"{w:.0f}"],
                              err["mean_bias"][f"{w:.0f}"], err["mean_relative_error"][f"{w:.0f}"]] for w in wl_sel]
            plots.write_csv(out / "principal_plane_truth.csv",
                            ["signed_view_zenith_deg"] + [f"truth_{w:.0f}nm" for w in wl_sel]
                            + [f"model_{w:.0f}nm" for w in wl_sel] + ["n_pixels"],
                            [[float(truth_s[k])] + [float(v) for v in truth_v[k]] + [float(v) for v in model_at[k]]
                             + [int(tb.n_pixels[k])] for k in range(n_t)])
            summary["files"]["principal_plane_truth_csv"] = "principal_plane_truth.csv"
        plots.plot_principal_plane(out / "principal_plane.png", s, pp.values, wl_sel, bm.sun_zenith_deg,
                                   title=f"{spec.name}: principal plane (sun zenith {bm.sun_zenith_deg:.1f}°)",
                                   obs_signed_zenith_deg=obs_x, obs_values=obs_v,
                                   truth_signed_zenith_deg=tru_x, truth_values=tru_v,
                                   truth_curve_signed_zenith_deg=truth_s, truth_curve_values=truth_v)
        summary["files"].update({"principal_plane_png": "principal_plane.png", "principal_plane_csv": "principal_plane.csv",
                                 "principal_plane_observations_csv": "principal_plane_observations.csv"})

        # polar maps
        if not no_polar:
            t = time.perf_counter()
            zc, ac, vals, res = B.polar_map(bm, region, bi, n_azimuth=polar_azimuths, n_zenith=polar_zeniths,
                                            max_zenith_deg=max_zenith, size=size, distance_m=distance,
                                            backend=backend, progress=progress, min_alpha=min_alpha)
            timings["polar_map_s"] = time.perf_counter() - t
            rows = []
            for i, z in enumerate(zc):
                for k, a in enumerate(ac):
                    rows.append([float(z), float(a), float(B.relative_azimuth_deg(a, bm.sun_azimuth_deg))]
                                + [float(v) for v in vals[i, k]] + [int(res.n_pixels.reshape(len(zc), len(ac))[i, k])])
            plots.write_csv(out / "polar.csv", ["view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg"]
                            + [f"brf_{w:.0f}nm" for w in wl_sel] + ["n_pixels"], rows)
            plots.plot_polar(out / "polar.png", zc, ac, vals, wl_sel, bm.sun_zenith_deg, bm.sun_azimuth_deg,
                             title=f"{spec.name}: BRF over the view hemisphere", max_zenith_deg=max_zenith)
            flat = vals.reshape(-1, len(bi))
            kmax = np.nanargmax(np.where(np.isfinite(flat), flat, -np.inf), axis=0)
            summary["polar"] = {"n_azimuth": polar_azimuths, "n_zenith": polar_zeniths, "max_zenith_deg": max_zenith,
                                "argmax": {f"{w:.0f}": {"view_zenith_deg": float(np.repeat(zc, len(ac))[kmax[j]]),
                                                        "view_azimuth_deg": float(np.tile(ac, len(zc))[kmax[j]])}
                                           for j, w in enumerate(wl_sel)},
                                "seconds": timings["polar_map_s"], "directions": int(flat.shape[0])}
            summary["files"].update({"polar_png": "polar.png", "polar_csv": "polar.csv"})
            if do_truth:
                from brfgs.analysis.views import hemisphere_grid

                t = time.perf_counter()
                tzc, tac = hemisphere_grid(truth_polar_azimuths, truth_polar_zeniths, max_zenith)
                TZ, TA = np.meshgrid(tzc, tac, indexing="ij")
                tpb = B.truth_brf(sc.root, region, TZ.ravel(), TA.ravel(), truth_bands,
                                  distance_m=res.extra["distance_m"], size=truth_polar_size, spp=truth_spp,
                                  progress=progress)
                timings["truth_polar_render_s"] = time.perf_counter() - t
                t = time.perf_counter()
                mtb = B.roi_brf(bm, region, TZ.ravel(), TA.ravel(), bi, size=size, distance_m=distance,
                                backend=backend, min_alpha=min_alpha, desc="model on the truth grid")
                timings["model_on_truth_grid_s"] = time.perf_counter() - t
                shape = (len(tzc), len(tac), len(bi))
                tvals, mvals = tpb.values.reshape(shape), mtb.values.reshape(shape)
                err = B.brf_error(mtb.values, tpb.values, wl_sel)
                plots.write_csv(out / "polar_truth.csv",
                                ["view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg"]
                                + [f"truth_{w:.0f}nm" for w in wl_sel] + [f"model_{w:.0f}nm" for w in wl_sel]
                                + ["n_pixels_truth", "n_pixels_model"],
                                [[float(TZ.flat[k]), float(TA.flat[k]),
                                  float(B.relative_azimuth_deg(TA.flat[k], bm.sun_azimuth_deg))]
                                 + [float(v) for v in tpb.values[k]] + [float(v) for v in mtb.values[k]]
                                 + [int(tpb.n_pixels[k]), int(mtb.n_pixels[k])] for k in range(TZ.size)])
                plots.plot_polar_truth(out / "polar_truth.png", zc, ac, vals, tzc, tac, tvals, mvals, wl_sel,
                                       bm.sun_zenith_deg, bm.sun_azimuth_deg, max_zenith_deg=max_zenith,
                                       title=f"{spec.name}: BRF-GS vs simulator truth over the view hemisphere")
                tflat = np.where(np.isfinite(tpb.values), tpb.values, -np.inf)
                tk = np.argmax(tflat, axis=0)
                summary["polar"]["vs_truth_render"] = {
                    **err, "n_azimuth": truth_polar_azimuths, "n_zenith": truth_polar_zeniths,
                    "size_px": truth_polar_size, "spp": truth_spp,
                    "model": "the model rendered for the same directions as the truth",
                    "truth_min_pixels": int(tpb.n_pixels.min()),
                    "truth_argmax": {f"{w:.0f}": ({"view_zenith_deg": float(TZ.flat[tk[j]]),
                                                   "view_azimuth_deg": float(TA.flat[tk[j]])}
                                                  if np.isfinite(tflat[tk[j], j]) else None)
                                     for j, w in enumerate(wl_sel)},
                    "seconds": timings["truth_polar_render_s"]}
                summary["files"].update({"polar_truth_png": "polar_truth.png", "polar_truth_csv": "polar_truth.csv"})
                truth_errors += [["polar", float(w), err["n_directions"], err["rmse"][f"{w:.0f}"],
                                  err["mean_bias"][f"{w:.0f}"], err["mean_relative_error"][f"{w:.0f}"]]
                                 for w in wl_sel]
        if truth_errors:
            plots.write_csv(out / "truth_error.csv", ["comparison", "wavelength_nm", "n_directions", "rmse",
                                                      "mean_bias_model_minus_truth", "mean_relative_error"],
                            [[r[0], r[1], r[2]] + [float("nan") if v is None else v for v in r[3:]]
                             for r in truth_errors])
            summary["files"]["truth_error_csv"] = "truth_error.csv"

    # spectra over the test views (Fig. 7) and errors
    test = [o for o in obs if o.split == "test" and o.observed is not None]
    if test:
        w = np.array([o.n_pixels for o in test], float)
        rec = np.average(np.array([o.reconstructed for o in test]), axis=0, weights=w)
        ob = np.average(np.array([o.observed for o in test]), axis=0, weights=w)
        tr_list = [o for o in test if o.truth is not None]
        tr = (np.average(np.array([o.truth for o in tr_list]), axis=0, weights=[o.truth_n_pixels for o in tr_list])
              if tr_list else None)
        le = B.log_error(rec, ob)
        plots.write_csv(out / "spectra.csv", ["wavelength_nm", "reconstructed", "observed", "log_error"]
                        + (["truth"] if tr is not None else []),
                        [[float(bm.wavelengths_nm[b]), float(rec[b]), float(ob[b]), float(le[b])]
                         + ([float(tr[b])] if tr is not None else []) for b in range(len(rec))])
        plots.plot_spectra(out / "spectra.png", bm.wavelengths_nm, rec, ob, le, truth=tr,
                           title=f"{spec.name}: mean over {len(test)} test views")
        summary["spectra"] = {"n_test_views": len(test), "mean_abs_log_error": float(np.mean(np.abs(le))),
                              "rmse_reconstructed_vs_observed": float(np.sqrt(np.mean((rec - ob) ** 2)))}
        summary["files"].update({"spectra_png": "spectra.png", "spectra_csv": "spectra.csv"})
    if obs:
        allrows = []
        for o in obs:
            allrows.append([o.name, o.split, o.view_zenith_deg, o.view_azimuth_deg, o.relative_azimuth_deg,
                            o.signed_zenith_deg, o.n_pixels]
                           + [float(v) for v in (o.reconstructed[bi] if o.reconstructed is not None else [np.nan] * len(bi))]
                           + [float(v) for v in (o.observed[bi] if o.observed is not None else [np.nan] * len(bi))]
                           + [float(v) for v in (o.truth[bi] if o.truth is not None else [np.nan] * len(bi))])
        plots.write_csv(out / "observations.csv",
                        ["frame", "split", "view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg",
                         "signed_view_zenith_deg", "n_pixels"] + [f"reconstructed_{w:.0f}nm" for w in wl_sel]
                        + [f"observed_{w:.0f}nm" for w in wl_sel] + [f"truth_{w:.0f}nm" for w in wl_sel], allrows)
        summary["files"]["observations_csv"] = "observations.csv"
        # BRF error per band: reconstructed vs observed and vs truth over all frames
        def _err(key):
            pairs = [(o.reconstructed[bi], getattr(o, key)[bi]) for o in obs
                     if o.reconstructed is not None and getattr(o, key) is not None]
            if not pairs:
                return None
            r = np.array([p[0] for p in pairs])
            t_ = np.array([p[1] for p in pairs])
            return {"n_frames": len(pairs),
                    "rmse": {f"{w:.0f}": float(np.sqrt(np.mean((r[:, j] - t_[:, j]) ** 2))) for j, w in enumerate(wl_sel)},
                    "mean_relative_error": {f"{w:.0f}": float(np.mean(np.abs(r[:, j] - t_[:, j]) / np.maximum(np.abs(t_[:, j]), 1e-6)))
                                            for j, w in enumerate(wl_sel)}}
        summary["brf_error"] = {"vs_observed": _err("observed"), "vs_truth": _err("truth")}
    else:
        summary["observations"] = "scene not available: no observations/truth (pass --scene)"
    timings["total_s"] = time.perf_counter() - t0
    summary["timings_s"] = timings
    (out / "brf.json").write_text(json.dumps(summary, indent=1))
    pk = ", ".join(f"{k} nm: {v:+.1f}°" for k, v in peaks.items())
    typer.echo(f"{spec.name}: principal-plane peaks {pk} (hotspot +{bm.sun_zenith_deg:.1f}°, "
               f"specular -{bm.sun_zenith_deg:.1f}°) -> {out}")


# ------------------------------------------------------------------------------------------ products
def products_cmd(
    run: Path = RunArg,
    size: str = typer.Option(None, "--size", metavar="W[,H]", help="Pixels of the nadir map (default: the "
                             "training images' pixel footprint on the ground, at most 2048)."),
    half_extent: float = typer.Option(None, "--half-extent", help="Half width of the mapped area (m) "
                                      "(default: half the Gaussians' 2–98 % extent)."),
    sun_zenith: float = typer.Option(None, "--sun-zenith", help="Sun zenith (deg) of the contribution maps and "
                                     "ANIX (default: training sun)."),
    nbar_sun_zenith: float = typer.Option(None, "--nbar-sun-zenith", help="Sun zenith (deg) of NBAR "
                                          "(default: the sun zenith)."),
    albedo_sun_zenith: float = typer.Option(None, "--albedo-sun-zenith", help="Sun zenith (deg) of the black-sky "
                                            "albedo (default: the sun zenith)."),
    min_alpha: float = typer.Option(0.5, "--min-alpha", min=0.0, max=1.0,
                                    help="Pixels whose accumulated opacity is below this are NaN in the products."),
    check_decoder: bool = typer.Option(True, "--check-decoder/--no-check-decoder",
                                       help="Measure how far latent-space albedo is from integrating decoded spectra."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: RUN/analysis/products)."),
    backend: str = BackendOpt,
    overwrite: bool = OverwriteOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Per-pixel products from nadir: kernel contribution maps, NBAR, black/white-sky albedo, ANIX."""
    import time

    import numpy as np

    from brfgs.analysis import plots
    from brfgs.analysis import products as P
    from brfgs.analysis.renderer import load_model
    from brfgs.analysis.views import check_zenith_deg
    from brfgs.data.cir import cir_composite
    from brfgs.data.cube_io import write_envi

    bm = load_model(run)
    P.require_hybrid(bm)
    sz = bm.sun_zenith_deg if sun_zenith is None else check_zenith_deg(sun_zenith, "--sun-zenith")
    nz = sz if nbar_sun_zenith is None else check_zenith_deg(nbar_sun_zenith, "--nbar-sun-zenith")
    az_ = sz if albedo_sun_zenith is None else check_zenith_deg(albedo_sun_zenith, "--albedo-sun-zenith")
    if size is None:
        from brfgs.analysis.brf import auto_roi_size

        half = bm.scene_half_extent_m() if half_extent is None else half_extent
        wh = [auto_roi_size(bm, half, lo=16, hi=2048)]
    else:
        wh = _floats_opt(size, "--size")
    if len(wh) not in (1, 2) or any(v != int(v) or v < 1 or v > 8192 for v in wh):
        raise UserError("expected W or W,H in pixels (1..8192)", field="--size")
    out = out if out is not None else _run_dir(run) / "analysis" / "products"
    _prepare_out(out, "products.json", overwrite, bm.scene_root)
    c2w, intr = P.nadir_camera(bm, size=int(wh[0]), half_extent_m=half_extent)
    if len(wh) == 2:
        from brfgs.data.cameras import Intrinsics

        intr = Intrinsics(intr.fl_x, intr.fl_x, wh[0] / 2, wh[1] / 2, int(wh[0]), int(wh[1]))
    t0 = time.perf_counter()
    res = P.render_products(bm, c2w, intr, sun_zenith_deg=sz, nbar_sun_zenith_deg=nz, albedo_sun_zenith_deg=az_,
                            backend=backend, progress=not quiet, min_alpha=min_alpha)
    t_render = time.perf_counter() - t0
    wl = bm.wavelengths_nm
    desc = {"iso": "isotropic term", "vol": "Ross-Thick (volumetric) term", "geo": "Li-Sparse-R (geometric) term",
            "spec": "Cook-Torrance (specular) term", "total": "total BRF (sum of the four terms)",
            "nbar": f"NBAR (nadir view, sun zenith {nz:g} deg)", "bsa": f"black-sky albedo (sun zenith {az_:g} deg)",
            "wsa": "white-sky albedo", "anix": "anisotropy index max/min BRF over the principal plane"}
    files = {}
    i860 = int(np.argmin(np.abs(wl - 860.0)))
    for name in ("iso", "vol", "geo", "spec", "total", "nbar", "bsa", "wsa", "anix"):
        if name not in res:
            continue
        cube = res[name]
        hdr = write_envi(out / f"{name}.hdr", cube, wl, bm.fwhm_nm, extra={"description": f"brfgs {desc[name]}"})
        if name in ("iso", "total", "nbar", "bsa", "wsa"):
            png = plots.save_rgb_png(out / f"{name}.png", cir_composite(cube, bm.cir_indices, bm.cir_scale))
        else:
            png = plots.save_map_png(out / f"{name}.png", cube[..., i860], f"{desc[name]}, {wl[i860]:.0f} nm",
                                     diverging=(name != "anix"), label="reflectance" if name != "anix" else "max/min")
        band = cube[..., i860]
        ok = np.isfinite(band)
        files[name] = {"cube": hdr.name, "png": png.name, "description": desc[name],
                       "mean_at_nm": float(band[ok].mean()) if ok.any() else None,
                       "finite_fraction": float(ok.mean())}
    np.save(out / "alpha.npy", res["alpha"].astype(np.float32))
    info = {"model": bm.source, "scene": bm.scene_name, "settings": res["settings"],
            "camera": {"c2w": c2w.tolist(), "intrinsics": {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx,
                                                            "cy": intr.cy, "w": intr.w, "h": intr.h}},
            "files": files, "mean_band_nm": float(wl[i860]), "timings_s": {"render_products_s": t_render},
            "notes": ["contributions are decoded sequentially (iso, +vol, +geo, +spec); they add up to 'total'",
                      "albedo integrals are applied in the latent space (brfgs.brdf.integrals); Cook-Torrance "
                      "integrals assume a horizontal facet", f"NaN where the accumulated opacity < {min_alpha:g}"]}
    if check_decoder:
        info["decoder_check"] = P.decoder_nonlinearity(bm, az_)
    (out / "products.json").write_text(json.dumps(info, indent=1))
    typer.echo(f"products ({intr.w}x{intr.h}, {len(wl)} bands) in {t_render:.1f} s -> {out}")


# ------------------------------------------------------------------------------------------ export
def export_cmd(
    run: Path = RunArg,
    out: Path = typer.Argument(..., help="Output folder (gaussians.ply, model.safetensors, export.json).",
                               show_default=False),
    view_dependence: str = typer.Option("fit", "--view-dependence",
                                        help="'fit': the view-dependent CIR colour of each Gaussian (training sun) "
                                        "fitted with degree-3 SH into f_dc/f_rest, so viewers show the BRF's "
                                        "hotspot and glint; 'none': the nadir-view colour, f_rest all zero."),
    sh_directions: int = typer.Option(48, "--sh-directions", min=16, max=1024,
                                      help="View directions (zenith <= 80 deg) sampled per Gaussian for the SH fit."),
    overwrite: bool = OverwriteOpt,
) -> None:
    """Export the Gaussians as a 3DGS PLY (full standard attribute set x y z nx ny nz f_dc_0..2 f_rest_0..44
    opacity scale_0..2 rot_0..3 with CIR colours, + BRF parameters) and the self-describing model file."""
    import time
    import hashlib
    import shutil

    from brfgs.analysis.export import write_ply
    from brfgs.analysis.renderer import load_model

    if view_dependence not in ("fit", "none"):
        raise UserError(f"expected 'fit' or 'none', got {view_dependence!r}", field="--view-dependence")
    bm = load_model(run)
    _prepare_out(out, "export.json", overwrite, bm.scene_root)
    src = Path(bm.source)
    colour_info: dict = {}
    t0 = time.perf_counter()
    ply = write_ply(out / "gaussians.ply", bm, view_dependence=view_dependence, n_directions=sh_directions,
                    info=colour_info)
    t_ply = time.perf_counter() - t0
    dst = out / "model.safetensors"
    if dst.resolve() != src.resolve():
        shutil.copyfile(src, dst.with_name(dst.name + ".tmp"))
        dst.with_name(dst.name + ".tmp").replace(dst)
    load_model(dst)  # the copy loads on its own (no scene needed)
    sha = hashlib.sha256(dst.read_bytes()).hexdigest()
    info = {"source": str(src), "ply": ply.name, "model": dst.name, "model_sha256": sha,
            "n_gaussians": bm.n_gaussians, "latent_dim": bm.model.latent_dim, "bands": len(bm.wavelengths_nm),
            "ply_properties": "x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2 rot_0..3 (standard 3DGS) "
                              "+ z_iso_*, z_vol_*, z_geo_*, z_spec_*, roughness (BRF-GS) or sh_<k>_<j> (SH baseline)",
            "ply_colours": {"space": "CIR composite (850/650/550 nm as R/G/B, scaled like the training data)",
                            "sun_zenith_deg": bm.sun_zenith_deg, "sun_azimuth_deg": bm.sun_azimuth_deg,
                            **colour_info},
            "timings_s": {"ply": t_ply},
            "model_format": "safetensors + JSON metadata (brfgs-gaussians/1); loading never executes code"}
    (out / "export.json").write_text(json.dumps(info, indent=1))
    typer.echo(f"wrote {ply} ({bm.n_gaussians} Gaussians) and {dst}")


# ------------------------------------------------------------------------------------------ bench
def bench_analysis_cmd(
    model: Path = typer.Option(None, "--model", help="Run folder or model file (default: a synthetic model of "
                               "a 128-px testsite run's size)."),
    gaussians: int = typer.Option(50_000, "--gaussians", min=100, help="Gaussians of the synthetic model."),
    size: int = typer.Option(128, "--size", min=8, help="Square size of the arbitrary view (pixels)."),
    repeats: int = typer.Option(5, "--repeats", min=1, help="Timed renders (median reported)."),
    polar_repeats: int = typer.Option(1, "--polar-repeats", min=1, help="Timed polar maps (median reported)."),
    polar_azimuths: int = typer.Option(60, "--polar-azimuths", min=1, help="Azimuth sectors of the polar map."),
    polar_zeniths: int = typer.Option(24, "--polar-zeniths", min=1, help="Zenith rings of the polar map."),
    threads: int = typer.Option(0, "--threads", min=0, help="numba/torch threads (0: all cores)."),
    json_path: Path = typer.Option(None, "--json", help="Also write the result as JSON to this file."),
) -> None:
    """Time one 164-band arbitrary view and one 60x24 polar BRF map of one ROI in 4 bands (BENCHMARKS.md)."""
    from brfgs.analysis.bench import bench_analysis
    from brfgs.render import configure_threads

    configure_threads(threads or None)
    res = bench_analysis(model, n_gaussians=gaussians, size=size, repeats=repeats, polar_repeats=polar_repeats,
                         polar_azimuths=polar_azimuths, polar_zeniths=polar_zeniths)
    r, p = res["render"], res["polar_map"]
    typer.echo(f"model: {res['model']} ({res['n_gaussians']} Gaussians, {res['bands']} bands, d={res['latent_dim']}); "
               f"threads numba {res['machine']['numba_threads']}")
    la = res["machine"]["load_average_1_5_15_before"]
    typer.echo(f"load average before: {la[0]:.1f} on {res['machine']['cpu_count']} cores (wall times include "
               f"other processes' load; CPU seconds are this process's)")
    typer.echo(f"arbitrary view {r['size'][0]}x{r['size'][1]}x{res['bands']}: median {r['median_s'] * 1000:.0f} ms wall, "
               f"{r['median_cpu_s'] * 1000:.0f} ms CPU (of {r['repeats']})")
    typer.echo(f"polar map {p['directions']} directions x {p['bands']} bands: {p['median_s']:.1f} s wall, "
               f"{p['median_cpu_s']:.1f} s CPU ({p['per_direction_ms']:.1f} ms wall per direction)")
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(res, indent=1))


def register(app: typer.Typer) -> None:
    app.command("render")(render_cmd)
    app.command("brf")(brf_cmd)
    app.command("products")(products_cmd)
    app.command("export")(export_cmd)
