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
    stage1_steps: Optional[int] = field(default=None, metadata={
        "help": "Override the fast preset's stage-1 steps (given for 17 training views and scaled to the scene's "
                "like the preset's: --schedule-ref-views of brfgs train)."})
    stage2_steps: Optional[int] = field(default=None, metadata={
        "help": "Override the fast preset's stage-2 steps (given for 17 training views, scaled likewise)."})
    threads: int = field(default=0, metadata={"help": "CPU threads (0 = all)."})


@dataclass
class BatchConfig:
    """Options of ``brfgs batch`` that say where and how the scenes run (each is a command-line
    option; what each scene runs is in the manifest, :mod:`brfgs.workflows.manifest`)."""

    address: Optional[str] = field(default=None, metadata={
        "help": "Ray cluster to run on (ray.init(address=...): 'auto', 'HOST:6379' or 'ray://HOST:10001'; "
                "outputs must be on a file system the cluster's nodes and this machine share). Default: a local "
                "Ray on this machine."})
    retries: int = field(default=1, metadata={
        "help": "Run a scene that failed with an unexpected error (not an input error) this many times more "
                "(default 1)."})
    max_parallel: int = field(default=0, metadata={
        "help": "At most this many scenes at once (0 = as many as the CPUs/GPUs the scenes ask for allow)."})
    local_cpus: int = field(default=0, metadata={
        "help": "CPUs of the local Ray (0 = every core of this machine); ignored with --address."})
