"""``brfgs view`` as a web server facing hostile pages and clients.

The pure rules first (which origins may connect; every browser value checked), then the command
itself in a subprocess, driven by raw websocket clients speaking viser's protocol: foreign origins
refused at the handshake, and one test per hostile message or field (huge and zero canvases, field
of view 0 / NaN / π, NaN pose, sun out of range, bad formula, band, mode, click position, ROI name with
``../``), each followed by a good camera that must still get frames; bad values are told to the
client that sent them only; nothing is written outside the run's folder; peak memory stays < 2 GB.
"""

import math
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from brfgs.analysis.bench import synthetic_model
from brfgs.errors import UserError
from brfgs.viewer.checks import MAX_SIDE_PX, client_view, frame_size, roi_name, screen_point
from brfgs.viewer.formula import parse_formula
from brfgs.viewer.origin import OriginPolicy, normalise_origin

# ---------------------------------------------------------------- which pages may connect


def test_normalise_origin():
    assert normalise_origin("HTTPS://Viewer.Example.org:443/") == "https://viewer.example.org"
    assert normalise_origin("http://[::1]:8080") == "http://[::1]:8080"
    for bad in ("viewer.example.org", "ftp://x", "https://x/path", "https://u:p@x", "https://x?q=1", "http://x:99999"):
        with pytest.raises(UserError) as e:
            normalise_origin(bad)
        assert e.value.field == "--allow-origin"


def test_origin_policy():
    p = OriginPolicy(allowed=("https://proxy.example.org",), host_names=("localhost", "myhost"))
    ok = [("http://localhost:8080", "localhost:8080"), ("http://127.0.0.1:8080", "127.0.0.1:8080"),
          ("http://[::1]:8080", "[::1]:8080"), ("http://localhost:9000", "localhost:9000"),  # an SSH tunnel's port
          ("http://192.168.1.5:8080", "192.168.1.5:8080"), ("http://myhost:8080", "myhost:8080"),
          ("https://proxy.example.org", "127.0.0.1:8080")]  # the proxy forwards to the viewer
    for origin, host in ok:
        assert p.refusal(origin, host) is None, (origin, host)
    refused = [(None, "localhost:8080"), ("", "localhost:8080"), ("null", "localhost:8080"),
               ("http://evil.example", "localhost:8080"),            # another site's page
               ("http://evil.example:8080", "evil.example:8080"),    # DNS rebinding: a name pointed at us
               ("http://localhost:8081", "localhost:8080"), ("https://localhost:8080", "localhost:8080"),
               ("http://6.6.6.6:8080", "127.0.0.1:8080"), ("http://localhost:8080", None)]
    for origin, host in refused:
        assert p.refusal(origin, host), (origin, host)
    assert "--allow-origin http://evil.example:8080" in p.refusal("http://evil.example:8080", "evil.example:8080")


# ---------------------------------------------------------------- browser values


@pytest.mark.parametrize("canvas", [(64000, 1), (10**9, 1), (10**30, 3), (1, 10**9), (5000, 5000)])
def test_frame_size_is_capped(canvas):
    w, h = frame_size(*canvas, 384)
    assert 2 <= w <= MAX_SIDE_PX and 2 <= h <= MAX_SIDE_PX


@pytest.mark.parametrize("canvas", [(0, 480), (640, 0), (-5, 480), (math.nan, 480), (math.inf, 480), ("x", 4)])
def test_canvas_without_pixels_is_refused(canvas):
    with pytest.raises(UserError):
        frame_size(*canvas, 384)


GOOD = dict(position=(10.0, -20.0, 80.0), wxyz=(0.0, 1.0, 0.0, 0.0), fov_rad=0.7, canvas_w=640, canvas_h=480)


@pytest.mark.parametrize("field, value", [("fov_rad", 0.0), ("fov_rad", math.nan), ("fov_rad", math.pi),
                                          ("fov_rad", -0.5), ("fov_rad", math.inf), ("fov_rad", None),
                                          ("position", (math.nan, 0.0, 1.0)), ("position", (1e30, 0.0, 1.0)),
                                          ("position", (1.0, 2.0)), ("wxyz", (0.0, 0.0, 0.0, 0.0)),
                                          ("wxyz", (math.nan, 1.0, 0.0, 0.0)), ("canvas_h", 0)])
def test_bad_cameras_are_refused(field, value):
    with pytest.raises(UserError):
        client_view(**{**GOOD, field: value}, height_px=384)


