"""The viewer page's result panels: a clicked ROI (spectrum, principal plane, polar map, saving)
and the camera comparison (render | observation | error of a training or test camera).

Plots are uPlot panels with a numeric x scale (uPlot's default x scale is time) and axes
labelled with their units. The ROI's directional BRF runs in its own thread one direction at a
time, after any frame a browser is waiting for, and says how far it is; a newer click
supersedes it.
"""

from __future__ import annotations

import contextlib
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np
import viser
import viser.uplot

from brfgs.analysis.brf import training_footprint_m
from brfgs.analysis.brf_report import open_model_scene
from brfgs.data.cameras import Intrinsics
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.viewer.cameras import viser_from_c2w
from brfgs.viewer.checks import ROI_RADIUS_M, roi_name
from brfgs.viewer.frames import SURFACE_MIN_ALPHA, frame_comparison
from brfgs.viewer.options import ViewerOptions
from brfgs.viewer.roi import (RoiResult, disc_roi, polar_image, roi_directional, roi_spectrum,
                              save_roi_folder, surface_hit)

__all__ = ["RoiPanel", "CameraPanel", "add_plot", "finite_rows", "PLOT_AXES"]

_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e")
PLOT_AXES = {"spectrum": ("wavelength (nm)", "BRF"), "pp": ("view zenith (deg), + = sun side", "BRF")}


class Superseded(Exception):
    """A newer click replaced the ROI being computed."""


def finite_rows(data: tuple) -> tuple[np.ndarray, ...]:
    """``data`` (arrays [n]) as float64 without the positions where any array is not finite (uPlot
    draws nothing there; a missing direction is not a zero)."""
    arrs = tuple(np.asarray(d, np.float64) for d in data)
    ok = np.logical_and.reduce([np.isfinite(a) for a in arrs])
    return tuple(a[ok] for a in arrs)


def add_plot(gui, data: tuple, x_label: str, y_label: str, series: tuple[str, ...], title: str):
    """A uPlot panel of ``data`` (x [n], then one array [n] per series) with a linear x scale and the
    axes labelled ``x_label`` / ``y_label``; NaN drawn as gaps."""
    data = finite_rows(data)
    spec = (viser.uplot.Series(label=x_label),) + tuple(
        viser.uplot.Series(label=n, stroke=_COLOURS[i % len(_COLOURS)], width=2, scale="y", spanGaps=False)
        for i, n in enumerate(series))
    return gui.add_uplot(data, spec, title=title, aspect=1.4,
                         scales={"x": viser.uplot.Scale(time=False, auto=True), "y": viser.uplot.Scale(auto=True)},
                         axes=(viser.uplot.Axis(scale="x", label=x_label), viser.uplot.Axis(scale="y", label=y_label)))


