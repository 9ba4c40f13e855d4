"""``brfgs render``: the model from any view under any sun, written as files.

:func:`render_report` renders one view (ENVI cube, CIR PNG, depth and normal maps as PNG and
.npy, alpha, render.json with the camera and timings) or a path of views (``orbit``: all
azimuths at one zenith; ``sweep``: through nadir in one vertical plane) as a PNG sequence and a
GIF. Every view goes through the one render path, :func:`brfgs.model.render`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

from brfgs.data.lock import releases_locks
from brfgs.analysis import plots, views
from brfgs.analysis.options import RenderOptions
from brfgs.analysis.output import Report, prepare_output_dir, run_folder
from brfgs.data.cameras import Intrinsics
from brfgs.data.cube_io import write_envi
from brfgs.errors import UserError
from brfgs.model import RenderedView, TrainedModel, camera_from_intrinsics, render
from brfgs.model.view import sun_visibility_map
from brfgs.data import atomic

__all__ = ["RenderOptions", "render_report", "PATHS"]

PATHS = ("orbit", "sweep")


@dataclass
class _Viewer:
    """The model and the camera settings shared by every view of one ``render`` call."""

    tm: TrainedModel
    sun: tuple[float, float]
    distance_m: float
    target_m: np.ndarray  # [3]
    size: tuple[int, int]
    fov_deg: float
    backend: str

    def view(self, zenith_deg: float, azimuth_deg: float) -> tuple[np.ndarray, Intrinsics, RenderedView]:
        """(c2w [4, 4], intrinsics, rendered view with normals) of one view direction."""
        c2w, intr = views.view_camera(zenith_deg, azimuth_deg, self.distance_m, self.target_m, size=self.size,
                                      fov_deg=self.fov_deg)
        rv = render(self.tm, camera_from_intrinsics(c2w, intr), sun_zenith_deg=self.sun[0],
                    sun_azimuth_deg=self.sun[1], normals=True, backend=self.backend)
        return c2w, intr, rv


def _check(opts: RenderOptions) -> tuple[float, float]:
    """Validated view zenith and azimuth (UserError naming the option otherwise)."""
    vz = views.check_zenith_deg(opts.view_zenith_deg, "--view-zenith")
    va = views.check_azimuth_deg(opts.view_azimuth_deg, "--view-azimuth")
    if opts.path is not None and opts.path not in PATHS:
        raise UserError(f"--path must be 'orbit' or 'sweep', got {opts.path!r}", field="--path")
    return vz, va


def _viewer(tm: TrainedModel, opts: RenderOptions) -> _Viewer:
    sz = tm.sun_zenith_deg if opts.sun_zenith_deg is None else views.check_zenith_deg(opts.sun_zenith_deg,
                                                                                      "--sun-zenith")
    sa = tm.sun_azimuth_deg if opts.sun_azimuth_deg is None else views.check_azimuth_deg(opts.sun_azimuth_deg,
                                                                                         "--sun-azimuth")
    tr = tm.intrinsics
    size = (tr.w, tr.h) if opts.size is None else (int(opts.size[0]), int(opts.size[-1]))
    fov = opts.fov_deg if opts.fov_deg is not None else math.degrees(2 * math.atan(0.5 * tr.w / tr.fl_x))
    target = tm.scene_centre_m() if opts.target_m is None else np.asarray(opts.target_m, float)
    dist = tm.typical_distance_m() if opts.distance_m is None else opts.distance_m
    return _Viewer(tm, (sz, sa), dist, target, size, fov, opts.backend)


def _write_view(out: Path, tm: TrainedModel, rv: RenderedView, description: str) -> dict:
    """cube.hdr (spectral models), cir.png, depth/alpha/normal .npy and PNGs; {kind: file}."""
    files = {}
    if rv.cube is not None:
        files["cube"] = str(write_envi(out / "cube.hdr", rv.cube, tm.wavelengths_nm, tm.fwhm_nm,
                                       extra={"description": description}, default_bands=tm.cir_indices,
                                       ignore_value=float("nan")))
    files["cir_png"] = str(plots.save_rgb_png(out / "cir.png", rv.cir))
    atomic.save_npy(out / "depth.npy", rv.depth.astype(np.float32))
    atomic.save_npy(out / "alpha.npy", rv.alpha.astype(np.float32))
    files["depth_png"] = str(plots.save_depth_png(out / "depth.png", rv.depth, rv.alpha))
    if rv.normal is not None:
        atomic.save_npy(out / "normal.npy", rv.normal.astype(np.float32))
        files["normal_png"] = str(plots.save_normal_png(out / "normal.png", rv.normal))
    return files


def _write_sun_visibility(out: Path, vw: _Viewer, c2w: np.ndarray, intr) -> dict:
    """sun_visibility.npy and .png (grey; black where nothing is rendered) of the view under the render's
    sun (:mod:`brfgs.model.shadows`)."""
    vis = sun_visibility_map(vw.tm, camera_from_intrinsics(c2w, intr),
                             vw.tm.sun_visibility(*vw.sun, backend=vw.backend), backend=vw.backend)
    atomic.save_npy(out / "sun_visibility.npy", vis)
    grey = np.repeat(np.nan_to_num(vis, nan=0.0)[..., None], 3, axis=-1)
    return {"sun_visibility_png": str(plots.save_rgb_png(out / "sun_visibility.png", grey))}


def _single_view(out: Path, vw: _Viewer, vz: float, va: float, repeat: int, info: dict) -> str:
    """Render one view ``repeat`` times, write its files and render.json; the summary line."""
    times = []
    for _ in range(repeat):
        c2w, intr, rv = vw.view(vz, va)
        times.append(rv.timings_s)
    sz, sa = vw.sun
    files = _write_view(out, vw.tm, rv, f"brfgs render view {vz:g}/{va:g} sun {sz:g}/{sa:g}")
    files.update(_write_sun_visibility(out, vw, c2w, intr))
    warm = times[1:] if len(times) > 1 else times   # the first call also loads numba's compiled kernels
    med = {k: float(np.median([t[k] for t in warm])) for k in times[0]}
    info.update({"view_zenith_deg": vz, "view_azimuth_deg": va, "c2w": c2w.tolist(),
                 "intrinsics": views.intrinsics_json(intr),
                 "timings_s": {"median": med, "first": times[0], "all": times, "repeat": repeat,
                               "median_over": "calls after the first" if len(times) > 1 else "the only call"},
                 "files": files,
                 "depth": "metres along the optical axis (0 where nothing is rendered)",
                 "normal": "unit world (ENU) normals facing the camera, 0 where nothing is rendered",
                 "sun_visibility": "share of the surface in each pixel that the direct sun reaches under the render's "
                                   "sun, from the model's geometry (1 lit, 0 in shadow, NaN where opacity < 0.1)"})
    atomic.write_json(out / "render.json", info)
    w, h = vw.size
    return (f"rendered {w}x{h}, {len(vw.tm.wavelengths_nm)} bands in {med['total_s'] * 1000:.0f} ms "
            f"({'median of ' + str(len(warm)) + ' warm calls' if repeat > 1 else 'first call'}) -> {out}")


def _path_views(out: Path, vw: _Viewer, opts: RenderOptions, vz: float, va: float, info: dict) -> str:
    """Render an orbit or a sweep: frames/frame_NNN.png, PATH.gif, render.json; the summary line."""
    seq = views.orbit_path(vz, opts.frames, va) if opts.path == "orbit" else views.zenith_sweep_path(va, vz,
                                                                                                     opts.frames)
    (out / "frames").mkdir(exist_ok=True)
    imgs, rows, times = [], [], []
    for k, (z, a) in enumerate(tqdm(seq, desc=opts.path, disable=not opts.progress)):
        _, _, rv = vw.view(z, a)
        p = plots.save_rgb_png(out / "frames" / f"frame_{k:03d}.png", rv.cir)
        imgs.append(Image.open(p).convert("RGB"))
        rows.append({"frame": k, "view_zenith_deg": z, "view_azimuth_deg": a, "file": str(p)})
        times.append(rv.timings_s["total_s"])
    gif = out / f"{opts.path}.gif"
    with atomic.atomic_path(gif) as tmp:
        imgs[0].save(tmp, format="GIF", save_all=True, append_images=imgs[1:], duration=100, loop=0)
    info.update({"path": opts.path, "frames": rows, "timings_s": {"median_total_s": float(np.median(times))},
                 "gif": str(gif)})
    atomic.write_json(out / "render.json", info)
    return f"rendered {len(seq)} frames ({np.median(times) * 1000:.0f} ms each) -> {gif}"


@releases_locks
def render_report(run: str | Path, opts: RenderOptions, out: str | Path | None = None) -> Report:
    """``brfgs render``: render the model of ``run`` (run folder or model file) as ``opts`` asks and
    write the files into ``out`` (default RUN/analysis/render_z<Z>_a<A>[_<path>])."""
    opts.validate()
    out = out if out is not None else opts.out
    vz, va = _check(opts)
    tm = TrainedModel.load(run)
    vw = _viewer(tm, opts)
    if out is None:
        out = run_folder(Path(run)) / "analysis" / (f"render_z{vz:g}_a{va:g}" + (f"_{opts.path}" if opts.path else ""))
    out = prepare_output_dir(Path(out), "render.json", opts.overwrite, tm.scene_root)
    w, h = vw.size
    info = {"model": tm.source, "scene": tm.scene_name, "sun_zenith_deg": vw.sun[0], "sun_azimuth_deg": vw.sun[1],
            "distance_m": vw.distance_m, "target_m": [float(v) for v in vw.target_m], "fov_deg": vw.fov_deg,
            "width": w, "height": h, "n_gaussians": tm.n_gaussians}
    if opts.path is None:
        message = _single_view(out, vw, vz, va, opts.repeat, info)
    else:
        message = _path_views(out, vw, opts, vz, va, info)
    return Report(out, info, message)