def test_a_good_camera():
    c2w, intr = client_view(**GOOD, height_px=384)
    assert (intr.w, intr.h) == (512, 384) and np.isfinite(c2w).all()
    assert intr.fl_y == pytest.approx(192 / math.tan(0.35))


@pytest.mark.parametrize("pos", [(math.nan, 0.5), (1.5, 0.5), (-0.1, 0.2), (0.5,), "ab"])
def test_bad_click_positions(pos):
    with pytest.raises(UserError):
        screen_point(pos)


@pytest.mark.parametrize("name", ["../evil", "..", ".hidden", "a/b", "a\\b", "", " ", "x" * 65, "/tmp/x", "a..b",
                                  "roi\x00", "-rf"])
def test_roi_names_that_are_not_plain_folder_names(name):
    with pytest.raises(UserError) as e:
        roi_name(name)
    assert e.value.field == "ROI name"


def test_constant_division_by_zero_is_nan():
    f = parse_formula("0/0*b860")
    assert np.isnan(f.evaluate({860.0: np.ones((2, 2))})).all()
    assert np.isnan(parse_formula("b860/0").evaluate({860.0: np.ones(3)})).all()
    assert np.isnan(parse_formula("1e308*1e308*b860").evaluate({860.0: np.ones(3)})).all()
    with pytest.raises(UserError):
        parse_formula("b860\x00")


def test_saved_rois_never_overwrite_and_stay_in_their_folder(tmp_path):
    from brfgs.viewer.roi import disc_roi, roi_spectrum, save_roi_folder
    from brfgs.products.maps import nadir_camera
    tm = synthetic_model(n_gaussians=500)
    c2w, intr = nadir_camera(tm, size=32)
    res = roi_spectrum(tm, disc_roi(tm.scene_centre_m(), 5.0), c2w, intr, (30.0, 100.0))
    out = tmp_path / "run" / "viewer_rois"
    assert save_roi_folder(res, out).name == "roi_01" and save_roi_folder(res, out).name == "roi_02"
    assert save_roi_folder(res, out, "field_a").name == "field_a"
    before = (out / "field_a" / "spectrum.csv").read_bytes()
    with pytest.raises(UserError) as e:
        save_roi_folder(res, out, "field_a")
    assert "exists" in str(e.value) and (out / "field_a" / "spectrum.csv").read_bytes() == before
    with pytest.raises(UserError):
        save_roi_folder(res, out, "../evil")
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["viewer_rois"]


# ---------------------------------------------------------------- the command, driven by hostile clients

viser = pytest.importorskip("viser", reason="viser is not installed (pip install 'brfgs[viewer]')")
import msgspec  # noqa: E402  (viser's dependencies)
import zstandard  # noqa: E402
from websockets.exceptions import InvalidStatus  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

from brfgs.viewer.cameras import viser_from_c2w  # noqa: E402
from brfgs.data.cameras import pose_from_view_angles  # noqa: E402

PROTOCOL = f"viser-v{viser.__version__}"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """``brfgs view`` of a small synthetic model in a subprocess: (port, pid, run folder, output lines)."""
    root = tmp_path_factory.mktemp("served")
    tm = synthetic_model(n_gaussians=20000)  # ground covered: a click at the centre hits it
    tm.save(root / "run" / "model.safetensors")
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "brfgs", "view", str(root / "run"), "--port", str(port), "--height",
                             "96", "--moving-height", "48", "--seconds", "600", "--polar-azimuths", "4",
                             "--polar-zeniths", "2", "--roi-step-deg", "25"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
    t_end = time.monotonic() + 120
    while not any("http://" in line for line in lines) and time.monotonic() < t_end and proc.poll() is None:
        time.sleep(0.2)
    assert any("http://" in line for line in lines), "".join(lines)
    centre, dist = tm.scene_centre_m(), tm.typical_distance_m()
    yield {"port": port, "pid": proc.pid, "run": root / "run", "lines": lines,
           "camera": viser_from_c2w(pose_from_view_angles(20.0, 30.0, dist, centre))}
    proc.terminate()
    proc.wait(timeout=30)


def _handshake(port: int, origin: str | None, host: str) -> str:
    """The status line of a raw websocket handshake with these Origin and Host headers."""
    head = [f"GET / HTTP/1.1", f"Host: {host}", "Upgrade: websocket", "Connection: Upgrade",
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13",
            f"Sec-WebSocket-Protocol: {PROTOCOL}"] + ([f"Origin: {origin}"] if origin is not None else [])
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        s.sendall(("\r\n".join(head) + "\r\n\r\n").encode())
        return s.recv(4096).decode(errors="replace").split("\r\n", 1)[0]


