"""``brfgs view`` in a real browser: headless Chromium driven over the Chrome DevTools protocol.

Starts the viewer on a free local port with a synthetic model (warmed up as ``brfgs view`` does),
opens the page, times the first frames, orbits by dragging (frames while moving), switches modes,
clicks the surface (an ROI; the camera and the camera panel stay as they were) and reads the plots
as a person does: the texts uPlot draws on its canvases (axis labels with units, numeric ticks,
no dates). Screenshots are saved in the test's tmp folder (and in $BRFGS_VIEWER_SCREENSHOTS).
Skips (with the reason) only where Chromium or viser cannot be found.
"""

import base64
import io
import json
import os
import re
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

from brfgs.viewer.cameras import viser_from_c2w  # noqa: E402
from brfgs.viewer.serve import start_server  # noqa: E402
from brfgs.viewer.server import Viewer, ViewerOptions, warm_up  # noqa: E402

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


# Records every text the page draws on a canvas (uPlot draws its axes' ticks and labels there).
RECORD_CANVAS_TEXT = """
window.__drawn = [];
const fill = CanvasRenderingContext2D.prototype.fillText;
CanvasRenderingContext2D.prototype.fillText = function (text, x, y, w) {
  window.__drawn.push(String(text));
  return fill.apply(this, arguments);
};
"""


@pytest.fixture
def viewer(tmp_path):
    port = _free_port()
    tm = synthetic_model(n_gaussians=20000)  # the ground covered: clicks near the centre hit it
    warm_up(tm)  # as brfgs view does before it prints its URL
    server = start_server("127.0.0.1", port, (), label="brfgs view test")
    opts = ViewerOptions(port=port, height_px=256, moving_height_px=64, out_dir=tmp_path / "rois", roi_step_deg=15.0,
                         polar_azimuths=8, polar_zeniths=3)
    v = Viewer(tm, server, opts)
    yield v, f"http://127.0.0.1:{port}"
    server.stop()


def _full_frame(v: Viewer):
    states = list(v.clients.values())
    return states and states[0].last is not None and states[0].last.rgb.shape[0] == v.opts.height_px and states[0]


def _scene_part(img: np.ndarray) -> np.ndarray:
    return img[160:, :640].astype(float)  # left of the GUI panel, below the notifications


def _texts(browser) -> list[str]:
    return browser.eval("window.__drawn") or []


def _save(browser, tmp_path, name: str) -> np.ndarray:
    shot = browser.screenshot()
    Image.fromarray(shot).save(tmp_path / f"{name}.png")
    keep = os.environ.get("BRFGS_VIEWER_SCREENSHOTS")
    if keep:
        Image.fromarray(shot).save(os.path.join(keep, f"{name}.png"))
    return shot


def _open(browser, url: str, v: Viewer):
    """Open the page; (the first client's state, seconds to its first frame, seconds to a full frame)."""
    browser.call("Page.enable")
    browser.call("Page.addScriptToEvaluateOnNewDocument", source=RECORD_CANVAS_TEXT)
    t0 = time.perf_counter()
    browser.call("Page.navigate", url=url)
    st = _wait(lambda: next(iter(v.clients.values()), None), 60, "the page to connect")
    _wait(lambda: len(st.log) > 0, 60, "the first frame")
    first = st.log[0][0] - t0
    _wait(lambda: _full_frame(v), 60, "the first full-resolution frame")
    full = next(t for t, _, _, h in st.log if h == v.opts.height_px) - t0
    return st, first, full


def _orbit(browser, st, n_moves: int = 24) -> list[tuple]:
    """Drag across the canvas (the camera orbits); the frames sent meanwhile."""
    vw, vh = browser.eval("[window.innerWidth, window.innerHeight]")
    x0, y0 = 0.3 * vw, 0.5 * vh
    n0 = len(st.log)
    browser.call("Input.dispatchMouseEvent", type="mousePressed", x=x0, y=y0, button="left", clickCount=1)
    for k in range(1, n_moves + 1):
        browser.call("Input.dispatchMouseEvent", type="mouseMoved", x=x0 + 6 * k, y=y0 + 2 * k, button="left",
                     buttons=1)
        time.sleep(0.05)
    browser.call("Input.dispatchMouseEvent", type="mouseReleased", x=x0 + 6 * n_moves, y=y0 + 2 * n_moves,
                 button="left", clickCount=1)
    time.sleep(1.0)
    return list(st.log)[n0:]


