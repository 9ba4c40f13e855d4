"""A training run's folder: what it holds, how it is prepared, and its status file.

``OUT/`` holds config.json (the options, loadable by ``brfgs train --config``), split.json,
bands.json, init/ (points, cameras, report), autoencoder.json, checkpoints/last.safetensors
and checkpoints/previous.safetensors (the newest two resume states: a damaged newest one is
skipped), checkpoints/stage1.safetensors, model.safetensors (final), train_log.csv
and run.json (status, phase, step). Rerunning on an unfinished folder resumes; a finished one
is refused without ``overwrite``, and then only these outputs are removed.
"""

from __future__ import annotations

import csv
import json
import shutil
from dataclasses import replace
from pathlib import Path

from brfgs.data import atomic
from brfgs.data.lock import LOCK_NAME
from brfgs.errors import UserError
from brfgs.model import MODEL_FILE
from brfgs.train.config import TrainConfig

RUN_FILE = "run.json"
CONFIG_FILE = "config.json"
LOG_FILE = "train_log.csv"
LAST_CKPT = "checkpoints/last.safetensors"
PREVIOUS_CKPT = "checkpoints/previous.safetensors"
STAGE1_CKPT = "checkpoints/stage1.safetensors"
LOG_HEADER = ["phase", "step", "loss", "psnr", "n_gaussians"]
OWNED_OUTPUTS = (CONFIG_FILE, "split.json", "bands.json", "autoencoder.json", LOG_FILE, RUN_FILE,
                 MODEL_FILE, "checkpoints", "init", "metrics.json", "eval")


RUN_STATES = ("running", "interrupted", "finished")


def run_status(out: Path) -> str | None:
    """Status recorded in ``out/run.json`` ("running", "interrupted", "finished"); "finished" for a
    folder with a model file but no run.json; None for no run. UserError naming run.json when it is
    damaged."""
    p = Path(out) / RUN_FILE
    if not p.is_file():
        return "finished" if (Path(out) / MODEL_FILE).is_file() else None
    try:
        status = json.loads(p.read_text()).get("status")
    except (OSError, ValueError, AttributeError, RecursionError):
        status = None
    if status not in RUN_STATES:
        raise UserError("damaged run status (not a JSON object with a status of "
                        f"{', '.join(RUN_STATES)}); pass --overwrite to start again", file=p, field="status")
    return status


class RunFolder:
    """Paths of one run folder and the files the trainer writes there besides checkpoints."""

    def __init__(self, out: str | Path):
        self.out = Path(out)
        self.model = self.out / MODEL_FILE
        self.last_ckpt = self.out / LAST_CKPT
        self.previous_ckpt = self.out / PREVIOUS_CKPT
        self.stage1_ckpt = self.out / STAGE1_CKPT
        self.log = self.out / LOG_FILE

    def prepare(self, cfg: TrainConfig, overwrite: bool) -> None:
        """Create the folder; refuse a finished run (unless ``overwrite``), a foreign non-empty
        folder, or resuming an unfinished run with other options; write config.json."""
        try:
            status = run_status(self.out)
        except UserError:
            if not overwrite:
                raise
            status = "interrupted"  # a damaged status file: --overwrite starts again
        if status == "finished" and not overwrite:
            raise UserError("a finished training run exists here; pass --overwrite to replace it "
                            "(or choose another output folder)", file=self.out)
        if status is not None and overwrite:
            self._remove_outputs()
        elif status is None and self.out.exists() and any(p.name != LOCK_NAME for p in self.out.iterdir()) \
                and not self.resume_points():
            foreign = [p.name for p in self.out.iterdir() if p.name not in OWNED_OUTPUTS and p.name != LOCK_NAME]
            if foreign:
                raise UserError(f"output folder is not empty and is not a brfgs run (contains {foreign[:5]}); "
                                "choose an empty or new folder", file=self.out)
        self.out.mkdir(parents=True, exist_ok=True)
        config = self.out / CONFIG_FILE
        if config.is_file() and self.resume_points():
            # options added since the run started take their defaults, or the behaviour the run had
            # before them where the default changed later (BEFORE_OPTION)
            diff = TrainConfig.from_run_config(config).changed_options(cfg)
            if diff:
                raise UserError(f"this unfinished run was started with different options ({', '.join(diff)}); "
                                "rerun with the same options to resume, or pass --overwrite", file=config)
        atomic.write_json(config, cfg.to_dict(), sort_keys=True)

    def started_cap(self, cfg: TrainConfig) -> TrainConfig:
        """``cfg`` with the fixed Gaussian cap of the unfinished run it resumes, when ``cfg`` leaves the cap
        to follow the image (``max_gaussians`` 0): a run started with a cap (as every run was before the cap
        followed the image) finishes with it. Unchanged when there is nothing to resume."""
        config = self.out / CONFIG_FILE
        if cfg.max_gaussians != 0 or not config.is_file() or not self.resume_points():
            return cfg
        try:
            started = TrainConfig.from_run_config(config).max_gaussians
        except UserError:
            return cfg  # prepare() reports the damaged file
        return replace(cfg, max_gaussians=started) if started > 0 else cfg

    def resume_points(self) -> list[Path]:
        """Existing resume checkpoints, newest first."""
        return [p for p in (self.last_ckpt, self.previous_ckpt) if p.is_file()]

    def rotate_checkpoints(self) -> Path:
        """Make room for a new newest checkpoint (the current one becomes the previous); returns its path."""
        if self.last_ckpt.is_file():
            self.last_ckpt.replace(self.previous_ckpt)
        return self.last_ckpt

    def truncate_log(self, keep) -> None:
        """Drop the rows of train_log.csv for which ``keep(phase, step)`` is false (steps a resumed
        run repeats), so that no (phase, step) appears twice."""
        if not self.log.is_file():
            return
        body = [r for r in self._log_rows() if keep(r[0], int(r[1]))]
        with atomic.atomic_path(self.log) as tmp, open(tmp, "w", newline="") as fh:
            csv.writer(fh).writerows([LOG_HEADER] + body)

    def _log_rows(self) -> list[list[str]]:
        """The whole data rows of train_log.csv (a header, a torn last line or other junk left out)."""
        with open(self.log, newline="") as fh:
            rows = list(csv.reader(fh))
        return [r for r in rows if len(r) == len(LOG_HEADER) and r[1].isdigit()]

    def _remove_outputs(self) -> None:
        """Remove only what a training run writes."""
        for name in OWNED_OUTPUTS:
            p = self.out / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()

    def write_json(self, name: str, obj) -> Path:
        """Write ``obj`` as indented JSON to ``out/name``."""
        return atomic.write_json(self.out / name, obj)

    def write_status(self, info: dict) -> None:
        """Atomically replace run.json with ``info``."""
        atomic.write_json(self.out / RUN_FILE, info)

    def open_log(self):
        """(file handle, csv writer) appending to train_log.csv, the header written once."""
        if self.log.exists() and self.log.read_text().splitlines()[:1] != [",".join(LOG_HEADER)]:
            rows = self._log_rows()  # a kill lost the header (or tore a line): write the file again
            with atomic.atomic_path(self.log) as tmp, open(tmp, "w", newline="") as fh:
                csv.writer(fh).writerows([LOG_HEADER] + rows)
        new = not self.log.exists()
        fh = open(self.log, "a", newline="")
        writer = csv.writer(fh)
        if new:
            writer.writerow(LOG_HEADER)
        return fh, writer
