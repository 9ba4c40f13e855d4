"""Options of ``brfgs select-bands`` (light: the command line builds its options from it at start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.data.options import SceneReadOptions
from brfgs.errors import UserError

STRATEGIES = ("efc", "efc-top1", "efc-top3", "all", "rgb", "cir", "central", "max-snr", "max-features")
DEFAULT_DETECT_MAX_PX = 512  # features are detected on an integer-downscaled copy above this long side
# at most this many million band-image pixels (views x bands x pixels of the copy) per scene: more views
# than fit are thinned to an evenly spread subset (a 49-view 256² scene of 164 bands is 527 M: all views)
DEFAULT_DETECT_MAX_MPX = 600.0


@dataclass
class SelectBandsOptions:
    """Which bands carry the geometry: the strategy, its k, where the result goes."""

    read: SceneReadOptions = field(default_factory=SceneReadOptions, metadata={"flatten": True})
    strategy: str = field(default="efc", metadata={
        "help": "efc (top k by EFC, the method), efc-top1, efc-top3, all, rgb, cir, central, max-snr, max-features.",
        "aliases": ("-s",)})
    top: int = field(default=3, metadata={"help": "k of the efc strategy.", "aliases": ("-k",)})
    min_separation_nm: float = field(default=0.0, metadata={
        "help": "EFC strategies: chosen bands at least this far apart in wavelength (0 = paper eq. 8)."})
    detect_max_px: int = field(default=DEFAULT_DETECT_MAX_PX, metadata={
        "help": "Detect features on an integer-downscaled copy when the long side is larger (px)."})
    detect_max_mpx: float = field(default=DEFAULT_DETECT_MAX_MPX, metadata={
        "help": "At most this many million band-image pixels (views x bands x pixels) are searched for features; "
                "more views are thinned to an evenly spread subset (0 = every view)."})
    out: Optional[Path] = field(default=None, metadata={
        "help": "Folder for bands.json and bands.png (default: ./bands_<scene>).", "aliases": ("-o",)})
    overwrite: bool = field(default=False, metadata={"help": "Replace an existing bands.json in --out."})
    quiet: bool = field(default=False, metadata={"help": "No progress bar.", "aliases": ("-q",)})

    def validate(self) -> "SelectBandsOptions":
        self.read.validate()
        if self.top < 1 or self.detect_max_px < 16 or self.min_separation_nm < 0:
            raise UserError("expected --top >= 1, --detect-max-px >= 16 and --min-separation-nm >= 0", field="--top")
        if not self.detect_max_mpx >= 0:
            raise UserError(f"expected a number >= 0, got {self.detect_max_mpx}", field="--detect-max-mpx")
        return self