def test_viewer_page_renders_switches_modes_and_picks_an_roi(viewer, browser, tmp_path):
    v, url = viewer
    st, first_s, full_s = _open(browser, url, v)
    time.sleep(1.5)  # the frame travels to the browser and is drawn
    scene = _scene_part(_save(browser, tmp_path, "1_opened"))
    assert scene.std() > 5.0, "the render area of the screenshot is blank"
    print(f"first frame sent {first_s:.2f} s after opening the page, first full frame {full_s:.2f} s")
    assert first_s < 30.0

    moving = [row for row in _orbit(browser, st) if row[3] == v.opts.moving_height_px]
    assert moving, "no frames while the camera moved"
    print(f"while orbiting: {len(moving)} frames, camera-to-frame latency median "
          f"{1000 * float(np.median([r[1] for r in moving])):.0f} ms, render median "
          f"{1000 * float(np.median([r[2] for r in moving])):.0f} ms")
    _wait(lambda: _full_frame(v) and st.log[-1][3] == v.opts.height_px, 30, "the full frame after orbiting")

    time.sleep(1.5)
    cir_shot = _scene_part(_save(browser, tmp_path, "2_orbited"))
    first = st.last
    v.mode.value = "depth"  # as the Mode dropdown does
    _wait(lambda: st.last is not first and st.last.rgb.shape[0] == v.opts.height_px, 30, "the depth frame")
    time.sleep(1.5)
    depth_shot = _scene_part(_save(browser, tmp_path, "3_depth"))
    assert np.abs(depth_shot - cir_shot).mean() > 5.0, "the screenshot did not change with the display mode"
    v.mode.value = "cir"
    _wait(lambda: st.last.rgb.shape[0] == v.opts.height_px and v.settings.mode.kind == "cir", 30, "the CIR frame")

    # a surface click: an ROI, and neither the camera nor the camera panel changes
    assert browser.eval("document.querySelectorAll('.uplot').length") == 0
    time.sleep(1.0)
    fr = st.last  # a pixel of the shown frame where the surface is opaque, nearest the centre
    ii, jj = np.nonzero(fr.view.alpha > 0.9)
    k = np.argmin((ii - fr.intr.h / 2) ** 2 + (jj - fr.intr.w / 2) ** 2)
    vw, vh = browser.eval("[window.innerWidth, window.innerHeight]")
    pos_before, wxyz_before = np.array(st.client.camera.position), np.array(st.client.camera.wxyz)
    t_click = time.perf_counter()
    browser.click((jj[k] + 0.5) / fr.intr.w * vw, (ii[k] + 0.5) / fr.intr.h * vh)
    _wait(lambda: v.rois.roi is not None, 60, "the click to reach the server and make an ROI")
    t_spectrum = time.perf_counter() - t_click
    assert v.rois.roi.n_pixels > 0 and np.isfinite(v.rois.roi.spectrum).all()
    _wait(lambda: browser.eval("document.querySelectorAll('.uplot').length") or 0, 30, "the spectrum plot")
    _wait(lambda: "BRF ready" in v.rois.text.content, 120, "the principal-plane and polar plots")
    t_brf = time.perf_counter() - t_click
    print(f"click -> spectrum {t_spectrum:.1f} s, click -> BRF {t_brf:.1f} s")
    time.sleep(1.0)
    assert np.allclose(st.client.camera.position, pos_before, atol=1e-6)
    assert np.allclose(st.client.camera.wxyz, wxyz_before, atol=1e-6)
    assert v.cameras.image is None, "a surface click filled the camera comparison"
    assert "ROI at E" in v.rois.text.content

    # what a person reads on the plots: numeric axes with units, no dates
    _wait(lambda: browser.eval("document.querySelectorAll('.uplot').length") >= 2, 30, "the principal-plane plot")
    for k in range(2):
        browser.call("Runtime.evaluate", expression=f"document.querySelectorAll('.uplot')[{k}].scrollIntoView()")
        time.sleep(1.0)
        _save(browser, tmp_path, f"4_roi_plot_{k}")
    texts = _texts(browser)
    assert "wavelength (nm)" in texts and "BRF" in texts and "view zenith (deg), + = sun side" in texts, texts
    dates = [t for t in texts if re.search(r"(am|pm)\b|/70|/69|:\d\d", t)]
    assert not dates, dates
    numbers = [t for t in texts if re.fullmatch(r"[−-]?\d[\d,]*(\.\d+)?", t)]
    wl = [float(t.replace(",", "")) for t in numbers]
    assert any(340 <= x <= 1010 for x in wl) and any(x <= 0 for x in wl)  # wavelength ticks; signed zeniths

    folder = v.rois.save(st.client)
    assert folder == tmp_path / "rois" / "roi_01"
    assert sorted(p.name for p in folder.iterdir()) == ["polar.csv", "principal_plane.csv", "roi.geojson",
                                                        "spectrum.csv"]


def test_cameras_are_chosen_from_the_list_not_by_a_surface_click(viewer, browser, tmp_path):
    v, url = viewer
    st, _, _ = _open(browser, url, v)
    name = v.cameras.names[1]
    v.cameras.go_to_named(st.client, name)
    _wait(lambda: np.allclose(st.client.camera.position,
                              viser_from_c2w(np.asarray(v.tm.frames[1]["c2w"], float))[0], atol=1e-3), 30,
          "the browser's camera at the chosen camera")
    assert v.cameras.image is not None
    time.sleep(1.5)
    _save(browser, tmp_path, "5_camera")