def test_foreign_origins_are_refused_at_the_handshake(served):
    port = served["port"]
    assert " 101 " in _handshake(port, f"http://127.0.0.1:{port}", f"127.0.0.1:{port}")
    assert " 101 " in _handshake(port, f"http://localhost:{port}", f"localhost:{port}")
    for origin, host in [("http://evil.example", f"127.0.0.1:{port}"), (None, f"127.0.0.1:{port}"),
                         (f"http://evil.example:{port}", f"evil.example:{port}"), ("null", f"127.0.0.1:{port}")]:
        assert " 403 " in _handshake(port, origin, host), (origin, host)
    with pytest.raises(InvalidStatus):
        connect(f"ws://127.0.0.1:{port}", origin="http://evil.example", subprotocols=[PROTOCOL], open_timeout=20)
    assert any("refused a connection" in line and "evil.example" in line for line in served["lines"])


class _Client:
    """A websocket client speaking viser's protocol (msgpack out; zstd-compressed msgpack windows in)."""

    def __init__(self, served):
        port = served["port"]
        self.ws = connect(f"ws://127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}", subprotocols=[PROTOCOL],
                          max_size=None, open_timeout=20)
        self.pos, self.wxyz = (np.asarray(v, float).tolist() for v in served["camera"])
        self.messages: list[dict] = []
        self.uuids: dict[str, str] = {}  # widget label -> uuid
        self.camera()

    def send(self, kind: str, **fields) -> None:
        self.ws.send(msgspec.msgpack.encode({"type": kind, **fields}))

    def camera(self, **over) -> None:
        msg = dict(wxyz=list(self.wxyz), position=list(self.pos), fov=0.7, near=0.1, far=1e4, image_height=480,
                   image_width=640, look_at=[0.0, 0.0, 0.0], up_direction=[0.0, 0.0, 1.0])
        self.send("ViewerCameraMessage", **{**msg, **over})

    def pump(self, seconds: float) -> list[dict]:
        new, t_end = [], time.monotonic() + seconds
        while time.monotonic() < t_end:
            try:
                raw = self.ws.recv(timeout=max(t_end - time.monotonic(), 0.01))
            except TimeoutError:
                break
            n_inner, n_comp = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
            inner = zstandard.ZstdDecompressor().decompress(raw[16:16 + n_comp], max_output_size=n_inner)
            new += msgspec.msgpack.decode(inner)["messages"]
        self.messages += new
        for m in new:
            if m["type"].startswith("Gui") and isinstance(m.get("props"), dict) and "label" in m["props"]:
                self.uuids[m["props"]["label"]] = m["uuid"]
        return new

    def wait(self, pred, timeout: float, what: str) -> dict:
        t_end = time.monotonic() + timeout
        seen = list(self.messages)
        while True:
            for m in seen:
                if pred(m):
                    return m
            assert time.monotonic() < t_end, f"timed out waiting for {what}"
            seen = self.pump(0.5)

    def frame_after(self, timeout: float = 60.0) -> dict:
        """A background image sent after this call (the client is still served)."""
        self.messages.clear()
        self.camera(position=[p + 0.01 * float(np.random.rand()) for p in self.pos])
        return self.wait(lambda m: m["type"] == "BackgroundImageMessage", timeout, "a frame")

    def uuid_of(self, label: str) -> str:
        t_end = time.monotonic() + 30
        while label not in self.uuids:
            assert time.monotonic() < t_end, f"no widget {label!r}"
            self.pump(0.5)
        return self.uuids[label]

    def texts(self) -> str:
        return " ".join(_strings(self.messages))


