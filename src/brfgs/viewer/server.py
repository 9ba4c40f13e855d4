"""The viser page of ``brfgs view RUN``: live renders, display modes, sun sliders, click-ROIs with
plots, and the training and test cameras.

Rendering stays in brfgs (:func:`brfgs.viewer.frames.render_frame`, the one render path); viser
only shows the image as the scene background and sends the browser's camera, clicks and widget
values, each checked (:mod:`brfgs.viewer.checks`) before use: a bad value is reported to the
browser that sent it in one line and changes nothing. Each browser gets a render thread that
always renders its newest camera: a frame ``--moving-height`` high while the camera moves, a
full-size one once it has rested for ``settle_s``; a frame that fails is reported in that
browser's status line and the next camera is served as usual.

A click on the surface picks an ROI (never a camera; cameras are chosen in the Cameras panel or
by shift-clicking a frustum) and leaves the camera where it is.
"""

from __future__ import annotations

import contextlib
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field, replace

import numba
import numpy as np
import viser

from brfgs.analysis.bench import bench_camera
from brfgs.analysis.brf import roi_brf, training_footprint_m
from brfgs.data.cameras import pose_from_view_angles
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.viewer.cameras import fov_from_intrinsics, viser_from_c2w
from brfgs.viewer.checks import ROI_RADIUS_M, SUN_AZIMUTH_DEG, SUN_ZENITH_DEG, checked_number, client_view, screen_point
from brfgs.viewer.formula import NDVI, parse_formula
from brfgs.viewer.frames import DisplayMode, FrameResult, parse_mode, render_frame
from brfgs.viewer.options import ViewerOptions
from brfgs.viewer.panels import CameraPanel, RoiPanel
from brfgs.viewer.roi import disc_roi, roi_spectrum, surface_hit

__all__ = ["ViewerOptions", "Viewer", "warm_up"]


SHADOW_NOTE = ("**Shadows are baked into the model.** The sun sliders re-evaluate the kernels (iso, vol, geo, "
               "spec) for the new sun; cast shadows stay where they were at acquisition.")
SHADOW_NOTE_LIT = ("**Shadows move with the sun.** The model was trained with shadows: the sun sliders re-evaluate "
                   "the kernels and each surface's direct-sun visibility from the model's geometry.")
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


def warm_up(tm: TrainedModel, backend: str = "auto") -> float:
    """Run every path the page uses once on a 32-pixel view (spectral, geometry and kernel frames, a
    click's hit and ROI spectrum, one BRF direction), so that the first frames and clicks do not wait
    for compiled kernels to load; returns the seconds taken."""
    t0 = time.perf_counter()
    c2w, intr = bench_camera(tm, 32)
    for mode in ("cir", "normals", "kernel:iso"):
        with contextlib.suppress(UserError):  # a model without these terms
            render_frame(tm, c2w, intr, parse_mode(mode), backend=backend)
    surface_hit(tm, c2w, intr, 0.5, 0.5, backend=backend)
    roi = disc_roi(tm.scene_centre_m(), 3.0 * training_footprint_m(tm))
    res = roi_spectrum(tm, roi, c2w, intr, (tm.sun_zenith_deg, tm.sun_azimuth_deg), backend=backend)
    roi_brf(tm, res.roi, [30.0], [0.0], [0], backend=backend)
    return time.perf_counter() - t0


@dataclass
class _ClientState:
    """One browser: its status line, render thread signals, its latest full frame."""

    client: object
    status: object = None
    dirty: threading.Event = field(default_factory=threading.Event)
    moved_at: float = 0.0
    need_full: bool = True
    camera_changed: bool = True
    rendering: bool = False
    last: FrameResult | None = None
    alive: bool = True
    log: deque = field(default_factory=lambda: deque(maxlen=200))  # (sent at, camera age s, render s, height px)


@dataclass(frozen=True)
class _Settings:
    """The checked widget values every frame uses."""

    mode: DisplayMode
    sun: tuple[float, float]


