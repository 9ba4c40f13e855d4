"""The viser page of ``brfgs view RUN``: live renders, display modes, sun sliders, click-ROIs with
plots, and the training and test cameras.

Rendering stays in brfgs (:func:`brfgs.viewer.frames.render_frame`, the one render path); viser
only shows the image as the scene background and sends the browser's camera, clicks and widget
values. Each browser gets a render thread: while its camera moves frames are rendered at a
reduced resolution, once it has stopped for ``settle_s`` the frame is rendered at full resolution.
"""

from __future__ import annotations

import contextlib
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
import viser
import viser.uplot

from brfgs.analysis.brf import training_footprint_m
from brfgs.analysis.brf_report import open_model_scene
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.viewer.options import ViewerOptions
from brfgs.viewer.cameras import c2w_from_viser, fov_from_intrinsics, intrinsics_from_fov, viser_from_c2w
from brfgs.viewer.formula import NDVI
from brfgs.viewer.frames import FrameResult, frame_comparison, parse_mode, render_frame
from brfgs.viewer.roi import RoiResult, disc_roi, hit_point, polar_image, roi_directional, roi_spectrum, save_roi

__all__ = ["ViewerOptions", "Viewer"]


SHADOW_NOTE = ("**Shadows are baked into the model.** The sun sliders re-evaluate the kernels (iso, vol, geo, "
               "spec) for the new sun; cast shadows stay where they were at acquisition.")
DISPLAY_CHOICES = ("cir", "truecolor", "band", "index", "depth", "normals", "alpha",
                   "kernel:iso", "kernel:vol", "kernel:geo", "kernel:spec")


def _serial_lock(lock: threading.Lock):
    """``lock`` when numba's threading layer cannot run parallel kernels from two threads at once
    (workqueue, or not known yet), else no lock (omp and tbb can)."""
    try:
        layer = numba.threading_layer()
    except ValueError:
        layer = "unknown"
    return lock if layer not in ("omp", "tbb") else contextlib.nullcontext()


@dataclass
class _ClientState:
    """One browser: its latest full frame (for clicks), render thread signals, its ROI."""

    client: object
    dirty: threading.Event = field(default_factory=threading.Event)
    moved_at: float = 0.0
    need_full: bool = True
    last: FrameResult | None = None
    alive: bool = True


