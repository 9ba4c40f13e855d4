"""``brfgs batch MANIFEST``: train → evaluate → products for every scene of a manifest, as Ray tasks.

Each scene that is not finished becomes one Ray task (:func:`run_scene`) with the CPUs and GPUs
the manifest asks for (:mod:`brfgs.workflows.manifest`); Ray runs as many at once as the resources
allow, on this machine (``ray.init()``) or on a cluster (``address``). A task does what is missing
of the scene's outputs in its folder ``OUT/<name>/``: trains ``run/`` (an unfinished run resumes
from its checkpoint, a finished one is never trained again), evaluates the test views
(``run/metrics.json``) and writes the products (``run/analysis/products/``).

- A scene whose outputs are all there is skipped without a task ("skipped (finished)").
- An input error (:class:`UserError`: a corrupt cube, a missing file) is not retried: the task
  returns it and the summary shows its one-line message. Any other exception is retried up to
  ``retries`` times by Ray (``max_retries``, ``retry_exceptions``), then reported with its type,
  message and ``OUT/<name>/error.log`` (the tracebacks of every failed attempt).
- One failed scene never stops the others; OUT/summary.md/.csv/.json are rewritten after every
  scene (:mod:`brfgs.workflows.batch_summary`).

Ray is optional (``pip install 'brfgs[scale]'``); without it the command says so and exits 2.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import time
import traceback
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch

from brfgs.evaluation.evaluate import evaluate_run, metrics_file, summary_lines
from brfgs.products.report import ProductsOptions, products_report
from brfgs.data import atomic
from brfgs.data.paths import check_outside
from brfgs.errors import UserError
from brfgs.render import configure_threads
from brfgs.train import train
from brfgs.train.config import TrainConfig
from brfgs.train.run_folder import run_status
from brfgs.workflows.batch_summary import (ERROR_LOG, LOG_FILE, STATE_FILE, failure_lines, products_dir, read_state,
                                           scene_row, summary_markdown, write_summary)
from brfgs.workflows.batch_plan import eval_splits, plan_scene
from brfgs.workflows.manifest import BatchScene, Manifest
from brfgs.workflows.options import BatchConfig

try:  # the optional extra brfgs[scale]
    import ray
except ImportError:  # pragma: no cover - depends on the environment
    ray = None

INSTALL_HINT = "brfgs batch runs scenes as Ray tasks: install Ray with pip install 'brfgs[scale]'"
_TOKEN_LOGGER = "ray._private.authentication.authentication_token_setup"


# ------------------------------------------------------------------------------------------ one scene (a Ray task)
def scene_pipeline(s: BatchScene, log: Callable[[str], None]) -> None:
    """Train (or resume) → evaluate → products, each only when its output is missing."""
    cfg = TrainConfig.from_dict(s.config)
    threads = cfg.threads or s.num_cpus
    torch.set_num_threads(threads)
    configure_threads(threads)
    check_outside(s.out, s.scene)
    trained = False
    if run_status(s.run) != "finished":
        log(f"training {s.scene} -> {s.run}")
        train(s.scene, s.run, cfg, progress=False, log=log)
        trained = True
    for split in eval_splits(cfg.validation):
        if trained or not (s.run / metrics_file(split)).is_file():
            res = evaluate_run(s.run, s.scene, backend=cfg.backend, progress=False, split=split)
            for line in summary_lines(res):
                log(f"[{split}] {line}")
    if s.products is not None and not (products_dir(s) / "products.json").is_file():
        opts = ProductsOptions(**s.products, backend=cfg.backend, progress=False)
        log(products_report(s.run, opts, products_dir(s)).message)


def _logger(path: Path, name: str) -> Callable[..., None]:
    def log(*parts) -> None:
        with open(path, "a") as fh:
            fh.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} [{name}] {' '.join(str(p) for p in parts)}\n")

    return log


def _begin_attempt(s: BatchScene, batch_id: str) -> dict:
    """Count this attempt in OUT/<name>/batch.json (attempts and seconds add up within one batch)."""
    s.out.mkdir(parents=True, exist_ok=True)
    old = read_state(s)
    same = old.get("batch_id") == batch_id
    state = {"batch_id": batch_id, "attempts": (old.get("attempts", 0) if same else 0) + 1,
             "seconds": old.get("seconds", 0.0) if same else 0.0, "status": "running", "host": socket.gethostname(),
             "error": None, "error_type": None, "error_log": None}
    atomic.write_json(s.out / STATE_FILE, state)
    return state


def _end_attempt(s: BatchScene, state: dict, t0: float, error: BaseException | None = None,
                 trace: str | None = None) -> dict:
    """Record the attempt's outcome (and append a failure to OUT/<name>/error.log); returns the state."""
    state = dict(state, seconds=state["seconds"] + time.perf_counter() - t0,
                 status="finished" if error is None else "failed")
    if error is not None:
        kind = type(error).__name__
        state.update(error_type=kind, error_log=str(s.out / ERROR_LOG),
                     error=str(error) if isinstance(error, UserError) else f"{kind}: {error}")
        with open(s.out / ERROR_LOG, "a") as fh:
            fh.write(f"=== {time.strftime('%Y-%m-%d %H:%M:%S')} batch {state['batch_id']} attempt "
                     f"{state['attempts']} on {state['host']} (pid {os.getpid()})\n{trace or state['error']}\n")
    atomic.write_json(s.out / STATE_FILE, state)
    return state


