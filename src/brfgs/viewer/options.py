"""Options of ``brfgs view`` (light: the command line builds its options from them at start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.errors import UserError
from brfgs.viewer.origin import normalise_origin


def _f(default, help: str, **meta):
    return field(default=default, metadata={"help": help, **meta})


@dataclass
class ViewerOptions:
    """Where the viewer listens, the frame sizes moving and at rest, the backend, where ROIs are saved."""

    host: str = _f("127.0.0.1", "Address to listen on (127.0.0.1: this machine only; 0.0.0.0: every interface).")
    port: int = _f(8080, "Port to listen on (over SSH: ssh -L PORT:localhost:PORT).")
    height_px: int = _f(384, "Frame height in pixels at rest.", flag="--height")
    moving_height_px: int = _f(128, "Frame height in pixels while the camera moves.", flag="--moving-height")
    backend: str = _f("auto", "Rasterizer: auto, torch, cpu or cuda.")
    allow_origin: tuple[str, ...] = _f((), "Web origins besides the viewer's own page that may connect, e.g. a "
                                       "proxy's https://host (comma-separated).", metavar="ORIGINS")
    out_dir: Optional[Path] = _f(None, "Folder for saved ROIs (default: RUN/viewer_rois).", flag="--out")
    seconds: float = _f(0.0, "Stop after this many seconds (0: run until Ctrl-C).")
    settle_s: float = _f(0.25, "Seconds without camera motion before the full-size frame.", expert=True)
    roi_step_deg: float = _f(5.0, "Principal-plane step of a clicked ROI's BRF (deg).", expert=True)
    polar_azimuths: int = _f(24, "Azimuth sectors of a clicked ROI's polar map.", expert=True)
    polar_zeniths: int = _f(8, "Zenith rings of a clicked ROI's polar map.", expert=True)

    def validate(self) -> "ViewerOptions":
        for name, lo, hi in (("height_px", 32, 2160), ("moving_height_px", 16, 2160), ("port", 1, 65535),
                             ("polar_azimuths", 4, 360), ("polar_zeniths", 2, 90)):
            v = getattr(self, name)
            if not lo <= v <= hi:
                raise UserError(f"{name} must be in [{lo}, {hi}], got {v}", field="--" + name.replace("_px", "")
                                .replace("_", "-"))
        if not self.host.strip():
            raise UserError("the listening address must not be empty", field="--host")
        self.allow_origin = tuple(normalise_origin(o) for o in self.allow_origin)
        for name, ok, what in (("seconds", self.seconds >= 0, ">= 0"), ("settle_s", self.settle_s >= 0, ">= 0"),
                               ("roi_step_deg", 0 < self.roi_step_deg <= 30, "in (0, 30]")):
            if not ok:
                raise UserError(f"{name} must be {what}, got {getattr(self, name)}",
                                field="--" + name.replace("_", "-"))
        return self
