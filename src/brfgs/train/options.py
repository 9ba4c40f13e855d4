"""Options of the ``brfgs train`` and ``brfgs ablate`` commands: the training options
(:class:`brfgs.train.config.TrainConfig`) and what the command does around them. Light, so that the
command line builds its options from them at start-up."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.train.config import TrainConfig

RUN = "Run"


def _run(default, help: str, **meta):
    return field(default=default, metadata={"help": help, "panel": RUN, **meta})


@dataclass
class TrainCommandOptions:
    """``brfgs train``: the training options, and how this call runs them."""

    train: TrainConfig = field(default_factory=TrainConfig, metadata={"flatten": True})
    config: Optional[Path] = _run(None, "Train with a run's config.json (options given here override it).")
    from_stage1: Optional[Path] = _run(None, "Start stage 2 from another run's checkpoints/stage1.safetensors: "
                                             "its geometry only (SCENE's frames and fields and these options are "
                                             "trained; SCENE must have the same frames).")
    evaluate: bool = _run(True, "Evaluate the held-out views after training.", flag="--evaluate/--no-evaluate")
    overwrite: bool = _run(False, "Replace a finished run in OUT.")
    quiet: bool = _run(False, "No progress bars.")
    nproc: int = field(default=1, metadata={"help": "Data-parallel training in this many local processes.",
                                            "panel": "Compute"})
    distributed: bool = field(default=False, metadata={"help": "Be one rank of a torchrun process group.",
                                                       "panel": "Compute"})


# the options an ablation study sets itself for each of its runs
STUDY_FIELDS = ("variant", "components", "joint", "band_strategy")
STUDIES = ("kernels", "training", "bands", "baselines", "additions")


@dataclass
class AblateOptions:
    """``brfgs ablate``: the study, which of its runs to train now, and the training options of all of them."""

    study: str = field(metadata={
        "help": "kernels (Table 3), training (Table 4), bands (Table 2), baselines (Table 1) or additions (each "
                "addition removed and added).", "panel": RUN})
    train: TrainConfig = field(default_factory=TrainConfig, metadata={"flatten": True})
    only: Optional[tuple[str, ...]] = _run(None, "Comma-separated run names of the study to train now.")
    quiet: bool = _run(False, "No progress bars.")