def run_scene(s: BatchScene, batch_id: str, pipeline: Callable | None = None) -> dict:
    """One scene as a Ray task: :func:`scene_pipeline` (or ``pipeline``, for tests) with its attempt
    recorded in OUT/<name>/batch.json; returns that record. A :class:`UserError` is returned as a
    failure (not retried); any other exception is logged to error.log and raised again, so that Ray
    retries the task."""
    state = _begin_attempt(s, batch_id)
    log = _logger(s.out / LOG_FILE, s.name)
    log(f"attempt {state['attempts']} on {state['host']} (pid {os.getpid()}, {s.num_cpus} CPUs, {s.num_gpus:g} GPUs)")
    t0 = time.perf_counter()
    try:
        (pipeline or scene_pipeline)(s, log)
    except UserError as exc:
        log(f"failed: {exc}")
        return _end_attempt(s, state, t0, exc)
    except Exception as exc:
        log(f"failed: {type(exc).__name__}: {exc}")
        _end_attempt(s, state, t0, exc, traceback.format_exc())
        raise
    state = _end_attempt(s, state, t0)
    log(f"finished in {state['seconds']:.1f} s")
    return state


# ------------------------------------------------------------------------------------------ the batch (the driver)
def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """UserError unless a TCP connection to ``address`` ('HOST:PORT' or 'ray://HOST:PORT') opens within
    ``timeout_s``: ray.init keeps retrying an unreachable cluster for minutes. 'auto' is not checked."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise UserError(f"cannot reach the Ray cluster at {address} ({exc.strerror or exc})", field="--address") from None


@contextlib.contextmanager
def ray_session(bc: BatchConfig):
    """Ray for the batch: connect to ``bc.address``, or start a local Ray (every core, no dashboard,
    warnings only) and shut it down at the end; a Ray this process already started is used as it is."""
    if ray is None:
        raise UserError(INSTALL_HINT)
    started = not ray.is_initialized()
    if started:
        quiet = dict(logging_level=logging.WARNING, log_to_driver=True)
        try:
            if bc.address:
                check_reachable(bc.address)
                ray.init(address=bc.address, **quiet)
            else:
                # a local Ray turns on token authentication by itself and says so at each start: not news here
                logging.getLogger(_TOKEN_LOGGER).setLevel(logging.ERROR)
                ray.init(num_cpus=bc.local_cpus or os.cpu_count(), include_dashboard=False, **quiet)
        except ConnectionError as exc:
            raise UserError(f"cannot connect to the Ray cluster ({exc})", field="--address") from None
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def _unfit(s: BatchScene, total: dict) -> str | None:
    """Why a local Ray can never run scene ``s`` (too few CPUs or GPUs), or None."""
    for key, want in (("CPU", s.num_cpus), ("GPU", s.num_gpus)):
        if want > total.get(key, 0):
            return str(UserError(f"asks for {want:g} {key}s, the local Ray has {total.get(key, 0):g}",
                                 field="num_cpus" if key == "CPU" else "num_gpus"))
    return None


def _outcome(ref, s: BatchScene, batch_id: str) -> tuple[str, dict]:
    """(status, task record) of a task that ended: its returned record, or the exception it ended with."""
    try:
        res = ray.get(ref)
        return res["status"], res
    except ray.exceptions.RayTaskError as exc:
        cause = getattr(exc, "cause", None) or exc
        message = f"{type(cause).__name__}: {str(cause).strip().splitlines()[0] if str(cause).strip() else ''}"
    except ray.exceptions.RayError as exc:  # the worker died (killed, out of memory), the task was cancelled
        message = f"{type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}"
    state = read_state(s)
    same = state.get("batch_id") == batch_id
    return "failed", {"attempts": state.get("attempts", 1) if same else 1, "seconds": state.get("seconds") if same
                      else None, "error": message, "error_log": state.get("error_log") if same else None}


@dataclass
class BatchResult:
    """What a batch did: the summary rows (in manifest order), the summary files, the table."""

    rows: list[dict]
    paths: dict[str, Path]
    markdown: str

    @property
    def failures(self) -> list[str]:
        return failure_lines(self.rows)


class _Batch:
    """The driver's state: rows by scene, the summary written after every change."""

    def __init__(self, m: Manifest, say: Callable[..., None]):
        self.m, self.say = m, say
        self.rows = {s.name: scene_row(s, "pending", m.out) for s in m.scenes}
        self.paths: dict[str, Path] = {}

    def set(self, s: BatchScene, status: str, result: dict | None = None) -> None:
        self.rows[s.name] = row = scene_row(s, status, self.m.out, result)
        if status == "finished":
            self.say(f"{s.name}: finished in {row['wall_s'] or 0:.0f} s ({row['attempts']} attempt(s)), CIR PSNR "
                     f"{row['psnr_observed'] or float('nan'):.2f} dB")
        elif status in ("failed", "skipped"):
            self.say(f"{s.name}: " + (f"failed: {row['error']}" if status == "failed" else "skipped (finished earlier)"))

    def write(self) -> None:
        self.paths = write_summary(self.m.out, list(self.rows.values()), self.m.path)

    def result(self) -> BatchResult:
        rows = list(self.rows.values())
        return BatchResult(rows, self.paths, summary_markdown(rows, self.m.path))


