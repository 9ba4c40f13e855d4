"""Options of ``brfgs products`` and ``brfgs export`` (light: the command line builds its options from
them at start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.analysis.options import BACKEND_HELP, PROGRESS, check_range, check_size
from brfgs.errors import UserError

VIEW_DEPENDENCE = ("fit", "none")
UP_AXES = {"z": 0.0, "y": -90.0, "-y": 90.0}   # rotation about +x (deg) from ENU to the PLY frame
VIEWER_TARGETS = {"supersplat": "-y", "playcanvas": "-y", "enu": "z"}


def _f(default, help: str, **meta):
    return field(default=default, metadata={"help": help, **meta})


@dataclass
class ProductsOptions:
    """Options of ``brfgs products``; None means "the model's own" (see
    :func:`brfgs.products.report.products_report`)."""

    size: Optional[tuple[int, ...]] = _f(None, "Pixels W or W,H of the nadir map (default: the training images' "
                                         "footprint, at most 2048).", metavar="W[,H]")
    half_extent_m: Optional[float] = _f(None, "Half width of the mapped area (m) (default: half the Gaussians' 2-98 % "
                                        "extent).", flag="--half-extent")
    sun_zenith_deg: Optional[float] = _f(None, "Sun zenith (deg) of the contribution maps and ANIX (default: the "
                                         "training sun).", flag="--sun-zenith")
    nbar_sun_zenith_deg: Optional[float] = _f(None, "Sun zenith (deg) of NBAR (default: --sun-zenith).",
                                              flag="--nbar-sun-zenith")
    albedo_sun_zenith_deg: Optional[float] = _f(None, "Sun zenith (deg) of the black-sky albedo (default: "
                                                "--sun-zenith).", flag="--albedo-sun-zenith")
    min_alpha: float = _f(0.5, "Pixels whose accumulated opacity is below this are NaN in the products.")
    check_decoder: bool = _f(True, "Measure how far latent-space albedo is from integrating decoded spectra.",
                             flag="--check-decoder/--no-check-decoder")
    mcd43: bool = _f(True, "Fit MODIS MCD43 f_iso, f_vol, f_geo per pixel and band to the model's BRF and write "
                     "them with NBAR and albedo from them.", flag="--mcd43/--no-mcd43")
    out: Optional[Path] = _f(None, "Output folder (default: RUN/analysis/products).", aliases=("-o",))
    backend: str = _f("auto", BACKEND_HELP)
    overwrite: bool = _f(False, "Replace the results of an earlier products call in --out.")
    progress: bool = _f(True, "Progress bars (--quiet: none).", **PROGRESS)

    def validate(self) -> "ProductsOptions":
        check_range("min_alpha", self.min_alpha, 0.0, 1.0)
        check_range("half_extent_m", self.half_extent_m, 1e-6, flag="--half-extent")
        for name in ("sun_zenith_deg", "nbar_sun_zenith_deg", "albedo_sun_zenith_deg"):
            check_range(name, getattr(self, name), 0.0, 89.0, flag="--" + name.replace("_deg", "").replace("_", "-"))
        if self.size is not None:
            check_size(self.size)
        return self


@dataclass
class ExportOptions:
    """Options of ``brfgs export`` (see :func:`brfgs.products.export.export_model`)."""

    view_dependence: str = _f("fit", "fit: each Gaussian's view-dependent CIR colour (training sun) fitted as SH "
                              "degree 3, so viewers show the hotspot and glint; none: the nadir colour.")
    sh_directions: int = _f(48, "View directions (zenith <= 80 deg) sampled per Gaussian for the SH fit.")
    up: Optional[str] = _f(None, "Up axis of the PLY: z (the scene's ENU metres), y (y-up, glTF axes) or -y "
                           "(3DGS/COLMAP, as SuperSplat and PlayCanvas expect); the y frames are centred "
                           "(default: z).")
    target: Optional[str] = _f(None, "Named viewer: supersplat or playcanvas (= --up -y), enu (= --up z).",
                               flag="--for")
    scale: float = _f(1.0, "PLY units per metre.")
    centre: Optional[bool] = _f(None, "Centre on the scene (default: for the y frames).", flag="--centre/--no-centre")
    overwrite: bool = _f(False, "Replace an earlier export in OUT.")

    def validate(self) -> "ExportOptions":
        """``self`` with ``up`` resolved from ``--for``; UserError naming the option otherwise."""
        if self.target is not None and self.target not in VIEWER_TARGETS:
            raise UserError(f"expected one of {', '.join(VIEWER_TARGETS)}, got {self.target!r}", field="--for")
        if self.target is not None and self.up is not None and VIEWER_TARGETS[self.target] != self.up:
            raise UserError(f"--for {self.target} writes --up {VIEWER_TARGETS[self.target]}, not {self.up}",
                            field="--up")
        if self.up is None:
            self.up = VIEWER_TARGETS.get(self.target, "z")
        if self.up not in UP_AXES:
            raise UserError(f"expected one of {', '.join(UP_AXES)}, got {self.up!r}", field="--up")
        if self.view_dependence not in VIEW_DEPENDENCE:
            raise UserError(f"expected 'fit' or 'none', got {self.view_dependence!r}", field="--view-dependence")
        check_range("sh_directions", self.sh_directions, 16, 1024)
        if not self.scale > 0:
            raise UserError(f"scale must be > 0, got {self.scale}", field="--scale")
        return self
