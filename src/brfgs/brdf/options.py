"""Options of ``brfgs kernels`` (light: the command line builds its options from them at start-up)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.errors import UserError


def _f(default, help: str, **meta):
    return field(default=default, metadata={"help": help, **meta})


@dataclass
class KernelsOptions:
    """Which kernels are drawn and where (the grid of view directions, the files)."""

    sun_zenith_deg: float = _f(30.0, "Sun zenith (deg, 0-89).", flag="--sun-zenith")
    roughness: float = _f(0.3, "GGX roughness of the Cook-Torrance kernel, (0, 1].")
    step_deg: float = _f(2.0, "Grid step of view zenith and relative azimuth (deg, (0, 30]).", flag="--step")
    max_view_zenith_deg: float = _f(80.0, "Largest view zenith of the grid (deg, (0, 89]).", flag="--max-view-zenith")
    out: Path = _f(Path("."), "Folder for the figure (created if needed).", aliases=("--out-dir",))
    png: Optional[Path] = _f(None, "PNG path (default: OUT/kernels_sun<Z>.png).")
    csv: Optional[Path] = _f(None, "Also write the grid values to this CSV file.")
    plot: bool = _f(True, "Draw the figure (--no-plot: only the CSV).", flag="--plot/--no-plot")
    overwrite: bool = _f(False, "Replace existing output files.")

    def validate(self) -> "KernelsOptions":
        def bad(cond, msg, flag):
            if cond:
                raise UserError(msg, field=flag)

        z, r, st, mx = self.sun_zenith_deg, self.roughness, self.step_deg, self.max_view_zenith_deg
        bad(not math.isfinite(z) or not 0.0 <= z <= 89.0, f"sun zenith must be in [0, 89] degrees, got {z}",
            "--sun-zenith")
        bad(not math.isfinite(r) or not 0.0 < r <= 1.0, f"roughness must be in (0, 1], got {r}", "--roughness")
        bad(not math.isfinite(st) or not 0.0 < st <= 30.0, f"step must be in (0, 30] degrees, got {st}", "--step")
        bad(not math.isfinite(mx) or not 0.0 < mx <= 89.0, f"max view zenith must be in (0, 89] degrees, got {mx}",
            "--max-view-zenith")
        bad(st > mx, f"step ({st}) is larger than the max view zenith ({mx})", "--step")
        bad(not self.plot and self.csv is None, "--no-plot needs --csv (nothing to write otherwise)", "--no-plot")
        return self