def _submit(remote, s: BatchScene, bc: BatchConfig, batch_id: str):
    return remote.options(num_cpus=s.num_cpus, num_gpus=s.num_gpus, max_retries=bc.retries, retry_exceptions=True,
                          name=f"brfgs-batch:{s.name}").remote(s, batch_id)


def _run_tasks(b: _Batch, todo: list[BatchScene], bc: BatchConfig, batch_id: str, task: Callable) -> None:
    """Submit the scenes as Ray tasks (at most ``max_parallel`` at once) and record each as it ends."""
    if not bc.address:
        total = ray.cluster_resources()
        for s in [s for s in todo if _unfit(s, total)]:
            b.set(s, "failed", {"attempts": 0, "error": _unfit(s, total)})
            todo.remove(s)
    remote = ray.remote(task)
    queue, pending = list(todo), {}
    limit = bc.max_parallel or len(queue)
    try:
        while queue or pending:
            while queue and len(pending) < limit:
                s = queue.pop(0)
                pending[_submit(remote, s, bc, batch_id)] = s
                b.set(s, "running")
            b.write()
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                s = pending.pop(ref)
                b.set(s, *_outcome(ref, s, batch_id))
    finally:
        for s in pending.values():
            b.set(s, "interrupted")
        b.write()


def run_batch(m: Manifest, bc: BatchConfig | None = None, say: Callable[..., None] = print,
              task: Callable | None = None) -> BatchResult:
    """Run every unfinished scene of manifest ``m`` as a Ray task (see the module docstring); writes
    OUT/summary.md, .csv and .json and returns them with the rows. ``task``: the function each Ray
    task runs (default :func:`run_scene`; tests pass one that fails on purpose)."""
    bc = bc or BatchConfig()
    for name in ("retries", "max_parallel", "local_cpus"):
        if getattr(bc, name) < 0:
            raise UserError(f"must be >= 0, got {getattr(bc, name)}", field="--" + name.replace("_", "-"))
    b, todo = _Batch(m, say), []
    for s in m.scenes:
        action, what = plan_scene(s)
        if action == "run":
            todo.append(s)
            say(f"{s.name}: to run ({what})")
        else:
            b.set(s, "skipped" if action == "skip" else "failed", {"attempts": 0, "error": what})
    if todo and ray is None:
        raise UserError(INSTALL_HINT)
    m.out.mkdir(parents=True, exist_ok=True)
    b.write()
    if todo:
        batch_id = f"{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:8]}"
        with ray_session(bc):
            _run_tasks(b, todo, bc, batch_id, task or run_scene)
    return b.result()