class RoiPanel:
    """The "ROI" folder: a click → hit point → disc; spectrum, then principal plane and polar map."""

    def __init__(self, tm: TrainedModel, server: viser.ViserServer, opts: ViewerOptions,
                 lock_for_render: Callable, wait_for_frames: Callable[[], None]):
        self.tm, self.server, self.opts = tm, server, opts
        self._render_lock, self._wait_for_frames = lock_for_render, wait_for_frames
        self.roi: RoiResult | None = None
        self.plots: dict[str, object] = {}
        self._seq = 0
        self._seq_lock, self._save_lock = threading.Lock(), threading.Lock()
        gui = server.gui
        with gui.add_folder("ROI (click the surface)") as self.folder:
            self.pick_box = gui.add_checkbox("Click picks an ROI", True)
            self.radius = gui.add_slider("ROI radius (m)", *ROI_RADIUS_M, 0.1,
                                         float(np.clip(5.0 * training_footprint_m(tm), *ROI_RADIUS_M)))
            self.text = gui.add_markdown("Click on the surface to pick a region.")
            self.name = gui.add_text("ROI name", "", hint="Folder name of the saved ROI (default roi_NN).")
            save = gui.add_button("Save ROI (CSV + GeoJSON)")
        save.on_click(lambda e: self.save(e.client))

    def pick(self, c2w: np.ndarray, intr: Intrinsics, x: float, y: float, radius_m: float,
             sun: tuple[float, float]) -> threading.Thread:
        """Start the analysis of a click at (x, y) ∈ [0, 1]² of the view (c2w, intr) (a thread)."""
        with self._seq_lock:
            self._seq += 1
            seq = self._seq
        t = threading.Thread(target=self._analyse_safely, args=(seq, c2w, intr, x, y, radius_m, sun), daemon=True)
        t.start()
        return t

    def _current(self, seq: int) -> None:
        if seq != self._seq:
            raise Superseded

    def _analyse_safely(self, seq: int, *args) -> None:
        try:
            self._analyse(seq, *args)
        except Superseded:
            return
        except UserError as exc:
            self.text.content = f"⚠ {exc}"
        except Exception as exc:  # a bug: keep the page alive, show where to look
            traceback.print_exc()
            self.text.content = f"⚠ the ROI analysis failed ({type(exc).__name__}); details in the terminal"

    def _analyse(self, seq: int, c2w, intr, x, y, radius_m, sun) -> None:
        tm, o = self.tm, self.opts
        t0 = time.perf_counter()
        self._wait_for_frames()
        with self._render_lock():
            p = surface_hit(tm, c2w, intr, x, y, backend=o.backend)
        self._current(seq)
        if p is None:
            self.text.content = (f"Nothing was hit there (accumulated opacity below {SURFACE_MIN_ALPHA:g}); "
                                 "click on the surface.")
            return
        roi = disc_roi(p, radius_m)
        self.server.scene.add_icosphere("/roi", radius=radius_m, position=tuple(p), color=(255, 0, 255), opacity=0.6)
        with self._render_lock():
            res = roi_spectrum(tm, roi, c2w, intr, sun, backend=o.backend)
        self._current(seq)
        self.roi = res
        head = (f"ROI at E {p[0]:.2f} m, N {p[1]:.2f} m, h {p[2]:.2f} m, radius {roi.radius_m:.2f} m: "
                f"{res.n_pixels} px in this view (spectrum in {time.perf_counter() - t0:.1f} s).")
        self.text.content = head + " Computing the BRF…"
        self._plot("spectrum", (res.wavelengths_nm, res.spectrum), ("BRF",), "ROI spectrum (this view)")

        @contextlib.contextmanager
        def each(done: int, total: int):  # frames first, then one direction under the render lock
            self._current(seq)
            self._wait_for_frames()
            if done % 8 == 0:
                self.text.content = f"{head} Computing the BRF: {done}/{total} directions…"
            with self._render_lock():
                yield

        def principal_plane_done(r: RoiResult) -> None:
            self._current(seq)
            self._plot("pp", (r.pp_signed_zenith_deg,) + tuple(r.pp_values.T),
                       tuple(f"{w:.0f} nm" for w in r.band_nm), "Principal-plane BRF")

        roi_directional(tm, res, step_deg=o.roi_step_deg, polar_azimuths=o.polar_azimuths,
                        polar_zeniths=o.polar_zeniths, backend=o.backend, each=each,
                        principal_plane_done=principal_plane_done)
        self._current(seq)
        self._polar(res)
        self.text.content = f"{head} BRF ready ({time.perf_counter() - t0:.1f} s)."

    def _plot(self, key: str, data: tuple, series: tuple[str, ...], title: str) -> None:
        if key in self.plots:
            self.plots[key].data = finite_rows(data)
            return
        with self.folder:
            self.plots[key] = add_plot(self.server.gui, data, *PLOT_AXES[key], series, title)

    def _polar(self, res: RoiResult) -> None:
        v = res.polar_values[..., -1]
        img = polar_image(res.polar_zenith_deg, res.polar_azimuth_deg, v)
        ok = v[np.isfinite(v)]
        rng = f"{np.percentile(ok, 2):.3f} (dark) to {np.percentile(ok, 98):.3f} (yellow)" if ok.size else "no data"
        label = (f"Polar BRF at {res.band_nm[-1]:.0f} nm: {rng}; north up, view zenith 0-75 deg from the centre "
                 "outwards")
        if "polar" in self.plots:
            self.plots["polar"].remove()
        with self.folder:
            self.plots["polar"] = self.server.gui.add_image(img, label=label)

    def save(self, client) -> Path | None:
        """Save the current ROI into ``--out``/NAME (a new folder; never an existing one)."""
        if self.roi is None:
            client.add_notification("No ROI yet", "Click on the surface first.", auto_close_seconds=4.0)
            return None
        try:
            name = roi_name(self.name.value) if str(self.name.value).strip() else None
            with self._save_lock:
                folder = save_roi_folder(self.roi, Path(self.opts.out_dir or "viewer_rois"), name)
        except UserError as exc:
            client.add_notification("ROI not saved", str(exc), auto_close_seconds=8.0, color="red")
            return None
        client.add_notification("ROI saved", f"{folder}", auto_close_seconds=6.0)
        return folder


