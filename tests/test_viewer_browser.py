"""``brfgs view`` in a real browser: headless Chromium driven over the Chrome DevTools protocol.

Starts the viewer on a free local port with a small synthetic model, opens the page, waits for
the canvas and the first full frame, checks the screenshot is not blank and changes with the
display mode, clicks the surface and waits for the ROI's spectrum plot (a uPlot panel) to appear.
Skips (with the reason) only where Chromium or viser cannot be found.
"""

import base64
import io
import json
import os
import shutil
import socket
import subprocess
import time
import urllib.request

import numpy as np
import pytest

from brfgs.analysis.bench import synthetic_model

CHROMIUM = next((p for p in ("/usr/bin/chromium", shutil.which("chromium") or "", shutil.which("chromium-browser") or "",
                             shutil.which("google-chrome") or "") if p and os.path.exists(p)), None)
viser = pytest.importorskip("viser", reason="viser is not installed (pip install 'brfgs[viewer]')")
if CHROMIUM is None:
    pytest.skip("no Chromium found (/usr/bin/chromium, chromium, chromium-browser, google-chrome)",
                allow_module_level=True)

from PIL import Image  # noqa: E402
from websockets.sync.client import connect  # noqa: E402  (websockets comes with viser)

from brfgs.viewer.server import Viewer, ViewerOptions  # noqa: E402

W, H = 1000, 700


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Page:
    """A minimal Chrome DevTools protocol client for one page."""

    def __init__(self, ws_url: str):
        self.ws = connect(ws_url, max_size=2**27, open_timeout=20)
        self.n = 0

    def call(self, method: str, **params):
        self.n += 1
        self.ws.send(json.dumps({"id": self.n, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=30))
            if msg.get("id") == self.n:
                assert "error" not in msg, msg
                return msg.get("result", {})

    def eval(self, js: str):
        return self.call("Runtime.evaluate", expression=js, returnByValue=True)["result"].get("value")

    def screenshot(self) -> np.ndarray:  # [H, W, 3] uint8
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def click(self, x: float, y: float) -> None:
        for kind in ("mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)


def _wait(cond, timeout_s: float, what: str):
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        v = cond()
        if v:
            return v
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.fixture
def browser(tmp_path):
    proc = subprocess.Popen([CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                             "--use-angle=swiftshader", f"--window-size={W},{H}", "--remote-debugging-port=0",
                             f"--user-data-dir={tmp_path / 'chromium'}", "--no-first-run", "about:blank"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        port = None
        t_end = time.monotonic() + 30
        while port is None and time.monotonic() < t_end:
            line = proc.stderr.readline()
            if "DevTools listening on" in line:
                port = int(line.rsplit(":", 1)[1].split("/")[0])
        assert port, "Chromium did not open its DevTools port"
        targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10))
        page = _Page(next(t for t in targets if t["type"] == "page")["webSocketDebuggerUrl"])
        yield page
        page.ws.close()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.fixture
def viewer(tmp_path):
    port = _free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    opts = ViewerOptions(port=port, height_px=256, moving_height_px=64, out_dir=tmp_path / "rois", roi_step_deg=15.0,
                         polar_azimuths=8, polar_zeniths=3)
    v = Viewer(synthetic_model(n_gaussians=2000), server, opts)
    yield v, f"http://127.0.0.1:{port}"
    server.stop()


def _full_frame(v: Viewer):
    states = list(v.clients.values())
    return states and states[0].last is not None and states[0].last.rgb.shape[0] == v.opts.height_px and states[0]


def _scene_part(img: np.ndarray) -> np.ndarray:
    return img[160:, :640].astype(float)  # left of the GUI panel, below the notifications


def test_viewer_page_renders_switches_modes_and_picks_an_roi(viewer, browser, tmp_path):
    v, url = viewer
    browser.call("Page.enable")
    browser.call("Page.navigate", url=url)
    _wait(lambda: browser.eval("document.querySelectorAll('canvas').length") or 0, 30, "the page's canvas")
    st = _wait(lambda: _full_frame(v), 40, "the first full-resolution frame")
    time.sleep(1.5)  # the frame travels to the browser and is drawn
    shot = browser.screenshot()
    scene = _scene_part(shot)
    assert scene.std() > 5.0, "the render area of the screenshot is blank"
    keep = os.environ.get("BRFGS_VIEWER_SCREENSHOT")
    if keep:
        Image.fromarray(shot).save(keep)

    first = st.last
    v.mode.value = "depth"  # as the Mode dropdown does
    _wait(lambda: st.last is not first and st.last.rgb.shape[0] == v.opts.height_px, 30, "the depth frame")
    time.sleep(1.5)
    depth_shot = _scene_part(browser.screenshot())
    assert np.abs(depth_shot - scene).mean() > 5.0, "the screenshot did not change with the display mode"

    assert browser.eval("document.querySelectorAll('.uplot').length") == 0
    fr = st.last  # click a pixel of the shown frame where the surface is opaque, nearest the centre
    ii, jj = np.nonzero(fr.view.alpha > 0.9)
    k = np.argmin((ii - fr.intr.h / 2) ** 2 + (jj - fr.intr.w / 2) ** 2)
    vw, vh = browser.eval("[window.innerWidth, window.innerHeight]")
    browser.click((jj[k] + 0.5) / fr.intr.w * vw, (ii[k] + 0.5) / fr.intr.h * vh)
    _wait(lambda: v.roi is not None, 30, "the click to reach the server and make an ROI")
    assert v.roi.n_pixels > 0 and np.isfinite(v.roi.spectrum).all()
    _wait(lambda: browser.eval("document.querySelectorAll('.uplot').length") or 0, 30, "the spectrum plot")
    _wait(lambda: v.roi.pp_values.size > 0 and "polar" in v._plots, 60, "the principal-plane and polar plots")
    v._save(st.client)
    assert sorted(p.name for p in (tmp_path / "rois" / "roi_01").iterdir()) == [
        "polar.csv", "principal_plane.csv", "roi.geojson", "spectrum.csv"]
