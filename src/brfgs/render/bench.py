"""Speed and memory benchmark of the rasterizer backends (``brfgs bench render``).

Scene: :func:`brfgs.render.scenes.ground_scene` — N Gaussians spread over a ground patch with
gentle relief and a canopy layer that fills a 35° camera 30 m away at 20° view zenith, each
with a 1σ screen size of ~1 px (log-normal spread, flattened along z, α ≥ 1/255 footprint
≈ 6 px across), opacities 0.05–0.95, like a trained landscape model. The loss for the
backward pass is Σ image + Σ depth.

Timings: the backends run alternately inside each repetition (so load changes on a shared
machine hit both), after one warm-up; the median over repetitions is reported.
``ratio_vs_torch`` = median torch ms / median ms of the row's backend (how many times faster
than the reference, measured in the same run). ``cpu_ms_median``: process CPU time per frame
summed over threads (less sensitive to other users of a shared machine than wall time).
Peak memory: the highest resident-set size sampled every ~2 ms during a frame minus the RSS
just before it, after returning freed heap memory to the OS (MiB; approximate).

``cuda`` (gsplat): the scene lives on the GPU, each frame ends with ``torch.cuda.synchronize()``,
and its peak memory is the GPU's (``torch.cuda.max_memory_allocated`` during the frame minus the
memory allocated before it).
"""

from __future__ import annotations

import ctypes
import gc
import os
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import torch

from brfgs.render.rasterize import rasterize
from brfgs.render.scenes import ground_scene


@dataclass
class BenchRow:
    backend: str
    width: int
    height: int
    n_gaussians: int
    channels: int
    pass_: str            # "forward" | "forward+backward"
    ms_median: float | None
    ratio_vs_torch: float | None
    cpu_ms_median: float | None   # process CPU time per frame (all threads), less load-sensitive
    peak_mem_mib: float | None
    repeats: int
    note: str = ""

    def to_json(self) -> dict:
        d = asdict(self)
        d["pass"] = d.pop("pass_")
        return d


