"""The viewer page's callbacks on a running viser server (no browser): sun reset, mode text, the
command line serving the page and printing its URL."""

import os
import socket
import subprocess
import sys
import threading
import time
import urllib.request

import pytest

from brfgs.analysis.bench import synthetic_model

viser = pytest.importorskip("viser", reason="viser is not installed (pip install 'brfgs[viewer]')")

from brfgs.viewer.server import Viewer, ViewerOptions  # noqa: E402


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
