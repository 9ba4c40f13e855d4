"""Options of the workflows (light: the command line builds its options from them at start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional


@dataclass
class DemoConfig:
    """Options of ``brfgs demo`` (each is a command-line option)."""

    size: int = field(default=64, metadata={"help": "Simulated image size (px)."})
    views: int = field(default=25, metadata={"help": "Simulated views (13, 25, 37 or 49)."})
    bands: int = field(default=164, metadata={"help": "Simulated bands over 350-1000 nm."})
    spp: int = field(default=16, metadata={"help": "Simulation samples per pixel (a power of 4)."})
    stage1_steps: Optional[int] = field(default=None, metadata={"help": "Override the fast preset's stage-1 steps."})
    stage2_steps: Optional[int] = field(default=None, metadata={"help": "Override the fast preset's stage-2 steps."})
    threads: int = field(default=0, metadata={"help": "CPU threads (0 = all)."})
