"""Data-parallel training over processes (torch.distributed; gloo on CPU, NCCL on GPU).

Every rank holds the whole model and the same random generator. In each step all ranks draw
the same global batch of ``views_per_step`` training views; rank r renders views r, r + N, ...
(N ranks), backpropagates ``loss / views_per_step`` of each, and the gradients and the step's
densification statistics are summed over the ranks (one all-reduce each). Every rank then takes
the same Adam step and the same densification decisions, so the ranks stay identical without
broadcasting the model; :func:`check_identical` verifies it at each phase start. Rank 0 alone
writes the run folder.

Two ways to start N ranks:
- ``torchrun --nproc-per-node N -m brfgs train SCENE OUT --distributed ...`` (torchrun sets
  RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT; also across machines);
- ``brfgs train SCENE OUT --nproc N ...``: :func:`launch` starts N local processes itself.
"""

from __future__ import annotations

import datetime
import logging
import os
import socket
import sys
import traceback
from typing import Callable, Sequence

import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch import Tensor

from brfgs.errors import UserError

# Set-up (SfM, autoencoder) runs on rank 0 while the others wait: allow hours, not gloo's 30 min.
GROUP_TIMEOUT = datetime.timedelta(hours=6)


class Comm:
    """One process: every collective is the identity (the default of :class:`brfgs.train.Trainer`)."""

    rank = 0
    world = 1

    @property
    def is_main(self) -> bool:
        """True on the rank that writes the run folder (rank 0)."""
        return self.rank == 0

    def all_reduce_(self, flat: Tensor, op: str = "sum") -> Tensor:
        """Sum (or max) ``flat`` over the ranks in place; returns it."""
        return flat

    def broadcast_object(self, obj):
        """Rank 0's ``obj`` on every rank."""
        return obj

    def barrier(self) -> None:
        """Wait until every rank arrives."""


class ProcessGroupComm(Comm):
    """The ranks of an initialised ``torch.distributed`` default process group."""

    def __init__(self):
        self.rank = dist.get_rank()
        self.world = dist.get_world_size()
        self.device = torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" else None

    def all_reduce_(self, flat: Tensor, op: str = "sum") -> Tensor:
        red = dist.ReduceOp.MAX if op == "max" else dist.ReduceOp.SUM
        if self.device is None:
            dist.all_reduce(flat, op=red)
            return flat
        on = flat.to(self.device)
        dist.all_reduce(on, op=red)
        flat.copy_(on.cpu())
        return flat

    def broadcast_object(self, obj):
        box = [obj]
        dist.broadcast_object_list(box, src=0)
        return box[0]

    def barrier(self) -> None:
        dist.barrier()


