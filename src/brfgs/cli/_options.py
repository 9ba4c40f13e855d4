"""Options shared by several commands (scene reading)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.errors import UserError

SceneArg = typer.Argument(..., help="Scene folder (transforms.json + images/, see README 'Data layout').",
                          show_default=False)
DownscaleOpt = typer.Option(1, "--downscale", min=1, help="Integer area-average factor applied while reading.")
ValueRangeOpt = typer.Option("-0.5,10", "--value-range", metavar="LO,HI",
                             help="Plausible reflectance range; finite values outside it are an error.")
SplitSeedOpt = typer.Option(0, "--split-seed", help="Seed of the deterministic 6:1 train/test split.")


def parse_value_range(text: str) -> tuple[float, float]:
    """'LO,HI' → (lo, hi); UserError if malformed."""
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"expected LO,HI (two numbers), got {text!r}", field="--value-range") from None
    if not lo < hi:
        raise UserError(f"expected LO < HI, got {text!r}", field="--value-range")
    return lo, hi


def load_scene(scene: Path, downscale: int = 1, value_range: str = "-0.5,10", split_seed: int = 0, **kw):
    """read_scene with the shared CLI options."""
    from brfgs.data import read_scene

    return read_scene(scene, downscale=downscale, value_range=parse_value_range(value_range),
                      split_seed=split_seed, **kw)


def check_output_dir(out: Path, scene_root: Path | None = None, overwrite: bool = False,
                     marker: str | None = None) -> None:
    """Refuse an output folder inside the scene folder, or a non-empty one unless ``overwrite``.

    ``marker``: a file whose presence means "a finished result is here" — only it blocks
    (other outputs may be regenerated) when given.
    """
    if scene_root is not None:
        try:
            out.resolve().relative_to(scene_root.resolve())
            raise UserError("output folder lies inside the scene folder; input data is never written to",
                            file=out)
        except ValueError:
            pass
    if out.exists() and not out.is_dir():
        raise UserError("output path exists and is not a folder", file=out)
    if overwrite or not out.exists():
        return
    if marker is not None:
        if (out / marker).exists():
            raise UserError(f"a finished result ({marker}) is already here; pass --overwrite to replace it",
                            file=out)
    elif any(out.iterdir()):
        raise UserError("output folder exists and is not empty; pass --overwrite to replace it", file=out)