class Viewer:
    """The page and its callbacks for one model (``server`` is a running :class:`viser.ViserServer`)."""

    def __init__(self, tm: TrainedModel, server: viser.ViserServer, opts: ViewerOptions):
        self.tm, self.server, self.opts = tm, server, opts
        self.clients: dict[int, _ClientState] = {}
        self.lock = threading.Lock()
        self.render_lock = threading.Lock()
        self.roi: RoiResult | None = None
        self.n_saved = 0
        self._plots: dict[str, object] = {}
        self._scene = None
        server.scene.set_up_direction("+z")
        self._build_gui()
        self._add_frustums()
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)
        server.scene.on_click()(self._on_click)

    # ------------------------------------------------------------------ GUI

    def _build_gui(self) -> None:
        gui, tm = self.server.gui, self.tm
        with gui.add_folder("Display"):
            self.mode = gui.add_dropdown("Mode", DISPLAY_CHOICES, initial_value="cir")
            self.band = gui.add_number("Band (nm)", 860.0, min=float(tm.wavelengths_nm.min()),
                                       max=float(tm.wavelengths_nm.max()), step=1.0)
            self.formula = gui.add_text("Index formula", NDVI)
            self.status = gui.add_markdown("")
        with gui.add_folder("Sun"):
            self.sun_z = gui.add_slider("Sun zenith (deg)", 0.0, 85.0, 0.5, float(tm.sun_zenith_deg))
            self.sun_a = gui.add_slider("Sun azimuth (deg)", 0.0, 360.0, 1.0, float(tm.sun_azimuth_deg) % 360.0)
            reset = gui.add_button("Reset to the acquisition's sun")
            gui.add_markdown(SHADOW_NOTE)
        with gui.add_folder("ROI (click the surface)"):
            self.pick = gui.add_checkbox("Click picks an ROI", True)
            self.radius = gui.add_slider("ROI radius (m)", 0.1, 50.0, 0.1,
                                         float(np.clip(5.0 * training_footprint_m(tm), 0.1, 50.0)))
            self.roi_text = gui.add_markdown("Click on the surface to pick a region.")
            save = gui.add_button("Save ROI (CSV + GeoJSON)")
        self.compare_folder = gui.add_folder("Camera comparison")
        for h in (self.mode, self.band, self.formula, self.sun_z, self.sun_a):
            h.on_update(lambda _e: self.redraw_all())
        reset.on_click(lambda _e: self.reset_sun())
        save.on_click(lambda e: self._save(e.client))

    def mode_text(self) -> str:
        """The display mode string of the widgets (band:<nm>, index:<formula> or the choice)."""
        m = self.mode.value
        if m == "band":
            return f"band:{float(self.band.value):g}"
        if m == "index":
            return f"index:{self.formula.value}"
        return m

    def sun(self) -> tuple[float, float]:
        return float(self.sun_z.value), float(self.sun_a.value)

    def reset_sun(self) -> None:
        """Sliders back to the acquisition's sun (this redraws)."""
        self.sun_z.value = float(self.tm.sun_zenith_deg)
        self.sun_a.value = float(self.tm.sun_azimuth_deg) % 360.0

    # ------------------------------------------------------------------ clients and rendering

    def _connect(self, client) -> None:
        st = _ClientState(client)
        with self.lock:
            self.clients[client.client_id] = st
        fr = self.tm.frames[0] if self.tm.frames else None
        if fr is not None:
            pos, wxyz = viser_from_c2w(np.asarray(fr["c2w"], float))
            with client.atomic():
                client.camera.position, client.camera.wxyz = pos, wxyz
        client.camera.on_update(lambda _cam: self._moved(st))
        threading.Thread(target=self._render_loop, args=(st,), daemon=True).start()
        st.dirty.set()

    def _disconnect(self, client) -> None:
        with self.lock:
            st = self.clients.pop(client.client_id, None)
        if st is not None:
            st.alive = False
            st.dirty.set()

    def _moved(self, st: _ClientState) -> None:
        st.moved_at = time.perf_counter()
        st.need_full = True
        st.dirty.set()

    def redraw_all(self) -> None:
        with self.lock:
            states = list(self.clients.values())
        for st in states:
            st.need_full = True
            st.dirty.set()

    def _render_loop(self, st: _ClientState) -> None:
        """Per browser: a reduced frame on each camera change, a full frame once the camera rests."""
        while st.alive:
            st.dirty.wait(timeout=self.opts.settle_s)
            if not st.alive:
                return
            moving = time.perf_counter() - st.moved_at < self.opts.settle_s
            if st.dirty.is_set():
                st.dirty.clear()
                self._draw(st, self.opts.moving_height_px if moving else self.opts.height_px)
                st.need_full = moving
            elif st.need_full and not moving:
                st.need_full = False
                self._draw(st, self.opts.height_px)

    def _draw(self, st: _ClientState, height_px: int) -> None:
        cam = st.client.camera
        c2w = c2w_from_viser(np.asarray(cam.position), np.asarray(cam.wxyz))
        intr = intrinsics_from_fov(float(cam.fov), float(cam.aspect), height_px)
        try:
            with _serial_lock(self.render_lock):
                res = render_frame(self.tm, c2w, intr, parse_mode(self.mode_text()), sun_zenith_deg=self.sun()[0],
                                   sun_azimuth_deg=self.sun()[1], backend=self.opts.backend)
        except UserError as exc:
            self.status.content = f"⚠ {exc}"
            return
        except Exception:  # a bug: keep the page alive, show where to look
            traceback.print_exc()
            self.status.content = "⚠ the frame failed (traceback in the terminal)"
            return
        st.client.scene.set_background_image(res.rgb, format="jpeg", jpeg_quality=90)
        if height_px == self.opts.height_px:
            st.last = res
        self.status.content = f"{res.rgb.shape[1]}×{res.rgb.shape[0]} px in {1000 * res.seconds:.0f} ms"

    # ------------------------------------------------------------------ ROI

    def _on_click(self, event) -> None:
        st = self.clients.get(event.client_id)
        if not self.pick.value or st is None or st.last is None or event.screen_pos is None:
            return
        fr = st.last
        x, y = event.screen_pos  # normalised, (0, 0) top left
        p = hit_point(fr.view.depth, fr.c2w, fr.intr, x * fr.intr.w, y * fr.intr.h, fr.view.alpha)
        if p is None:
            self.roi_text.content = "Nothing was hit there; click on the surface."
            return
        threading.Thread(target=self._analyse_safely, args=(p, fr), daemon=True).start()

    def _analyse_safely(self, p: np.ndarray, fr: FrameResult) -> None:
        try:
            with _serial_lock(self.render_lock):
                self._analyse(p, fr)
        except UserError as exc:
            self.roi_text.content = f"⚠ {exc}"
        except Exception:  # a bug: keep the page alive, show where to look
            traceback.print_exc()
            self.roi_text.content = "⚠ the ROI analysis failed (traceback in the terminal)"

    def _analyse(self, p: np.ndarray, fr: FrameResult) -> None:
        """Spectrum at once, then the principal plane and polar map (slower) into the page."""
        tm, o = self.tm, self.opts
        roi = disc_roi(p, float(self.radius.value))
        self.server.scene.add_icosphere("/roi", radius=float(self.radius.value), position=tuple(p),
                                        color=(255, 0, 255), opacity=0.6)
        res = roi_spectrum(tm, roi, fr.c2w, fr.intr, self.sun(), backend=o.backend)
        self.roi = res
        self.roi_text.content = (f"ROI at E {p[0]:.2f} m, N {p[1]:.2f} m, h {p[2]:.2f} m, radius "
                                 f"{roi.radius_m:.2f} m: {res.n_pixels} px in this view. Computing the BRF…")
        self._plot("spectrum", (res.wavelengths_nm, res.spectrum), ("wavelength (nm)", "reflectance"),
                   "ROI spectrum (this view)")
        roi_directional(tm, res, step_deg=o.roi_step_deg, polar_azimuths=o.polar_azimuths,
                        polar_zeniths=o.polar_zeniths, backend=o.backend)
        cols = tuple(res.pp_values[:, k] for k in range(res.pp_values.shape[1]))
        self._plot("pp", (res.pp_signed_zenith_deg,) + cols,
                   ("signed view zenith (deg)",) + tuple(f"{w:.0f} nm" for w in res.band_nm),
                   "Principal-plane BRF (+ = sun side)")
        img = polar_image(res.polar_zenith_deg, res.polar_azimuth_deg, res.polar_values[..., -1])
        label = f"Polar BRF {res.band_nm[-1]:.0f} nm (north up)"
        if "polar" in self._plots:
            self._plots["polar"].image = img
        else:
            self._plots["polar"] = self.server.gui.add_image(img, label=label)
        self.roi_text.content = self.roi_text.content.replace(" Computing the BRF…", " BRF ready.")

    def _plot(self, key: str, data: tuple, names: tuple, title: str) -> None:
        """A uPlot panel (created on first use, updated after)."""
        data = tuple(np.nan_to_num(np.asarray(d, np.float64), nan=0.0) for d in data)
        if key in self._plots:
            self._plots[key].data = data
            return
        colours = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e")
        series = (viser.uplot.Series(label=names[0]),) + tuple(
            viser.uplot.Series(label=n, stroke=colours[i % len(colours)], width=2) for i, n in enumerate(names[1:]))
        self._plots[key] = self.server.gui.add_uplot(data, series, title=title, aspect=1.4)

    def _save(self, client) -> None:
        if self.roi is None:
            client.add_notification("No ROI yet", "Click on the surface first.", auto_close_seconds=4.0)
            return
        self.n_saved += 1
        out = Path(self.opts.out_dir or "viewer_rois") / f"roi_{self.n_saved:02d}"
        paths = save_roi(self.roi, out)
        client.add_notification("ROI saved", f"{len(paths)} files in {out}", auto_close_seconds=6.0)

    # ------------------------------------------------------------------ cameras

    def _add_frustums(self) -> None:
        tm = self.tm
        fov, aspect = fov_from_intrinsics(tm.intrinsics)
        scale = 0.08 * tm.typical_distance_m() if tm.frames else 1.0
        for i, fr in enumerate(tm.frames):
            pos, wxyz = viser_from_c2w(np.asarray(fr["c2w"], float))
            colour = (40, 90, 220) if fr.get("split") == "train" else (230, 120, 20)
            h = self.server.scene.add_camera_frustum(f"/cameras/{fr['name']}", fov, aspect, scale=scale,
                                                     wxyz=wxyz, position=pos, color=colour)
            h.on_click(lambda e, i=i: self._go_to_frame(e.client, i))

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

    def _go_to_frame(self, client, i: int) -> None:
        """Move the browser's camera to frame ``i`` and show render | observation | error."""
        fr = self.tm.frames[i]
        pos, wxyz = viser_from_c2w(np.asarray(fr["c2w"], float))
        with client.atomic():
            client.camera.wxyz, client.camera.position = wxyz, pos
        with _serial_lock(self.render_lock):
            rgb, obs, err = frame_comparison(self.tm, i, self._observed(i), backend=self.opts.backend)
        blank = np.full_like(rgb, 255)
        panel = np.concatenate([rgb, blank[:, :4], obs if obs is not None else blank, blank[:, :4],
                                err if err is not None else blank], axis=1)  # [H, 3W+8, 3]
        label = f"{fr['name']} ({fr.get('split', '?')}): render | observation | error"
        if obs is None:
            label += " (scene not found: no observation)"
        if "compare" in self._plots:
            self._plots["compare"].remove()
        with self.compare_folder:
            self._plots["compare"] = self.server.gui.add_image(panel, label=label)
