"""The viewer page's callbacks on a running viser server (no browser): sun reset, mode text, the
frame policy while the camera moves (however slow frames are), plots with numeric axes and units,
cameras chosen from the list, the command line serving the page and printing its URL."""

import os
import socket
import subprocess
import sys
import threading
import time
import urllib.request

import numpy as np
import pytest

from brfgs.analysis.bench import synthetic_model

viser = pytest.importorskip("viser", reason="viser is not installed (pip install 'brfgs[viewer]')")

from brfgs.viewer.panels import add_plot, finite_rows  # noqa: E402
from brfgs.viewer.server import Viewer, ViewerOptions, _ClientState  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def viewer():
    port = _free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    v = Viewer(synthetic_model(n_gaussians=500), server, ViewerOptions(port=port))
    yield v
    server.stop()


def test_sun_sliders_reset_to_the_acquisition(viewer):
    tm = viewer.tm
    assert viewer.sun() == (pytest.approx(tm.sun_zenith_deg), pytest.approx(tm.sun_azimuth_deg % 360))
    viewer.sun_z.value, viewer.sun_a.value = 70.0, 10.0
    assert viewer.sun() == (70.0, 10.0)
    viewer.reset_sun()
    assert viewer.sun() == (pytest.approx(tm.sun_zenith_deg), pytest.approx(tm.sun_azimuth_deg % 360))


def test_mode_text_follows_the_widgets(viewer):
    viewer.mode.value = "band"
    viewer.band.value = 700.0
    assert viewer.mode_text() == "band:700"
    viewer.mode.value = "index"
    viewer.formula.value = "(b800-b670)/(b800+b670)"
    assert viewer.mode_text() == "index:(b800-b670)/(b800+b670)"
    viewer.mode.value = "kernel:vol"
    assert viewer.mode_text() == "kernel:vol"
    viewer.mode.value = "cir"


def test_frames_while_moving_stay_small_however_slow_they_are(viewer):
    """Camera updates every 50 ms, then every 300 ms (a loaded browser), for 2 s each, frames taking
    0.4 s (longer than settle_s): every frame during the motion is a moving-size one, one full frame
    follows once the camera rests, and each frame renders the newest camera (older updates dropped)."""
    drawn: list[tuple[int, int]] = []
    n_updates = [0]
    st = _ClientState(client=None)
    real_draw = viewer._draw
    viewer._draw = lambda st_, h: (drawn.append((h, n_updates[0])), time.sleep(0.4))
    try:
        threading.Thread(target=viewer._render_loop, args=(st,), daemon=True).start()
        for period in (0.05, 0.3):
            t_end = time.monotonic() + 2.0
            while time.monotonic() < t_end:
                n_updates[0] += 1
                viewer._moved(st)
                time.sleep(period)
        time.sleep(1.2)
        st.alive = False
        st.dirty.set()
    finally:
        viewer._draw = real_draw
    heights = [h for h, _ in drawn]
    o = viewer.opts
    assert heights[-1] == o.height_px and heights.count(o.height_px) == 1, heights
    assert set(heights[:-1]) == {o.moving_height_px} and 6 <= len(heights) - 1 <= 16, heights
    assert [n for _, n in drawn[:-1]] == sorted(set(n for _, n in drawn[:-1]))  # always a newer camera


def test_a_settings_change_at_rest_draws_the_full_frame_at_once(viewer):
    drawn: list[int] = []
    st = _ClientState(client=None, camera_changed=False)
    real_draw = viewer._draw
    viewer._draw = lambda st_, h: drawn.append(h)
    with viewer.lock:
        viewer.clients[-1] = st
    try:
        threading.Thread(target=viewer._render_loop, args=(st,), daemon=True).start()
        viewer.redraw_all()
        time.sleep(0.6)
    finally:
        with viewer.lock:
            viewer.clients.pop(-1)
        st.alive = False
        st.dirty.set()
        viewer._draw = real_draw
    assert drawn == [viewer.opts.height_px]


def test_plots_have_a_numeric_x_scale_and_axes_with_units(viewer):
    h = add_plot(viewer.server.gui, (np.array([400.0, 500.0, np.nan, 700.0]), np.array([0.1, np.nan, 0.3, 0.4])),
                 "wavelength (nm)", "BRF", ("BRF",), "test")
    try:
        assert h.scales["x"]["time"] is False
        assert [a["label"] for a in h.axes] == ["wavelength (nm)", "BRF"]
        assert [a["scale"] for a in h.axes] == ["x", "y"]
        assert np.array_equal(h.data[0], [400.0, 700.0]) and np.array_equal(h.data[1], [0.1, 0.4])  # gaps, not zeros
    finally:
        h.remove()
    assert [len(a) for a in finite_rows((np.array([np.nan]), np.array([1.0])))] == [0, 0]


def test_frustums_for_every_training_and_test_camera(viewer):
    assert len(viewer.tm.frames) == 3
    # one frustum per frame under /cameras (viser keeps the handles by name)
    names = [n for n in viewer.server.scene._handle_from_node_name if n.startswith("/cameras/")]
    assert sorted(names) == sorted(f"/cameras/{f['name']}" for f in viewer.tm.frames)


def test_command_serves_the_page_and_prints_the_url(tmp_path):
    model = synthetic_model(n_gaussians=200).save(tmp_path / "run" / "model.safetensors")
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "brfgs", "view", str(model.parent), "--port", str(port),
                             "--seconds", "30"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)  # the command's output
    reader.start()
    try:
        t_end, html = time.monotonic() + 60, None
        while html is None and time.monotonic() < t_end:
            try:
                html = urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=2).read().decode()
            except OSError:
                time.sleep(0.3)
        assert html is not None and "<html" in html.lower()
        while not any("ssh -L" in line for line in lines) and time.monotonic() < t_end:
            time.sleep(0.2)          # the page is served before the command has printed its URL line
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        reader.join(timeout=20)
    out = "".join(lines)
    assert f"http://localhost:{port}" in out and "ssh -L" in out
