"""Options of ``brfgs evaluate`` (light: the command line builds its options from them at start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.analysis.output import SPLITS
from brfgs.errors import UserError


@dataclass
class EvaluateOptions:
    """Which views of a run are scored, against which scene, and what is written."""

    scene: Optional[Path] = field(default=None, metadata={
        "help": "Scene folder (default: the one recorded in the model); another flight of the same site is "
                "rendered from its own cameras and scored into RUN/evaluate/<scene>-sun-<sun>/."})
    split: str = field(default="test", metadata={
        "help": "Views to score: test (metrics.json), validation (metrics_validation.json) or train (the fit)."})
    sun: str = field(default="scene", metadata={
        "help": "Sun of each rendered view: scene (each frame's own) or model (the sun the model was trained "
                "under: the prediction without relighting)."})
    backend: Optional[str] = field(default=None, metadata={
        "help": "Rasterizer: auto, torch, cpu or cuda (default: the one the model was trained with)."})
    images: bool = field(default=True, metadata={"help": "Write ENVI renders and CIR comparison PNGs.",
                                                 "flag": "--images/--no-images"})
    quiet: bool = field(default=False, metadata={"help": "No progress bar."})

    def validate(self) -> "EvaluateOptions":
        if self.split not in SPLITS:
            raise UserError(f"split must be one of {', '.join(SPLITS)}, got {self.split!r}", field="--split")
        if self.sun not in ("scene", "model"):
            raise UserError(f"sun must be scene or model, got {self.sun!r}", field="--sun")
        return self


@dataclass
class CompareOptions:
    """Options of ``brfgs compare``: which metrics files, the bootstrap, the output."""

    split: str = field(default="test", metadata={
        "help": "test (metrics.json), validation (metrics_validation.json) or train (metrics_train.json)."})
    against: str = field(default="truth", metadata={"help": "truth (simulated scenes) or observed."})
    scenes: bool = field(default=False, metadata={
        "help": "A and B list runs of several scenes, paired in order: each scene's row and the mean over the "
                "scenes (several pairs of one scene are its seeds, averaged per view)."})
    resamples: int = field(default=10_000, metadata={"help": "Bootstrap resamples of the views."})
    seed: int = field(default=0, metadata={"help": "Seed of the bootstrap."})
    json: Optional[Path] = field(default=None, metadata={"help": "Also write the comparison to this JSON file."})

    def validate(self) -> "CompareOptions":
        if self.split not in SPLITS:
            raise UserError(f"split must be one of {', '.join(SPLITS)}, got {self.split!r}", field="--split")
        return self
