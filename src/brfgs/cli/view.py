"""``brfgs view RUN``: the live web viewer (viser) of a trained model (brfgs.viewer, docs/viewer.md)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from brfgs.cli._options import BackendOpt
from brfgs.errors import UserError

# The command body imports the library and viser lazily: `brfgs --help` stays fast and viser is optional.


def view_cmd(
    run: Path = typer.Argument(..., help="Run folder (with model.safetensors) or a model file."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on (0.0.0.0: every interface)."),
    port: int = typer.Option(8080, "--port", help="Port to listen on (over SSH: ssh -L PORT:localhost:PORT)."),
    height: int = typer.Option(384, "--height", min=32, max=2160, help="Frame height in pixels at rest."),
    moving_height: int = typer.Option(128, "--moving-height", min=16, max=2160,
                                      help="Frame height in pixels while the camera moves."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for saved ROIs (default RUN/viewer_rois)."),
    backend: str = BackendOpt,
    seconds: float = typer.Option(0.0, "--seconds", min=0.0, help="Stop after this many seconds (0: run until "
                                  "Ctrl-C)."),
) -> None:
    """Serve a web page that renders the model live from the browser's camera: CIR, true colour, a band,
    an index (NDVI by default), depth, normals, alpha and each kernel's contribution; sun sliders;
    click the surface for an ROI's spectrum and BRF; the training and test cameras as frustums."""
    from brfgs.model import TrainedModel
    from brfgs.viewer.ports import check_port_free

    tm = TrainedModel.load(run)
    check_port_free(host, port)
    try:
        import viser  # lazy: optional dependency (pip install brfgs[viewer])
    except ImportError:
        raise UserError("the viewer needs viser: pip install 'brfgs[viewer]' (or pip install viser)",
                        field="viser") from None
    from brfgs.viewer.server import Viewer, ViewerOptions

    default_out = (run if run.is_dir() else run.parent) / "viewer_rois"
    opts = ViewerOptions(host=host, port=port, height_px=height, moving_height_px=moving_height, backend=backend,
                         out_dir=out if out is not None else default_out)
    server = viser.ViserServer(host=host, port=port, label=f"brfgs view {run}", verbose=False)
    Viewer(tm, server, opts)
    shown = "localhost" if host in ("0.0.0.0", "127.0.0.1", "::") else host
    typer.echo(f"brfgs viewer of {run}: http://{shown}:{port}  (over SSH: ssh -L {port}:localhost:{port} HOST; "
               "Ctrl-C stops)", err=False)
    t_end = time.monotonic() + seconds if seconds > 0 else float("inf")
    try:
        while time.monotonic() < t_end:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


def register(app: typer.Typer) -> None:
    app.command("view")(view_cmd)
