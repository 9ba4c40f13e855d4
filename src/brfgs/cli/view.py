"""``brfgs view RUN``: the live web viewer (viser) of a trained model (brfgs.viewer, docs/viewer.md)."""

from __future__ import annotations

import time
from pathlib import Path
import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.errors import UserError
from brfgs.viewer.options import ViewerOptions

# The command body imports the library and viser lazily: `brfgs --help` stays fast and viser is optional.


def view_cmd(run: Path, opts: ViewerOptions) -> None:
    """Serve the viewer of the model in ``run`` until Ctrl-C (or ``opts.seconds``)."""
    from brfgs.model import TrainedModel
    from brfgs.viewer.ports import check_port_free

    opts.validate()
    tm = TrainedModel.load(run)
    check_port_free(opts.host, opts.port)
    try:
        import viser  # noqa: F401  lazy: optional dependency (pip install brfgs[viewer])
    except ImportError:
        raise UserError("the viewer needs viser: pip install 'brfgs[viewer]' (or pip install viser)",
                        field="viser") from None
    from brfgs.viewer.serve import start_server
    from brfgs.viewer.server import Viewer, warm_up

    if opts.out_dir is None:
        opts.out_dir = (run if run.is_dir() else run.parent) / "viewer_rois"
    warm_s = warm_up(tm, opts.backend)  # before the URL: the first frames and clicks need no kernel loading
    server = start_server(opts.host, opts.port, opts.allow_origin, label=f"brfgs view {run}")
    Viewer(tm, server, opts)
    shown = "localhost" if opts.host in ("0.0.0.0", "127.0.0.1", "::", "::1") else opts.host
    typer.echo(f"brfgs viewer of {run}: http://{shown}:{opts.port}  (ready in {warm_s:.1f} s; over SSH: ssh -L "
               f"{opts.port}:localhost:{opts.port} HOST; Ctrl-C stops)", err=False)
    if opts.host not in ("127.0.0.1", "localhost", "::1"):
        typer.echo(f"listening on {opts.host}: every machine that can reach this address can open the viewer",
                   err=True)
    t_end = time.monotonic() + opts.seconds if opts.seconds > 0 else float("inf")
    try:
        while time.monotonic() < t_end:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


def register(app: typer.Typer) -> None:
    @config_command(app, "view", ViewerOptions)
    def command(run: Path = typer.Argument(..., help="Run folder (with model.safetensors) or a model file."),
                options: dict | None = None) -> None:
        """Serve a web page that renders the model live from the browser's camera: CIR, true colour, a band,
        an index (NDVI by default), depth, normals, alpha and each kernel's contribution; sun sliders;
        click the surface for an ROI's spectrum and BRF; the training and test cameras."""
        view_cmd(run, apply_options(ViewerOptions(), options))
