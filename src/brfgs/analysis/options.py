"""Options of the analysis commands (``brfgs render``, ``brf``) and the parsing of text options
(comma-separated numbers, image sizes); light, so that the command line builds its options from them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.data.validation import ascii_float
from brfgs.errors import UserError

__all__ = ["parse_floats", "parse_size", "check_size", "MAX_IMAGE_PX", "RenderOptions", "BRFOptions", "TruthOptions"]

MAX_IMAGE_PX = 8192


def parse_floats(text: str, field: str, n: int | None = None) -> list[float]:
    """Finite numbers of the comma-separated ``text`` (empty items skipped), ``n`` of them when
    given; UserError naming ``field`` otherwise."""
    try:
        vals = [ascii_float(t.strip(" ")) for t in str(text).split(",") if t.strip(" ")]
    except ValueError:
        raise UserError(f"expected comma-separated numbers written with the digits 0-9, got {str(text)[:80]!r}",
                        field=field) from None
    if not vals or not all(math.isfinite(v) for v in vals):
        raise UserError(f"expected finite numbers, got {text!r}", field=field)
    if n is not None and len(vals) != n:
        raise UserError(f"expected {n} numbers, got {len(vals)}", field=field)
    return vals


def parse_size(text: str, field: str = "--size") -> tuple[int, int]:
    """(W, H) pixels of 'W' (square) or 'W,H', each 1..8192; UserError otherwise."""
    wh = parse_floats(text, field)
    check_size(wh, field)
    return int(wh[0]), int(wh[-1])


def check_size(wh: Sequence[float], field: str = "--size") -> None:
    """UserError unless ``wh`` is [W] or [W, H] of whole pixels in 1..8192."""
    if len(wh) not in (1, 2) or any(v != int(v) or v < 1 or v > MAX_IMAGE_PX for v in wh):
        raise UserError(f"expected W or W,H in pixels (1..{MAX_IMAGE_PX})", field=field)


def _f(default, help: str, **meta):
    """A dataclass field with its command-line help (and ``flag``, ``aliases``, ``metavar``, ``expert``)."""
    return field(default=default, metadata={"help": help, **meta})


def _required(help: str, **meta):
    return field(metadata={"help": help, **meta})


BACKEND_HELP = "Rasterizer: auto, torch, cpu or cuda."
PROGRESS = dict(flag="--progress/--quiet", aliases=(" /-q",))


def check_range(name: str, value, lo=None, hi=None, flag: str | None = None) -> None:
    """UserError naming ``flag`` (default ``--name``) unless lo <= value <= hi (None values pass)."""
    if value is None:
        return
    if (lo is not None and not value >= lo) or (hi is not None and not value <= hi):
        bounds = f">= {lo}" if hi is None else (f"<= {hi}" if lo is None else f"in [{lo}, {hi}]")
        raise UserError(f"{name} must be {bounds}, got {value}", field=flag or "--" + name.replace("_", "-"))


@dataclass
class RenderOptions:
    """Options of ``brfgs render``; None means "the model's own" (training sun, size, field of view,
    median camera distance, median Gaussian position)."""

    view_zenith_deg: float = _required("View zenith (deg, 0 = nadir, < 90).", flag="--view-zenith")
    view_azimuth_deg: float = _required("View azimuth (deg clockwise from north, from the target toward the sensor).",
                                        flag="--view-azimuth")
    sun_zenith_deg: Optional[float] = _f(None, "Sun zenith (deg) (default: the training sun).", flag="--sun-zenith")
    sun_azimuth_deg: Optional[float] = _f(None, "Sun azimuth (deg) (default: the training sun).", flag="--sun-azimuth")
    distance_m: Optional[float] = _f(None, "Camera distance to the target (m) (default: the training cameras' median).",
                                     flag="--distance")
    target_m: Optional[tuple[float, float, float]] = _f(None, "Point looked at, ENU m (default: the Gaussians' "
                                                        "median).", flag="--target", metavar="X,Y,Z")
    size: Optional[tuple[int, ...]] = _f(None, "Image size W or W,H in pixels (default: the training size).",
                                         metavar="W[,H]")
    fov_deg: Optional[float] = _f(None, "Horizontal field of view (deg) (default: the training camera's).",
                                  flag="--fov")
    path: Optional[str] = _f(None, "orbit (all azimuths at --view-zenith) or sweep (through nadir up to "
                             "--view-zenith): a PNG sequence and a GIF.")
    frames: int = _f(36, "Frames of --path.")
    repeat: int = _f(1, "Render this many times; timings report the median after the first call.")
    out: Optional[Path] = _f(None, "Output folder (default: RUN/analysis/render_z<Z>_a<A>).", aliases=("-o",))
    backend: str = _f("auto", BACKEND_HELP)
    overwrite: bool = _f(False, "Replace the results of an earlier render in --out.")
    progress: bool = _f(True, "Progress bars (--quiet: none).", **PROGRESS)

    def validate(self) -> "RenderOptions":
        check_range("frames", self.frames, 2)
        check_range("repeat", self.repeat, 1)
        if self.size is not None:
            check_size(self.size)
        return self


@dataclass
class TruthOptions:
    """Simulator truth renders of ``brfgs brf`` on simulated scenes (truth/scene.json)."""

    render: bool = _f(True, "On simulated scenes, render the truth again along the principal plane and on a coarse "
                      "polar grid and report the model's BRF error per band (slow).",
                      flag="--truth-render/--no-truth-render")
    step_deg: float = _f(10.0, "Principal-plane step of the truth renders (deg).", flag="--truth-step")
    size: int = _f(128, "Pixels of the principal-plane truth renders.", flag="--truth-size")
    polar_azimuths: int = _f(12, "Azimuth sectors of the truth polar grid.", flag="--truth-polar-azimuths")
    polar_zeniths: int = _f(6, "Zenith rings of the truth polar grid.", flag="--truth-polar-zeniths")
    polar_size: int = _f(64, "Pixels of the polar truth renders.", flag="--truth-polar-size")
    spp: int = _f(16, "Samples per pixel of the truth renders (a power of 4).", flag="--truth-spp")

    def validate(self) -> "TruthOptions":
        for name, lo in (("step_deg", 1.0), ("size", 16), ("polar_azimuths", 1), ("polar_zeniths", 1),
                         ("polar_size", 16), ("spp", 1)):
            check_range(name, getattr(self, name), lo, flag="--truth-" + name.replace("_deg", "").replace("_", "-"))
        return self


@dataclass
class BRFOptions:
    """Options of ``brfgs brf`` (see :func:`brfgs.analysis.brf_report.brf_report`)."""

    roi: str = _required("polygon:X1,Y1;X2,Y2;... (ENU m) | FILE.geojson (ENU m, or lon/lat with a CRS84 crs) | "
                         "lonlat:FILE | box:VIEW:C0,R0,C1,R1 | mask:VIEW:FILE | material:NAME (simulated scenes).")
    roi_name: Optional[str] = _f(None, "Name used in file names and titles.")
    bands_nm: tuple[float, ...] = _f((480.0, 680.0, 760.0, 860.0), "Wavelengths (nm) of the curves and maps.",
                                     flag="--bands")
    scene: Optional[Path] = _f(None, "Scene folder for observations and truth (default: the training scene).")
    sun_zenith_deg: Optional[float] = _f(None, "Sun zenith (deg) of the BRF (default: the --scene's sun, else the "
                                         "training sun).", flag="--sun-zenith")
    sun_azimuth_deg: Optional[float] = _f(None, "Sun azimuth (deg) of the BRF (default: as the zenith).",
                                          flag="--sun-azimuth")
    step_deg: float = _f(2.5, "Principal-plane step (deg).", flag="--step")
    max_zenith_deg: float = _f(75.0, "Largest view zenith (deg).", flag="--max-zenith")
    polar_azimuths: int = _f(60, "Azimuth sectors of the polar map.")
    polar_zeniths: int = _f(24, "Zenith rings of the polar map.")
    polar: bool = _f(True, "Draw the polar maps.", flag="--polar/--no-polar")
    min_alpha: float = _f(0.5, "Pixels count for the ROI only where the accumulated opacity is at least this.")
    distance_m: Optional[float] = _f(None, "ROI camera distance (m) (default: the training cameras' median, at least "
                                     "8 ROI radii).", flag="--distance")
    size: Optional[int] = _f(None, "Pixels of the square ROI camera (default: the training images' footprint).")
    truth: TruthOptions = field(default_factory=TruthOptions, metadata={"flatten": True})
    max_plane_offset_deg: float = _f(20.0, "Observations within this azimuth (deg) of the principal plane are "
                                     "plotted.", flag="--max-plane-offset")
    threads: int = _f(1, "PyTorch threads in the sampling loops (0 = as is).")
    out: Optional[Path] = _f(None, "Output folder (default: RUN/analysis/brf_<roi name>).", aliases=("-o",))
    backend: str = _f("auto", BACKEND_HELP)
    overwrite: bool = _f(False, "Replace the results of an earlier brf call in --out.")
    progress: bool = _f(True, "Progress bars (--quiet: none).", **PROGRESS)

    def validate(self) -> "BRFOptions":
        check_range("step_deg", self.step_deg, 0.1, flag="--step")
        check_range("max_zenith_deg", self.max_zenith_deg, 1.0, 85.0, flag="--max-zenith")
        check_range("sun_zenith_deg", self.sun_zenith_deg, 0.0, 89.0, flag="--sun-zenith")
        check_range("sun_azimuth_deg", self.sun_azimuth_deg, -360.0, 360.0, flag="--sun-azimuth")
        check_range("polar_azimuths", self.polar_azimuths, 4)
        check_range("polar_zeniths", self.polar_zeniths, 2)
        check_range("min_alpha", self.min_alpha, 0.0, 1.0)
        check_range("distance_m", self.distance_m, 1.0, flag="--distance")
        check_range("size", self.size, 8, 1024)
        check_range("threads", self.threads, 0)
        self.truth.validate()
        return self