class Viewer:
    """The page and its callbacks for one model (``server`` is a running :class:`viser.ViserServer`)."""

    def __init__(self, tm: TrainedModel, server: viser.ViserServer, opts: ViewerOptions):
        self.tm, self.server, self.opts = tm, server, opts
        self.clients: dict[int, _ClientState] = {}
        self.lock = threading.Lock()
        self.render_lock = threading.Lock()
        self.settings = _Settings(parse_mode("cir"), (float(tm.sun_zenith_deg), float(tm.sun_azimuth_deg) % 360.0))
        self._good: dict[str, object] = {}
        server.scene.set_up_direction("+z")
        self._initial_camera()
        self._build_gui()
        self.cameras = CameraPanel(tm, server, opts, self.lock_for_render)
        self._add_frustums()
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)
        server.scene.on_click()(self._on_click)

    # ------------------------------------------------------------------ GUI

    def _build_gui(self) -> None:
        gui, tm = self.server.gui, self.tm
        wl = np.asarray(tm.wavelengths_nm, float)
        self.band_range_nm = (float(wl.min()), float(wl.max()))
        with gui.add_folder("Display") as self.display_folder:
            self.mode = gui.add_dropdown("Mode", DISPLAY_CHOICES, initial_value="cir")
            self.band = gui.add_number("Band (nm)", float(np.clip(860.0, *self.band_range_nm)),
                                       min=self.band_range_nm[0], max=self.band_range_nm[1], step=1.0)
            self.formula = gui.add_text("Index formula", NDVI)
        with gui.add_folder("Sun"):
            self.sun_z = gui.add_slider("Sun zenith (deg)", *SUN_ZENITH_DEG, 0.5,
                                        float(np.clip(tm.sun_zenith_deg, *SUN_ZENITH_DEG)))
            self.sun_a = gui.add_slider("Sun azimuth (deg)", *SUN_AZIMUTH_DEG, 1.0, float(tm.sun_azimuth_deg) % 360.0)
            reset = gui.add_button("Reset to the acquisition's sun")
            gui.add_markdown(SHADOW_NOTE_LIT if tm.shadowed else SHADOW_NOTE)
        self.rois = RoiPanel(tm, self.server, self.opts, self.lock_for_render, self.wait_for_frames)
        self.pick, self.radius = self.rois.pick_box, self.rois.radius
        checks = {"mode": (self.mode, self._check_mode), "band": (self.band, self._check_band),
                  "sun_z": (self.sun_z, lambda v: checked_number(v, *SUN_ZENITH_DEG, "Sun zenith (deg)")),
                  "sun_a": (self.sun_a, lambda v: checked_number(v, *SUN_AZIMUTH_DEG, "Sun azimuth (deg)")),
                  "radius": (self.radius, lambda v: checked_number(v, *ROI_RADIUS_M, "ROI radius (m)"))}
        for key, (handle, check) in checks.items():
            self._good[key] = handle.value
            handle.on_update(lambda e, key=key, handle=handle, check=check: self._checked(e, key, handle, check))
        self.formula.on_update(self._formula_changed)
        reset.on_click(lambda _e: self.reset_sun())

    def _check_mode(self, value) -> str:
        if value not in DISPLAY_CHOICES:
            raise UserError(f"display mode {str(value)[:40]!r} is not one of {', '.join(DISPLAY_CHOICES)}",
                            field="Mode")
        return value

    def _check_band(self, value) -> float:
        return checked_number(value, *self.band_range_nm, "Band (nm)")

    def _checked(self, event, key: str, handle, check) -> None:
        """A widget changed: keep a valid value and apply it, or put the last valid one back and tell
        the browser that sent it."""
        try:
            check(handle.value)
        except UserError as exc:
            self.tell(event.client, exc)
            handle.value = self._good[key]
            return
        self._good[key] = handle.value
        if key in ("sun_z", "sun_a"):
            with self.lock:
                self.settings = replace(self.settings, sun=(float(self._good["sun_z"]), float(self._good["sun_a"])))
            self.redraw_all()
        elif key in ("mode", "band"):
            self._apply_display(event)

    def _formula_changed(self, event) -> None:
        """A formula is checked when it is typed (whatever the mode), applied in index mode."""
        try:
            parse_formula(self.formula.value)
        except UserError as exc:
            self.tell(event.client, exc)
            return
        self._apply_display(event)

    def _apply_display(self, event) -> None:
        """The display mode of the (checked) widgets, or the browser told why it is not applied."""
        try:
            mode = parse_mode(self.mode_text())
        except UserError as exc:
            self.tell(event.client, exc)
            return
        with self.lock:
            self.settings = replace(self.settings, mode=mode)
        self.redraw_all()

    def tell(self, client, exc: UserError) -> None:
        """Say in one line why a value from ``client`` was not applied."""
        if client is not None:
            client.add_notification("Not applied", str(exc), auto_close_seconds=8.0, color="red")

    def mode_text(self) -> str:
        """The display mode string of the widgets (band:<nm>, index:<formula> or the choice)."""
        m = self._good.get("mode", self.mode.value)
        if m == "band":
            return f"band:{float(self._good.get('band', self.band.value)):g}"
        if m == "index":
            return f"index:{self.formula.value}"
        return str(m)

    def sun(self) -> tuple[float, float]:
        return self.settings.sun

    def reset_sun(self) -> None:
        """Sliders back to the acquisition's sun (this redraws)."""
        self.sun_z.value = float(np.clip(self.tm.sun_zenith_deg, *SUN_ZENITH_DEG))
        self.sun_a.value = float(self.tm.sun_azimuth_deg) % 360.0

    def _initial_camera(self) -> None:
        """Pages open on an oblique overview from beyond the cameras, looking at the scene centre."""
        tm, ic = self.tm, self.server.initial_camera
        centre, dist = tm.scene_centre_m(), 1.3 * tm.typical_distance_m()
        ic.position = pose_from_view_angles(37.0, 65.0, dist, centre)[:3, 3]
        ic.look_at = centre
        ic.up = (0.0, 0.0, 1.0)
        ic.fov = fov_from_intrinsics(tm.intrinsics)[0]

    # ------------------------------------------------------------------ clients and rendering

    def _connect(self, client) -> None:
        st = _ClientState(client, moved_at=time.perf_counter())  # the first frame small and fast, then full
        with self.display_folder:
            st.status = client.gui.add_markdown("")
        with self.lock:
            self.clients[client.client_id] = st
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
        st.camera_changed = True
        st.dirty.set()

    def redraw_all(self) -> None:
        with self.lock:
            states = list(self.clients.values())
        for st in states:
            st.dirty.set()

    def lock_for_render(self):
        """The render lock when renders from two threads must not overlap (:func:`_serial_lock`)."""
        return _serial_lock(self.render_lock)

    def wait_for_frames(self, max_s: float = 2.0) -> None:
        """Return once no browser waits for a frame (at most ``max_s``): background work goes second."""
        t_end = time.perf_counter() + max_s
        while time.perf_counter() < t_end:
            with self.lock:
                busy = any(st.rendering or st.dirty.is_set() for st in self.clients.values())
            if not busy:
                return
            time.sleep(0.005)

    def _render_loop(self, st: _ClientState) -> None:
        """Per browser: a reduced frame for each camera change, a full frame once no camera change
        has come for ``settle_s`` (however long frames take) or at once for a settings change at
        rest; the camera read when a frame starts is the newest (older updates are never rendered)."""
        while st.alive:
            changed = st.dirty.wait(timeout=self.opts.settle_s)
            if not st.alive:
                return
            if changed:
                st.dirty.clear()
                moving, st.camera_changed = st.camera_changed, False
                self._draw(st, self.opts.moving_height_px if moving else self.opts.height_px)
                st.need_full = moving
            elif st.need_full:
                st.need_full = False
                self._draw(st, self.opts.height_px)

    def _draw(self, st: _ClientState, height_px: int) -> None:
        """Render and send one frame of ``st``'s camera; any failure goes to its status line."""
        st.rendering = True
        moved_at = st.moved_at
        try:
            cam = st.client.camera
            c2w, intr = client_view(cam.position, cam.wxyz, cam.fov, cam.image_width, cam.image_height, height_px)
            s = self.settings
            with self.lock_for_render():
                res = render_frame(self.tm, c2w, intr, s.mode, sun_zenith_deg=s.sun[0], sun_azimuth_deg=s.sun[1],
                                   backend=self.opts.backend)
            st.client.scene.set_background_image(res.rgb, format="jpeg", jpeg_quality=90)
            now = time.perf_counter()
            st.log.append((now, now - moved_at, res.seconds, res.rgb.shape[0]))
            if height_px == self.opts.height_px:
                st.last = res
            self._status(st, f"{res.rgb.shape[1]}×{res.rgb.shape[0]} px in {1000 * res.seconds:.0f} ms")
        except UserError as exc:
            self._status(st, f"⚠ {exc}")
        except Exception as exc:  # a bug: keep serving this browser, show where to look
            traceback.print_exc()
            self._status(st, f"⚠ the frame failed ({type(exc).__name__}); details in the terminal")
        finally:
            st.rendering = False

    def _status(self, st: _ClientState, text: str) -> None:
        if st.status is not None and st.status.content != text:
            st.status.content = text

    # ------------------------------------------------------------------ clicks and cameras

    def _on_click(self, event) -> None:
        """A click (no modifier) on the scene: an ROI at the surface under it, when picking is on."""
        st = self.clients.get(event.client_id)
        if st is None or not self.pick.value:
            return
        try:
            x, y = screen_point(event.screen_pos)
            cam = event.client.camera
            c2w, intr = client_view(cam.position, cam.wxyz, cam.fov, cam.image_width, cam.image_height,
                                    self.opts.height_px)
            radius = checked_number(self.radius.value, *ROI_RADIUS_M, "ROI radius (m)")
        except UserError as exc:
            self.tell(event.client, exc)
            return
        self.rois.pick(c2w, intr, x, y, radius, self.settings.sun)

    def _add_frustums(self) -> None:
        tm = self.tm
        fov, aspect = fov_from_intrinsics(tm.intrinsics)
        scale = 0.08 * tm.typical_distance_m() if tm.frames else 1.0
        for i, fr in enumerate(tm.frames):
            pos, wxyz = viser_from_c2w(np.asarray(fr["c2w"], float))
            colour = (40, 90, 220) if fr.get("split") == "train" else (230, 120, 20)
            h = self.server.scene.add_camera_frustum(f"/cameras/{fr['name']}", fov, aspect, scale=scale,
                                                     wxyz=wxyz, position=pos, color=colour)
            h.on_click(modifier="shift")(lambda e, i=i: self.cameras.go_to(e.client, i))

