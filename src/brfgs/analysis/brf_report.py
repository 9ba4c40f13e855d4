"""``brfgs brf``: the BRF of a region, written as CSV tables, figures and a JSON summary.

:func:`brf_report` resolves the ROI (:mod:`brfgs.analysis.roi_spec`), samples the model's BRF
along the principal plane and over the view hemisphere (:mod:`brfgs.analysis.brf`), compares it
with the observations of every frame when the training scene is available (and with the truth
of simulated scenes: at the frames, and rendered again by the simulator,
:mod:`brfgs.analysis.truth`), and writes:

    roi.json                          the resolved ROI
    principal_plane.csv / .png        BRF vs signed view zenith per band (Fig. 8)
    principal_plane_observations.csv  the observations nearest the principal plane
    principal_plane_truth.csv         simulator truth along the plane (simulated scenes)
    polar.csv / .png                  BRF over the view hemisphere (Fig. 9)
    polar_truth.csv / .png            model vs simulator truth on a coarse grid (simulated scenes)
    truth_error.csv                   per-band RMSE / bias / relative error against the simulator
    spectra.csv / .png                mean spectra over the test views and the log error (Fig. 7)
    observations.csv                  per frame: reconstructed, observed, truth in the bands
    brf.json                          summary: peaks, errors, settings, files, timings
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from brfgs.data.lock import releases_locks
from brfgs.analysis import brf as B
from brfgs.analysis import plots
from brfgs.analysis.options import BRFOptions, TruthOptions
from brfgs.analysis.output import Report, prepare_output_dir, run_folder, safe_name
from brfgs.analysis.roi import ROI
from brfgs.analysis.roi_spec import ROISpec, parse_roi_spec, resolve_roi
from brfgs.analysis.threads import torch_threads
from brfgs.analysis.truth import brf_error, check_truth_spp, has_simulator_truth, truth_brf
from brfgs.analysis.views import hemisphere_grid, principal_plane_directions
from brfgs.data import read_scene
from brfgs.data.splits import split_rule_of
from brfgs.data.angles import relative_azimuth_deg
from brfgs.data.scene import Scene
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.data import atomic

__all__ = ["TruthOptions", "BRFOptions", "brf_report", "open_model_scene"]


def open_model_scene(tm: TrainedModel, scene_path: Path | None, required: bool) -> Scene | None:
    """The scene of ``scene_path`` or, by default, the model's training scene when it still exists
    (read with the model's downscale, region and split seed); None when there is none and not ``required``."""
    root = scene_path if scene_path is not None else (Path(tm.scene_root) if tm.scene_root else None)
    if root is None or not (root / "transforms.json").is_file():
        if scene_path is not None:
            raise UserError("not a scene folder (no transforms.json)", file=scene_path, field="--scene")
        if required:
            raise UserError("the training scene is needed here; pass --scene", field="--scene")
        return None
    kw = {"roi": tm.scene["roi"]} if tm.scene.get("roi") is not None else {}
    split_seed = int(tm.config.get("split_seed", 0))
    return read_scene(root, downscale=int(tm.scene.get("downscale", 1) or 1), split_seed=split_seed,
                      split_rule=split_rule_of(tm.config),
                      allow_outside_links=bool(tm.config.get("allow_outside_links", False)), **kw)


@dataclass
class _BRFRun:
    """One ``brf`` run: the model, the ROI, the bands, the scene and what the report collects."""

    tm: TrainedModel
    opts: BRFOptions
    out: Path
    bi: list[int]
    scene: Scene | None
    do_truth: bool
    warn: Callable[[str], None]
    sun: tuple[float, float] = (0.0, 0.0)              # (zenith, azimuth) deg of the BRF
    sky: np.ndarray | None = None                      # [B] diffuse fraction of --scene (None: the model's)
    region: ROI | None = None                          # resolved inside the run's thread setting
    summary: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    truth_errors: list = field(default_factory=list)   # rows of truth_error.csv

    @property
    def wl(self) -> np.ndarray:  # [nb] nm of the selected bands
        return self.tm.wavelengths_nm[self.bi]

    def sampling(self) -> dict:
        """Keyword arguments of the model's BRF sampling (brfgs.analysis.brf.roi_brf)."""
        o = self.opts
        return {"size": o.size, "distance_m": o.distance_m, "backend": o.backend, "min_alpha": o.min_alpha,
                "sun_deg": self.sun, "diffuse_fraction": self.sky}

    def cols(self, prefix: str) -> list[str]:
        return [f"{prefix}_{w:.0f}nm" for w in self.wl]

    def add_truth_errors(self, comparison: str, err: dict) -> None:
        self.truth_errors += [[comparison, float(w), err["n_directions"], err["rmse"][f"{w:.0f}"],
                               err["mean_bias"][f"{w:.0f}"], err["mean_relative_error"][f"{w:.0f}"]] for w in self.wl]


def _nan_row(values: np.ndarray | None, bi: list[int]) -> list[float]:
    return [float(v) for v in values[bi]] if values is not None else [float("nan")] * len(bi)


def _principal_plane(r: _BRFRun) -> tuple[np.ndarray, B.ROIBRF]:
    """The model's principal-plane curve: principal_plane.csv and the summary's peaks."""
    o, tm = r.opts, r.tm
    t = time.perf_counter()
    s, pp = B.principal_plane(tm, r.region, r.bi, max_zenith_deg=o.max_zenith_deg, step_deg=o.step_deg,
                              progress=o.progress, **r.sampling())
    r.timings["principal_plane_s"] = time.perf_counter() - t
    peaks = {f"{w:.0f}": B.curve_peak(s, pp.values[:, j]) for j, w in enumerate(r.wl)}
    r.summary["principal_plane"] = {"peak_signed_zenith_deg": peaks, "hotspot_signed_zenith_deg": r.sun[0],
                                    "specular_signed_zenith_deg": -r.sun[0],
                                    "camera": pp.extra, "min_pixels": int(pp.n_pixels.min()),
                                    "directions_without_roi_pixels": int((pp.n_pixels == 0).sum()),
                                    "min_alpha": o.min_alpha}
    if (pp.n_pixels == 0).any():
        r.warn(f"warning: the ROI is not seen (no pixel with opacity >= {o.min_alpha:g} whose surface point "
               f"lies in it) in {int((pp.n_pixels == 0).sum())} of {len(s)} principal-plane directions; "
               "see --min-alpha and the model's opacity")
    rows = [[float(x)] + [float(v) for v in pp.values[k]] + [int(pp.n_pixels[k])] for k, x in enumerate(s)]
    plots.write_csv(r.out / "principal_plane.csv", ["signed_view_zenith_deg"] + r.cols("brf") + ["n_pixels"], rows)
    return s, pp


def _plane_observations(r: _BRFRun, obs: list[B.FrameObservation]) -> list[B.FrameObservation]:
    """The observations nearest the principal plane: principal_plane_observations.csv."""
    near = B.nearest_to_plane(obs, max_offset_deg=r.opts.max_plane_offset_deg)
    plots.write_csv(r.out / "principal_plane_observations.csv",
                    ["frame", "split", "signed_view_zenith_deg", "plane_offset_deg", "n_pixels"]
                    + r.cols("observed") + r.cols("reconstructed") + r.cols("truth"),
                    [[o.name, o.split, o.signed_zenith_deg, o.plane_offset_deg, o.n_pixels]
                     + _nan_row(o.observed, r.bi) + [float(v) for v in o.reconstructed[r.bi]] + _nan_row(o.truth, r.bi)
                     for o in near])
    return near


def _principal_plane_truth(r: _BRFRun, s: np.ndarray, pp: B.ROIBRF) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's truth along the plane (signed zenith [T], values [T, nb]): principal_plane_truth.csv."""
    o, tr = r.opts, r.opts.truth
    t = time.perf_counter()
    n_t = int(round(2 * o.max_zenith_deg / tr.step_deg)) + 1
    truth_s = np.linspace(-o.max_zenith_deg, o.max_zenith_deg, n_t)
    tz, ta = principal_plane_directions(truth_s, r.sun[1])
    tb = truth_brf(r.scene.root, r.region, tz, ta, _truth_bands(r), distance_m=pp.extra["distance_m"],
                   size=tr.size, spp=tr.spp, progress=o.progress)
    r.timings["truth_render_s"] = time.perf_counter() - t
    model_at = np.stack([np.interp(truth_s, s, pp.values[:, j]) for j in range(len(r.bi))], 1)
    err = brf_error(model_at, tb.values, r.wl)
    r.summary["principal_plane"]["vs_truth_render"] = {
        **err, "step_deg": tr.step_deg, "size_px": tr.size, "spp": tr.spp,
        "model": "principal-plane curve interpolated to the truth directions",
        "truth_peak_signed_zenith_deg": {f"{w:.0f}": B.curve_peak(truth_s, tb.values[:, j])
                                         for j, w in enumerate(r.wl)},
        # sun side (+, backscatter / hotspot) and the other (-, forward / specular), view zenith >= 5°
        "mean_abs_error_by_side": {side: {f"{w:.0f}": float(np.nanmean(np.abs(model_at[sel, j] - tb.values[sel, j])))
                                          for j, w in enumerate(r.wl)}
                                   for side, sel in (("backscatter", truth_s >= 5.0), ("forward", truth_s <= -5.0))
                                   if sel.any()}}
    r.add_truth_errors("principal_plane", err)
    plots.write_csv(r.out / "principal_plane_truth.csv",
                    ["signed_view_zenith_deg"] + r.cols("truth") + r.cols("model") + ["n_pixels"],
                    [[float(truth_s[k])] + [float(v) for v in tb.values[k]] + [float(v) for v in model_at[k]]
                     + [int(tb.n_pixels[k])] for k in range(n_t)])
    r.summary["files"]["principal_plane_truth_csv"] = "principal_plane_truth.csv"
    return truth_s, tb.values


def _truth_bands(r: _BRFRun) -> list[int]:
    """Bands of the simulated scene nearest the selected wavelengths."""
    return [r.scene.band_index_nearest(w) for w in r.wl]


def _plot_principal_plane(r: _BRFRun, s: np.ndarray, pp: B.ROIBRF, near: list[B.FrameObservation],
                          truth_curve: tuple[np.ndarray | None, np.ndarray | None]) -> None:
    seen = [o for o in near if o.observed is not None]
    tru = [o for o in near if o.truth is not None]
    sz = r.sun[0]
    plots.plot_principal_plane(r.out / "principal_plane.png", s, pp.values, r.wl, sz,
                               title=f"{r.region.name}: principal plane (sun zenith {sz:.1f}°)",
                               obs_signed_zenith_deg=[o.signed_zenith_deg for o in seen],
                               obs_values=np.array([o.observed[r.bi] for o in seen]).reshape(-1, len(r.bi)),
                               truth_signed_zenith_deg=[o.signed_zenith_deg for o in tru],
                               truth_values=np.array([o.truth[r.bi] for o in tru]).reshape(-1, len(r.bi)),
                               truth_curve_signed_zenith_deg=truth_curve[0], truth_curve_values=truth_curve[1])
    r.summary["files"].update({"principal_plane_png": "principal_plane.png",
                               "principal_plane_csv": "principal_plane.csv",
                               "principal_plane_observations_csv": "principal_plane_observations.csv"})


def _polar(r: _BRFRun) -> tuple[np.ndarray, np.ndarray, np.ndarray, B.ROIBRF]:
    """The model's polar map: polar.csv, polar.png, the summary's argmax per band."""
    o, tm = r.opts, r.tm
    t = time.perf_counter()
    zc, ac, vals, res = B.polar_map(tm, r.region, r.bi, n_azimuth=o.polar_azimuths, n_zenith=o.polar_zeniths,
                                    max_zenith_deg=o.max_zenith_deg, progress=o.progress, **r.sampling())
    r.timings["polar_map_s"] = time.perf_counter() - t
    counts = res.n_pixels.reshape(len(zc), len(ac))
    rows = [[float(z), float(a), float(relative_azimuth_deg(a, r.sun[1]))]
            + [float(v) for v in vals[i, k]] + [int(counts[i, k])] for i, z in enumerate(zc) for k, a in enumerate(ac)]
    plots.write_csv(r.out / "polar.csv", ["view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg"]
                    + r.cols("brf") + ["n_pixels"], rows)
    plots.plot_polar(r.out / "polar.png", zc, ac, vals, r.wl, *r.sun,
                     title=f"{r.region.name}: BRF over the view hemisphere", max_zenith_deg=o.max_zenith_deg)
    flat = vals.reshape(-1, len(r.bi))
    kmax = np.nanargmax(np.where(np.isfinite(flat), flat, -np.inf), axis=0)
    r.summary["polar"] = {"n_azimuth": o.polar_azimuths, "n_zenith": o.polar_zeniths,
                          "max_zenith_deg": o.max_zenith_deg,
                          "argmax": {f"{w:.0f}": {"view_zenith_deg": float(np.repeat(zc, len(ac))[kmax[j]]),
                                                  "view_azimuth_deg": float(np.tile(ac, len(zc))[kmax[j]])}
                                     for j, w in enumerate(r.wl)},
                          "seconds": r.timings["polar_map_s"], "directions": int(flat.shape[0])}
    r.summary["files"].update({"polar_png": "polar.png", "polar_csv": "polar.csv"})
    return zc, ac, vals, res


def _polar_truth_renders(r: _BRFRun, distance_m: float) -> tuple[np.ndarray, np.ndarray, B.ROIBRF, B.ROIBRF]:
    """(truth grid zeniths [Zt], azimuths [At], simulator truth, model) on the coarse truth grid."""
    o, tr = r.opts, r.opts.truth
    t = time.perf_counter()
    tzc, tac = hemisphere_grid(tr.polar_azimuths, tr.polar_zeniths, o.max_zenith_deg)
    TZ, TA = np.meshgrid(tzc, tac, indexing="ij")
    tpb = truth_brf(r.scene.root, r.region, TZ.ravel(), TA.ravel(), _truth_bands(r), distance_m=distance_m,
                    size=tr.polar_size, spp=tr.spp, progress=o.progress)
    r.timings["truth_polar_render_s"] = time.perf_counter() - t
    t = time.perf_counter()
    mtb = B.roi_brf(r.tm, r.region, TZ.ravel(), TA.ravel(), r.bi, **r.sampling())
    r.timings["model_on_truth_grid_s"] = time.perf_counter() - t
    return tzc, tac, tpb, mtb


def _polar_truth(r: _BRFRun, model: plots.PolarGrid, distance_m: float) -> None:
    """Model vs simulator truth on a coarse polar grid: polar_truth.csv / .png and the summary's errors."""
    tr = r.opts.truth
    tzc, tac, tpb, mtb = _polar_truth_renders(r, distance_m)
    TZ, TA = np.meshgrid(tzc, tac, indexing="ij")
    shape = (len(tzc), len(tac), len(r.bi))
    err = brf_error(mtb.values, tpb.values, r.wl)
    plots.write_csv(r.out / "polar_truth.csv",
                    ["view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg"] + r.cols("truth") + r.cols("model")
                    + ["n_pixels_truth", "n_pixels_model"],
                    [[float(TZ.flat[k]), float(TA.flat[k]), float(relative_azimuth_deg(TA.flat[k], r.sun[1]))]
                     + [float(v) for v in tpb.values[k]] + [float(v) for v in mtb.values[k]]
                     + [int(tpb.n_pixels[k]), int(mtb.n_pixels[k])] for k in range(TZ.size)])
    plots.plot_polar_truth(r.out / "polar_truth.png", model, plots.PolarGrid(tzc, tac, tpb.values.reshape(shape)),
                           mtb.values.reshape(shape), r.wl, *r.sun,
                           max_zenith_deg=r.opts.max_zenith_deg,
                           title=f"{r.region.name}: BRF-GS vs simulator truth over the view hemisphere")
    tflat = np.where(np.isfinite(tpb.values), tpb.values, -np.inf)
    tk = np.argmax(tflat, axis=0)
    r.summary["polar"]["vs_truth_render"] = {
        **err, "n_azimuth": tr.polar_azimuths, "n_zenith": tr.polar_zeniths, "size_px": tr.polar_size, "spp": tr.spp,
        "model": "the model rendered for the same directions as the truth",
        "truth_min_pixels": int(tpb.n_pixels.min()),
        "truth_argmax": {f"{w:.0f}": ({"view_zenith_deg": float(TZ.flat[tk[j]]),
                                       "view_azimuth_deg": float(TA.flat[tk[j]])}
                                      if np.isfinite(tflat[tk[j], j]) else None) for j, w in enumerate(r.wl)},
        "seconds": r.timings["truth_polar_render_s"]}
    r.summary["files"].update({"polar_truth_png": "polar_truth.png", "polar_truth_csv": "polar_truth.csv"})
    r.add_truth_errors("polar", err)


def _write_truth_errors(r: _BRFRun) -> None:
    if r.truth_errors:
        plots.write_csv(r.out / "truth_error.csv", ["comparison", "wavelength_nm", "n_directions", "rmse",
                                                    "mean_bias_model_minus_truth", "mean_relative_error"],
                        [[e[0], e[1], e[2]] + [float("nan") if v is None else v for v in e[3:]]
                         for e in r.truth_errors])
        r.summary["files"]["truth_error_csv"] = "truth_error.csv"


def _sample_brf(r: _BRFRun) -> list[B.FrameObservation]:
    """Principal plane, observations, polar maps and their truth comparisons; the observations."""
    s, pp = _principal_plane(r)
    obs = []
    if r.scene is not None:
        t = time.perf_counter()
        obs = B.frame_observations(r.tm, r.region, r.scene, backend=r.opts.backend, progress=r.opts.progress,
                                   min_alpha=r.opts.min_alpha, sun_deg=r.sun, diffuse_fraction=r.sky)
        r.timings["observations_s"] = time.perf_counter() - t
    near = _plane_observations(r, obs)
    truth_curve = _principal_plane_truth(r, s, pp) if r.do_truth else (None, None)
    _plot_principal_plane(r, s, pp, near, truth_curve)
    if r.opts.polar:
        zc, ac, vals, res = _polar(r)
        if r.do_truth:
            _polar_truth(r, plots.PolarGrid(zc, ac, vals), res.extra["distance_m"])
    _write_truth_errors(r)
    return obs


def _spectra(r: _BRFRun, obs: list[B.FrameObservation]) -> None:
    """Mean spectra over the test views (weighted by ROI pixels) and the log error: spectra.csv / .png."""
    test = [o for o in obs if o.split == "test" and o.observed is not None]
    if not test:
        return
    wl = r.tm.wavelengths_nm
    w = np.array([o.n_pixels for o in test], float)
    rec = np.average(np.array([o.reconstructed for o in test]), axis=0, weights=w)
    ob = np.average(np.array([o.observed for o in test]), axis=0, weights=w)
    tr_list = [o for o in test if o.truth is not None]
    tr = (np.average(np.array([o.truth for o in tr_list]), axis=0, weights=[o.truth_n_pixels for o in tr_list])
          if tr_list else None)
    le = B.log_error(rec, ob)
    plots.write_csv(r.out / "spectra.csv", ["wavelength_nm", "reconstructed", "observed", "log_error"]
                    + (["truth"] if tr is not None else []),
                    [[float(wl[b]), float(rec[b]), float(ob[b]), float(le[b])]
                     + ([float(tr[b])] if tr is not None else []) for b in range(len(rec))])
    plots.plot_spectra(r.out / "spectra.png", wl, rec, ob, le, truth=tr,
                       title=f"{r.region.name}: mean over {len(test)} test views")
    r.summary["spectra"] = {"n_test_views": len(test), "mean_abs_log_error": float(np.mean(np.abs(le))),
                            "rmse_reconstructed_vs_observed": float(np.sqrt(np.mean((rec - ob) ** 2)))}
    r.summary["files"].update({"spectra_png": "spectra.png", "spectra_csv": "spectra.csv"})


def _band_error(r: _BRFRun, obs: list[B.FrameObservation], key: str) -> dict | None:
    """BRF error per band of the reconstructed means against ``key`` ("observed" or "truth") over all frames."""
    pairs = [(o.reconstructed[r.bi], getattr(o, key)[r.bi]) for o in obs
             if o.reconstructed is not None and getattr(o, key) is not None]
    if not pairs:
        return None
    m = np.array([p[0] for p in pairs])
    t = np.array([p[1] for p in pairs])
    return {"n_frames": len(pairs),
            "rmse": {f"{w:.0f}": float(np.sqrt(np.mean((m[:, j] - t[:, j]) ** 2))) for j, w in enumerate(r.wl)},
            "mean_relative_error": {f"{w:.0f}": float(np.mean(np.abs(m[:, j] - t[:, j])
                                                              / np.maximum(np.abs(t[:, j]), 1e-6)))
                                    for j, w in enumerate(r.wl)}}


def _observations(r: _BRFRun, obs: list[B.FrameObservation]) -> None:
    """Per frame statistics (observations.csv) and the BRF error against observations and truth."""
    if not obs:
        r.summary["observations"] = "scene not available: no observations/truth (pass --scene)"
        return
    nan = np.full(len(r.tm.wavelengths_nm), np.nan)
    rows = [[o.name, o.split, o.view_zenith_deg, o.view_azimuth_deg, o.relative_azimuth_deg, o.signed_zenith_deg,
             o.n_pixels] + [float(v) for v in (o.reconstructed if o.reconstructed is not None else nan)[r.bi]]
            + _nan_row(o.observed, r.bi) + _nan_row(o.truth, r.bi) for o in obs]
    plots.write_csv(r.out / "observations.csv",
                    ["frame", "split", "view_zenith_deg", "view_azimuth_deg", "relative_azimuth_deg",
                     "signed_view_zenith_deg", "n_pixels"] + r.cols("reconstructed") + r.cols("observed")
                    + r.cols("truth"), rows)
    r.summary["files"]["observations_csv"] = "observations.csv"
    r.summary["brf_error"] = {"vs_observed": _band_error(r, obs, "observed"), "vs_truth": _band_error(r, obs, "truth")}


def _start(run: str | Path, opts: BRFOptions, out: str | Path | None,
           warn: Callable[[str], None]) -> tuple[ROISpec, _BRFRun]:
    """Parse the ROI and bands, load the model and its scene, prepare the output folder."""
    spec = parse_roi_spec(opts.roi, opts.roi_name)
    tm = TrainedModel.load(run)
    if not tm.spectral:
        raise UserError("this model has no spectra (CIR variant); BRF analysis needs a spectral model", file=run)
    bi = tm.band_indices(opts.bands_nm)
    sc = open_model_scene(tm, opts.scene, required=(spec.kind == "material"))
    sun = _brf_sun(tm, sc if opts.scene is not None else None, opts)
    do_truth = sc is not None and opts.truth.render and has_simulator_truth(sc.root)
    if do_truth and max(abs(sun[0] - sc.sun_zenith_deg), abs(relative_azimuth_deg(sun[1], sc.sun_azimuth_deg))) > 0.01:
        warn(f"note: the simulator's truth is rendered under the scene's own sun ({sc.sun_zenith_deg:.1f}°, "
             f"{sc.sun_azimuth_deg:.1f}°), not this BRF's: no truth comparison (pass --scene with that sun)")
        do_truth = False
    if do_truth:
        check_truth_spp(sc.root, opts.truth.spp, field="--truth-spp")
    out = Path(out) if out is not None else run_folder(Path(run)) / "analysis" / f"brf_{safe_name(spec.name)}"
    prepare_output_dir(out, "brf.json", opts.overwrite, tm.scene_root)
    sky = sc.sky_at(sun[0]) if opts.scene is not None else None    # another flight's sky at the BRF's sun
    return spec, _BRFRun(tm, opts, out, bi, sc, do_truth, warn, sun, sky)


def _brf_sun(tm: TrainedModel, scene: Scene | None, opts: BRFOptions) -> tuple[float, float]:
    """(zenith, azimuth) deg of the BRF: ``--sun-zenith``/``--sun-azimuth`` where given, else the sun of
    the ``--scene`` (another flight's), else the model's training sun."""
    z0, a0 = (scene.sun_zenith_deg, scene.sun_azimuth_deg) if scene is not None else (tm.sun_zenith_deg,
                                                                                       tm.sun_azimuth_deg)
    z = z0 if opts.sun_zenith_deg is None else float(opts.sun_zenith_deg)
    a = a0 if opts.sun_azimuth_deg is None else float(opts.sun_azimuth_deg)
    return float(z), float(a) % 360.0


def _stderr(message: str) -> None:
    print(message, file=sys.stderr)


@releases_locks
def brf_report(run: str | Path, opts: BRFOptions, out: str | Path | None = None,
               warn: Callable[[str], None] = _stderr) -> Report:
    """``brfgs brf``: the BRF of the ROI ``opts.roi`` of the model of ``run``, written into ``out``
    (default RUN/analysis/brf_<roi name>; the files are listed in the module docstring).
    ``warn`` receives warnings (an ROI not seen from some directions; default: standard error)."""
    opts.validate()
    spec, r = _start(run, opts, out if out is not None else opts.out, warn)
    t0 = time.perf_counter()
    with torch_threads(opts.threads or None):
        r.region = resolve_roi(spec, r.tm, r.scene, opts.backend)
        atomic.write_json(r.out / "roi.json", r.region.describe())
        r.timings["roi_s"] = time.perf_counter() - t0
        r.summary = {"model": r.tm.source, "scene": r.tm.scene_name, "roi": r.region.describe(),
                     "bands_nm": [float(w) for w in r.wl], "sun_zenith_deg": r.sun[0],
                     "sun_azimuth_deg": r.sun[1], "files": {}}
        obs = _sample_brf(r)
    _spectra(r, obs)
    _observations(r, obs)
    r.timings["total_s"] = time.perf_counter() - t0
    r.summary["timings_s"] = r.timings
    atomic.write_json(r.out / "brf.json", r.summary)
    peaks = r.summary["principal_plane"]["peak_signed_zenith_deg"]
    pk = ", ".join(f"{k} nm: {v:+.1f}°" for k, v in peaks.items())
    sz = r.sun[0]
    return Report(r.out, r.summary, f"{spec.name}: principal-plane peaks {pk} (hotspot +{sz:.1f}°, "
                                    f"specular -{sz:.1f}°) -> {r.out}")