def _strings(obj):
    if isinstance(obj, str):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from _strings(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from _strings(v)


@pytest.fixture(scope="module")
def clients(served):
    a, b = _Client(served), _Client(served)
    a.wait(lambda m: m["type"] == "BackgroundImageMessage", 60, "the first frame")
    yield a, b
    a.ws.close()
    b.ws.close()


@pytest.mark.parametrize("bad", [dict(image_width=64000, image_height=1), dict(image_width=10**9, image_height=1),
                                 dict(image_width=0, image_height=480), dict(fov=0.0), dict(fov=float("nan")),
                                 dict(fov=math.pi), dict(position=[float("nan"), 0.0, 1.0]),
                                 dict(wxyz=[0.0, 0.0, 0.0, 0.0])])
def test_a_hostile_camera_costs_one_status_line_and_the_client_stays_served(clients, bad):
    a, b = clients
    a.messages.clear()
    b.pump(0.1)
    b.messages.clear()
    a.camera(**bad)
    a.pump(3.0)
    text = a.texts()
    big = ("image_width" in bad and bad["image_width"] >= 64000)
    if not big:  # refused: said in this client's status line, not in the other's
        assert "⚠" in text, text[-500:]
    assert "⚠" not in " ".join(_strings(b.pump(0.5)))
    a.frame_after()


@pytest.mark.parametrize("label, value, says", [("Sun zenith (deg)", 1e9, "Sun zenith"),
                                                ("Sun zenith (deg)", "nan", "Sun zenith"),
                                                ("Sun azimuth (deg)", -40.0, "Sun azimuth"),
                                                ("Band (nm)", 5000.0, "Band"), ("Mode", "rainbow", "Mode"),
                                                ("ROI radius (m)", 0.0, "ROI radius"),
                                                ("Index formula", "__import__('os').system('x')", "formula")])
def test_a_hostile_widget_value_is_refused_and_told(clients, label, value, says):
    a, _ = clients
    uuid = a.uuid_of(label)
    a.messages.clear()
    a.send("GuiUpdateMessage", uuid=uuid, updates={"value": value})
    m = a.wait(lambda m: m["type"] == "NotificationShowMessage" and says in " ".join(_strings(m)), 20,
               f"the notification about {label}")
    assert "Not applied" in " ".join(_strings(m))
    a.frame_after()


def test_formula_dividing_by_zero_renders(clients):
    a, _ = clients
    mode, formula = a.uuid_of("Mode"), a.uuid_of("Index formula")
    a.send("GuiUpdateMessage", uuid=formula, updates={"value": "0/0*b860"})
    a.send("GuiUpdateMessage", uuid=mode, updates={"value": "index"})
    a.frame_after()
    a.pump(1.0)
    assert "Not applied" not in a.texts() and "⚠" not in a.texts()
    a.send("GuiUpdateMessage", uuid=mode, updates={"value": "cir"})


def _click(client, x: float, y: float) -> None:
    client.send("ScenePointerMessage", event_type="click", ray_origin=list(client.pos),
                ray_direction=[0.0, 0.0, -1.0], screen_pos=[[x, y]], modifier=None)


def test_clicks_and_roi_names_from_a_hostile_client(clients, served):
    a, _ = clients
    a.messages.clear()
    _click(a, float("nan"), 0.5)
    a.wait(lambda m: m["type"] == "NotificationShowMessage" and "click position" in " ".join(_strings(m)), 20,
           "the refused click")
    _click(a, 0.5, 0.5)
    a.wait(lambda m: "BRF ready" in " ".join(_strings(m)), 120, "the ROI's BRF")
    out = served["run"] / "viewer_rois"
    name, save = a.uuid_of("ROI name"), a.uuid_of("Save ROI (CSV + GeoJSON)")
    for bad in ("../evil", "../../evil", "/tmp/evil", "..", "a/../../evil"):
        a.messages.clear()
        a.send("GuiUpdateMessage", uuid=name, updates={"value": bad})
        a.send("GuiUpdateMessage", uuid=save, updates={"value": True})
        a.wait(lambda m: m["type"] == "NotificationShowMessage" and "ROI not saved" in " ".join(_strings(m)), 20,
               f"the refused name {bad!r}")
    a.send("GuiUpdateMessage", uuid=name, updates={"value": "field_a"})
    a.send("GuiUpdateMessage", uuid=save, updates={"value": True})
    a.wait(lambda m: m["type"] == "NotificationShowMessage" and "ROI saved" in " ".join(_strings(m)), 20, "saved")
    a.messages.clear()
    a.send("GuiUpdateMessage", uuid=save, updates={"value": True})  # the same name again: never overwritten
    a.wait(lambda m: m["type"] == "NotificationShowMessage" and "exists" in " ".join(_strings(m)), 20, "exists")
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["field_a"]
    assert sorted(p.name for p in served["run"].iterdir()) == ["model.safetensors", "viewer_rois"]
    assert not any(p.name == "evil" for p in served["run"].parent.rglob("*"))
    a.frame_after()


def test_server_peak_memory_stays_below_2_gb(served, clients):
    status = open(f"/proc/{served['pid']}/status").read()
    peak_kb = int(next(line for line in status.splitlines() if line.startswith("VmHWM")).split()[1])
    assert peak_kb < 2 * 1024 * 1024, f"peak RSS {peak_kb / 1024:.0f} MiB"
