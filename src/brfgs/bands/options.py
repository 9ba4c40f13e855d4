"""Options of ``brfgs select-bands`` (light: the command line builds its options from it at start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.data.options import SceneReadOptions
from brfgs.errors import UserError

STRATEGIES = ("efc", "efc-top1", "efc-top3", "all", "rgb", "cir", "central", "max-snr", "max-features")
DEFAULT_DETECT_MAX_PX = 1024  # features are detected on an integer-downscaled copy above this long side


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
    out: Optional[Path] = field(default=None, metadata={
        "help": "Folder for bands.json and bands.png (default: ./bands_<scene>).", "aliases": ("-o",)})
    overwrite: bool = field(default=False, metadata={"help": "Replace an existing bands.json in --out."})
    quiet: bool = field(default=False, metadata={"help": "No progress bar.", "aliases": ("-q",)})

    def validate(self) -> "SelectBandsOptions":
        self.read.validate()
        if self.top < 1 or self.detect_max_px < 16 or self.min_separation_nm < 0:
            raise UserError("expected --top >= 1, --detect-max-px >= 16 and --min-separation-nm >= 0", field="--top")
        return self
