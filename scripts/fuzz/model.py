"""A tiny trained model for the ROI and sun surfaces: the tests' synthetic carpet of Gaussians (a flat
20 m x 20 m surface at z = 0, 4 bands, identity decoder; tests/test_analysis_helpers.py) written once per
fuzz session as RUN/model.safetensors, which ``brfgs brf`` and ``brfgs render`` read like a trained run."""

from __future__ import annotations

import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parents[2] / "tests"
HALF_M = 10.0          # the carpet spans x, y in [-HALF_M, HALF_M] metres
BANDS_NM = (480, 860)  # wavelengths the brf cases ask for


def make_run(root: Path) -> Path:
    """RUN folder ``root`` with model.safetensors (a few seconds); returns ``root``."""
    if str(TESTS) not in sys.path:
        sys.path.insert(0, str(TESTS))
    import numpy as np
    from test_analysis_helpers import carpet_model, write_model_file

    tm = carpet_model(half_m=HALF_M, spacing_m=2.0, n_bands=4, z_left=np.linspace(0.1, 0.4, 4),
                      z_right=np.linspace(0.5, 0.1, 4), geo=0.2, components=("iso", "geo"))
    write_model_file(root / "model.safetensors", tm)
    return root


def brf_args(run: Path, roi: str, out: Path | None) -> list[str]:
    """The cheapest ``brfgs brf`` of an ROI: one band, 30° steps, no polar plot, 8 x 8 px renders;
    ``out`` None: the default output folder RUN/analysis/brf_<ROI name>."""
    return ["brf", str(run), "--roi", roi, "--bands", str(BANDS_NM[0]), "--step", "30", "--max-zenith", "60",
            "--no-polar", "--size", "8", "-q"] + ([] if out is None else ["-o", str(out)])


def render_args(run: Path, out: Path) -> list[str]:
    """The cheapest ``brfgs render`` of the model: nadir, 8 x 8 px."""
    return ["render", str(run), "--view-zenith", "0", "--view-azimuth", "0", "--size", "8", "-o", str(out), "-q"]
