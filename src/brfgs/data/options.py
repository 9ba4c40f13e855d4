"""How a scene is read (``brfgs inspect``, ``select-bands``, ``init`` and the training options share
these): light, so that the command line can build its options from it at start-up."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.errors import UserError


@dataclass
class SceneReadOptions:
    """Options of reading a scene folder (:func:`brfgs.data.read_scene`)."""

    downscale: int = field(default=1, metadata={"help": "Read the cubes downscaled by this integer factor "
                                                        "(area average)."})
    value_range: tuple[float, float] = field(default=(-0.5, 10.0), metadata={
        "help": "Plausible reflectance range LO,HI: a frame with more than 5 % of its pixels above it or 1 % below "
                "is refused.", "metavar": "LO,HI"})
    allow_outside_links: bool = field(default=False, metadata={
        "help": "Read files that links in the scene folder lead to outside it.",
        "flag": "--allow-outside-links/--confine-to-scene"})

    def validate(self) -> "SceneReadOptions":
        if self.downscale < 1:
            raise UserError(f"downscale must be >= 1, got {self.downscale}", field="--downscale")
        if not self.value_range[0] < self.value_range[1]:
            raise UserError(f"expected LO < HI, got {self.value_range}", field="--value-range")
        return self


@dataclass
class InspectOptions:
    """Options of ``brfgs inspect``: reading the scene, its split, where the summary goes."""

    read: SceneReadOptions = field(default_factory=SceneReadOptions, metadata={"flatten": True})
    split_seed: int = field(default=0, metadata={"help": "Seed of the train/test split (6:1 per view ring)."})
    out: Optional[Path] = field(default=None, metadata={
        "help": "Folder for views_polar.png and summary.json (default: ./inspect_<scene>).", "aliases": ("-o",)})
    quiet: bool = field(default=False, metadata={"help": "No progress bar.", "aliases": ("-q",)})


@dataclass
class MergeOptions:
    """Options of ``brfgs merge``: the split each flight keeps."""

    split_seed: int = field(default=0, metadata={
        "help": "Seed of each flight's train/test split (train with the same --split-seed)."})
