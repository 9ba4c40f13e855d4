"""Options shared by several commands (scene reading; the analysis of a trained model)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.analysis.output import check_output_dir
from brfgs.errors import UserError

__all__ = ["SceneArg", "DownscaleOpt", "ValueRangeOpt", "SplitSeedOpt", "RunArg", "BackendOpt", "QuietOpt",
           "OverwriteOpt", "AllowLinksOpt", "parse_value_range", "load_scene", "check_output_dir"]

# The function bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).

SceneArg = typer.Argument(..., help="Scene folder (transforms.json + images/, see README 'Data layout').",
                          show_default=False)
DownscaleOpt = typer.Option(1, "--downscale", min=1, help="Integer area-average factor applied while reading.")
ValueRangeOpt = typer.Option("-0.5,10", "--value-range", metavar="LO,HI",
                             help="Plausible reflectance range: a frame with more than 5 % of its pixels above it or "
                                  "1 % below it is refused (a unit error); fewer are glints (above: kept) or bad "
                                  "pixels (below: masked).")
SplitSeedOpt = typer.Option(0, "--split-seed", help="Seed of the deterministic 6:1 train/test split.")
SplitRuleOpt = typer.Option("spread", "--split-rule", help="Which views of each ring are held out: spread "
                            "(farthest-point over the view directions) or random.")
AllowLinksOpt = typer.Option(False, "--allow-outside-links",
                             help="Read files that links in the scene folder lead to outside it (refused by default).")

RunArg = typer.Argument(..., help="Run folder of `brfgs train` (with model.safetensors) or a model file.",
                        show_default=False)
BackendOpt = typer.Option("auto", "--backend", help="Rasterizer backend: auto | torch | cpu | cuda.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="No progress bars.")
OverwriteOpt = typer.Option(False, "--overwrite", help="Replace the results of an earlier run of this command in --out.")


def parse_value_range(text: str) -> tuple[float, float]:
    """'LO,HI' → (lo, hi); UserError if malformed."""
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"expected LO,HI (two numbers), got {text!r}", field="--value-range") from None
    if not lo < hi:
        raise UserError(f"expected LO < HI, got {text!r}", field="--value-range")
    return lo, hi


def load_scene(scene: Path, downscale: int = 1, value_range: str = "-0.5,10", split_seed: int = 0,
               split_rule: str = "spread", **kw):
    """read_scene with the shared CLI options."""
    from brfgs.data import read_scene

    return read_scene(scene, downscale=downscale, value_range=parse_value_range(value_range),
                      split_seed=split_seed, split_rule=split_rule, **kw)