class CameraPanel:
    """The "Cameras" folder: go to a training or test camera (the list, or shift-click its frustum)
    and show the model's render | the observation | their error."""

    def __init__(self, tm: TrainedModel, server: viser.ViserServer, opts: ViewerOptions, lock_for_render: Callable):
        self.tm, self.server, self.opts, self._render_lock = tm, server, opts, lock_for_render
        self.names = tuple(str(f["name"]) for f in tm.frames)
        self._scene = None
        self.image = None
        self.folder = server.gui.add_folder("Cameras", expand_by_default=False)
        with self.folder:
            self.choice = server.gui.add_dropdown("Camera", self.names or ("(none)",),
                                                  initial_value=self.names[0] if self.names else "(none)")
            go = server.gui.add_button("Go to this camera", disabled=not self.names)
            server.gui.add_markdown("Or shift-click a camera's frustum. Blue: training, orange: test.")
        go.on_click(lambda e: self.go_to_named(e.client, self.choice.value))

    def go_to_named(self, client, name) -> None:
        if client is None:
            return
        if name not in self.names:
            client.add_notification("No such camera", f"{str(name)[:60]!r} is not a camera of this model",
                                    auto_close_seconds=6.0, color="red")
            return
        self.go_to(client, self.names.index(name))

    def _observed(self, i: int) -> np.ndarray | None:
        """The observed cube of frame ``i`` from the training scene, when it can still be read."""
        try:
            if self._scene is None:
                self._scene = open_model_scene(self.tm, None, required=False) or False
            if not self._scene:
                return None
            names = [f.name for f in self._scene.frames]
            name = self.tm.frames[i]["name"]
            return self._scene.load_image(names.index(name)) if name in names else None
        except UserError:
            return None

    def go_to(self, client, i: int) -> None:
        """Move ``client``'s camera to frame ``i`` and show render | observation | error."""
        fr = self.tm.frames[i]
        pos, wxyz = viser_from_c2w(np.asarray(fr["c2w"], float))
        with client.atomic():
            client.camera.wxyz, client.camera.position = wxyz, pos
        with self._render_lock():
            rgb, obs, err = frame_comparison(self.tm, i, self._observed(i), backend=self.opts.backend)
        blank = np.full_like(rgb, 255)
        panel = np.concatenate([rgb, blank[:, :4], obs if obs is not None else blank, blank[:, :4],
                                err if err is not None else blank], axis=1)  # [H, 3W+8, 3]
        label = f"{fr['name']} ({fr.get('split', '?')}): render | observation | error"
        if obs is None:
            label += " (scene not found: no observation)"
        if self.image is not None:
            self.image.remove()
        with self.folder:
            self.image = self.server.gui.add_image(panel, label=label)