def accelerator_record() -> dict:
    """A benchmark record's torch version and the name of the CUDA device torch uses (None without one)."""
    return {"gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None, "torch": str(torch.__version__)}


def _trim() -> None:
    """Return freed heap memory to the OS (glibc) so that RSS peaks measure one frame."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except OSError:
        pass


def _rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


class _PeakRSS:
    """Samples RSS in a thread (the numba kernels release the GIL)."""

    def __enter__(self):
        self.base = _rss_mib()
        self.peak = self.base
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        return self

    def _run(self):
        while not self._stop.wait(0.002):
            self.peak = max(self.peak, _rss_mib())

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _rss_mib())

    @property
    def mib(self) -> float:
        return self.peak - self.base


class _PeakCUDA:
    """GPU memory allocated by torch during a frame above what was allocated before it."""

    def __enter__(self):
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
        self.base = torch.cuda.memory_allocated()
        return self

    def __exit__(self, *exc):
        self.peak = torch.cuda.max_memory_allocated()

    @property
    def mib(self) -> float:
        return (self.peak - self.base) / 2**20


def _on_device(sc: dict, backend: str) -> dict:
    """The scene ``sc`` with its tensors where ``backend`` renders (the GPU for ``cuda``)."""
    if backend != "cuda":
        return sc
    return {k: (v.to("cuda") if isinstance(v, torch.Tensor) else v) for k, v in sc.items()}


def _frame(sc, backend: str, backward: bool, params=None):
    """One render of the scene ``sc`` (with ``params``, then backward of Σ image + Σ depth, when ``backward``)."""
    if backward:
        p = params
        out = rasterize(p["means"], p["quats"], p["scales"], p["opacities"], p["features"], sc["viewmat"],
                        sc["K"], sc["width"], sc["height"], backend=backend)
        (out.image.sum() + out.depth.sum()).backward()
        for v in p.values():
            v.grad = None
    else:
        with torch.no_grad():
            rasterize(sc["means"], sc["quats"], sc["scales"], sc["opacities"], sc["features"], sc["viewmat"],
                      sc["K"], sc["width"], sc["height"], backend=backend)
    if backend == "cuda":
        torch.cuda.synchronize()


def run_bench(sizes: tuple[int, ...] = (128, 256), gaussians: tuple[int, ...] = (10_000, 20_000, 50_000, 200_000),
              channels: tuple[int, ...] = (3, 16, 164), repeats: int = 5, backends: tuple[str, ...] = ("torch", "cpu"),
              torch_limit_s: float = 10.0, seed: int = 0,
              progress: Callable[[BenchRow], None] | None = None) -> list[BenchRow]:
    """Benchmark grid → rows. A ``torch`` configuration whose warm-up frame takes longer than
    ``torch_limit_s`` is not timed further, nor are larger N at the same size and C."""
    rows: list[BenchRow] = []

    def add(row: BenchRow) -> None:
        rows.append(row)
        if progress:
            progress(row)

    for size in sizes:
        for C in channels:
            torch_stopped = False
            for N in sorted(gaussians):
                sc = ground_scene(N, size, size, C, seed=seed)
                bes = [b for b in backends if not (b == "torch" and torch_stopped)]
                scs = {b: _on_device(sc, b) for b in bes}
                for backward in (False, True):
                    pass_name = "forward+backward" if backward else "forward"
                    params = {b: {k: scs[b][k].clone().requires_grad_(True)
                                  for k in ("means", "quats", "scales", "opacities", "features")} for b in bes}
                    active = []
                    for b in bes:  # warm-up (and the torch time limit)
                        t0 = time.perf_counter()
                        _frame(scs[b], b, backward, params[b])
                        dt = time.perf_counter() - t0
                        if b == "torch" and dt > torch_limit_s:
                            torch_stopped = True
                            add(BenchRow(b, size, size, N, C, pass_name, round(1000 * dt, 1), 1.0, None, None, 1,
                                         f"warm-up frame over {torch_limit_s:g} s: not repeated"))
                        else:
                            active.append(b)
                    times = {b: [] for b in active}
                    cpu_times = {b: [] for b in active}
                    peaks = {b: 0.0 for b in active}
                    for _ in range(repeats):
                        for b in active:
                            _trim()
                            with (_PeakCUDA() if b == "cuda" else _PeakRSS()) as mem:
                                t0 = time.perf_counter()
                                c0 = time.process_time()
                                _frame(scs[b], b, backward, params[b])
                                cpu_times[b].append(1000 * (time.process_time() - c0))
                                times[b].append(1000 * (time.perf_counter() - t0))
                            peaks[b] = max(peaks[b], mem.mib)
                    ref = statistics.median(times["torch"]) if "torch" in times else None
                    for r in rows:  # a torch row over the limit is still a reference for this config
                        if (ref is None and r.backend == "torch" and r.width == size and r.n_gaussians == N
                                and r.channels == C and r.pass_ == pass_name):
                            ref = r.ms_median
                    for b in active:
                        med = statistics.median(times[b])
                        add(BenchRow(b, size, size, N, C, pass_name, round(med, 2),
                                     round(ref / med, 2) if ref else None,
                                     round(statistics.median(cpu_times[b]), 2), round(peaks[b], 1), repeats))
    return rows


def format_table(rows: list[BenchRow]) -> str:
    """Markdown table of the rows."""
    head = ("| backend | size | N | C | pass | ms (median) | × vs torch | CPU ms | peak MiB | note |\n"
            "|---|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        ratio = "" if r.ratio_vs_torch is None else f"{r.ratio_vs_torch:.2f}"
        mem = "" if r.peak_mem_mib is None else f"{r.peak_mem_mib:.0f}"
        cpu = "" if r.cpu_ms_median is None else f"{r.cpu_ms_median:.1f}"
        lines.append(f"| {r.backend} | {r.width}x{r.height} | {r.n_gaussians} | {r.channels} | {r.pass_} | "
                     f"{r.ms_median:.1f} | {ratio} | {cpu} | {mem} | {r.note} |")
    return "\n".join(lines)