def init_from_env(backend: str = "auto") -> Comm:
    """Join the process group that torchrun (or :func:`launch`) describes in the environment
    (RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT); gloo on CPU, NCCL when ``backend`` is "cuda"
    or "auto" with a GPU. A missing variable is a UserError naming it."""
    missing = [k for k in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT") if k not in os.environ]
    if missing:
        raise UserError(f"--distributed needs the environment of torchrun (missing {', '.join(missing)}); start "
                        "it with `torchrun --nproc-per-node N -m brfgs train ... --distributed` or use --nproc N",
                        field="--distributed")
    use_nccl = torch.cuda.is_available() and backend in ("auto", "cuda")
    if use_nccl:
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
    if not dist.is_initialized():
        dist.init_process_group("nccl" if use_nccl else "gloo", timeout=GROUP_TIMEOUT)
    return ProcessGroupComm()


def shutdown() -> None:
    """Leave the process group (if joined)."""
    if dist.is_initialized():
        dist.destroy_process_group()


def check_views_per_step(views_per_step: int, world: int) -> None:
    """UserError unless the global batch ``views_per_step`` shares out equally over ``world`` ranks."""
    if views_per_step % world:
        raise UserError(f"views_per_step ({views_per_step}) must be a multiple of the number of processes "
                        f"({world}): each rank renders an equal share of every step's views", field="views_per_step")


def shard(items: Sequence, comm: Comm) -> list:
    """This rank's share of one step's global batch: items r, r + N, r + 2N, ..."""
    return list(items[comm.rank :: comm.world])


def reduce_gradients(comm: Comm, params: dict[str, Tensor]) -> int:
    """Sum the ``.grad`` of every tensor in ``params`` over the ranks (one all-reduce of one
    flat buffer); returns the bytes each rank sent. A tensor without a gradient on some rank
    counts as zero there; one without a gradient on every rank keeps ``grad = None`` (Adam then
    skips it, as in one process)."""
    if comm.world == 1:
        return 0
    names = sorted(params)  # the same order on every rank (a loaded model may list its tensors otherwise)
    has = torch.tensor([params[k].grad is not None for k in names], dtype=torch.float32)  # [P]
    comm.all_reduce_(has, op="max")
    live = [k for k, h in zip(names, has.tolist()) if h > 0]
    if not live:
        return 0
    parts = [params[k].grad.reshape(-1) if params[k].grad is not None else torch.zeros(params[k].numel(),
                                                                                       dtype=params[k].dtype)
             for k in live]
    flat = torch.cat([p.to(torch.float32) for p in parts])  # [sum of numel]
    comm.all_reduce_(flat)
    at = 0
    for k in live:
        p = params[k]
        p.grad = flat[at : at + p.numel()].reshape(p.shape).to(p.dtype).clone()
        at += p.numel()
    return flat.numel() * flat.element_size() + has.numel() * has.element_size()


def fingerprint(tensors: dict[str, Tensor]) -> Tensor:  # [T] float64
    """Per tensor (sorted by name) the float64 sum of its values and of their squares: a cheap
    summary that two ranks holding different values almost surely disagree on."""
    rows = []
    for k in sorted(tensors):
        t = tensors[k].detach().to(torch.float64)
        rows.extend([t.sum(), (t * t).sum(), torch.tensor(float(t.numel()), dtype=torch.float64)])
    return torch.stack(rows) if rows else torch.zeros(0, dtype=torch.float64)


def check_identical(comm: Comm, tensors: dict[str, Tensor], where: str) -> None:
    """Raise when the ranks' ``tensors`` differ (a bug: the ranks must stay identical)."""
    if comm.world == 1:
        return
    mine = fingerprint(tensors)
    ref = comm.broadcast_object(mine)
    if mine.shape != ref.shape or not torch.equal(mine, ref):
        names = sorted(tensors)
        bad = names if mine.shape != ref.shape else \
            [k for j, k in enumerate(names) if not torch.equal(mine[3 * j : 3 * j + 3], ref[3 * j : 3 * j + 3])]
        raise RuntimeError(f"rank {comm.rank}: {', '.join(bad[:6])} differ from rank 0 at {where}; the ranks diverged")


def free_port() -> int:
    """A free TCP port on the loopback interface (for a local process group)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_as_rank(fn: Callable, args: tuple = (), backend: str = "auto") -> bool:
    """Join the process group the environment describes, run ``fn(comm, *args)`` and leave the
    group; returns True on rank 0. A UserError propagates on rank 0 only (the caller prints it
    once); the other ranks end with ``SystemExit(2)`` instead."""
    comm = init_from_env(backend)
    try:
        fn(comm, *args)
    except UserError:
        if comm.is_main:
            raise
        raise SystemExit(2) from None
    finally:
        shutdown()
    return comm.is_main


def _rank_main(rank: int, world: int, port: int, fn: Callable, args: tuple) -> None:
    """Entry of one process started by :func:`launch`: :func:`run_as_rank` on a loopback group.
    A UserError is printed once (rank 0) as one line and the process exits with status 2."""
    os.environ.update({"RANK": str(rank), "WORLD_SIZE": str(world), "LOCAL_RANK": str(rank),
                       "LOCAL_WORLD_SIZE": str(world), "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port)})
    try:
        run_as_rank(fn, args)
    except UserError as exc:  # rank 0's (the others leave with SystemExit(2))
        print(f"brfgs: error: {exc}", file=sys.stderr, flush=True)
        sys.exit(2)
    except KeyboardInterrupt:  # Ctrl-C reaches every rank; rank 0 saved its checkpoint (the trainer)
        sys.exit(130 if rank == 0 else 0)  # the others end quietly, so that rank 0 is not terminated early
    except BaseException as exc:
        if not isinstance(exc, SystemExit):
            traceback.print_exc()
        raise


def launch(nproc: int, fn: Callable, args: tuple = ()) -> None:
    """Run ``fn(comm, *args)`` in ``nproc`` new local processes joined by a gloo (or NCCL) group
    on a free loopback port. ``fn`` and ``args`` must be picklable. Exit status 2 of a rank (a
    user error, already printed) becomes ``SystemExit(2)``; Ctrl-C, which reaches every rank,
    waits for rank 0 to save its checkpoint and becomes ``SystemExit(130)`` (a second Ctrl-C stops
    at once); another failure of a rank is a RuntimeError naming it."""
    port = free_port()
    # when one rank stops (a user error, already printed), torch terminates the others with a warning
    logging.getLogger("torch.multiprocessing.spawn").setLevel(logging.ERROR)
    ctx = mp.start_processes(_rank_main, args=(nproc, port, fn, args), nprocs=nproc, join=False,
                             start_method="spawn")
    interrupted = False
    try:
        while True:
            try:
                if ctx.join():
                    break
            except KeyboardInterrupt:
                if interrupted:
                    raise
                interrupted = True  # the ranks have it too: let rank 0 write its checkpoint
    except mp.ProcessExitedException as exc:
        if exc.exit_code in (2, 130):
            raise SystemExit(exc.exit_code) from None
        raise RuntimeError(f"training rank {exc.error_index} failed (exit status {exc.exit_code})") from None
    finally:
        for proc in ctx.processes:
            if proc.is_alive():
                proc.terminate()
    if interrupted:
        raise SystemExit(130)
