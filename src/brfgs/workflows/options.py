"""Options of the workflows and the benchmarks (light: the command line builds its options from them at
start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.errors import UserError
from brfgs.train.config import TrainConfig


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
    quiet: bool = field(default=False, metadata={"help": "No progress bars."})


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
    out: Optional[Path] = field(default=None, metadata={
        "help": "Output root: OUT/<scene>/ per scene and OUT/summary.md/.csv/.json (default: the manifest's out, "
                "else <manifest folder>/<manifest name>_batch).", "aliases": ("-o",)})
    dry_run: bool = field(default=False, metadata={
        "help": "Read and check the manifest, print what each scene would run, start nothing."})
    quiet: bool = field(default=False, metadata={"help": "No line per scene while the batch runs."})


# ----------------------------------------------------------------------------- brfgs bench
def _b(default, help: str, **meta):
    return field(default=default, metadata={"help": help, **meta})


JSON_HELP = "Also write the result as JSON to this file."
THREADS_HELP = "numba/torch threads (0: all cores)."
MODEL_HELP = "Run folder or model file (default: a synthetic model of a 128-px testsite run's size)."


@dataclass
class BenchRenderOptions:
    """``brfgs bench render``: the rasterizer backends against the torch reference."""

    sizes: tuple[int, ...] = _b((128, 256), "Square image sizes in pixels, comma-separated.")
    gaussians: tuple[int, ...] = _b((10_000, 20_000, 50_000, 200_000), "Numbers of Gaussians.")
    channels: tuple[int, ...] = _b((3, 16, 164), "Feature channels C.")
    repeats: int = _b(5, "Timed repetitions per row (median reported).")
    backends: tuple[str, ...] = _b(("torch", "cpu"), "Backends to time; torch is the reference.")
    torch_limit_s: float = _b(10.0, "Stop timing torch for larger N once a frame takes longer (s).")
    threads: int = _b(0, THREADS_HELP)
    seed: int = _b(0, "Scene seed.")
    json: Optional[Path] = _b(None, JSON_HELP)


@dataclass
class BenchKernelsOptions:
    """``brfgs bench kernels``: the BRDF head's evaluation."""

    gaussians: int = _b(1_000_000, "Number of Gaussians (one view).")
    d: int = _b(16, "Latent dimension.")
    repeats: int = _b(5, "Timed repetitions (median reported).")
    threads: int = _b(0, "torch threads (0: leave as is).")
    json: Optional[Path] = _b(None, JSON_HELP)


@dataclass
class BenchAnalysisOptions:
    """``brfgs bench analysis``: an arbitrary view and a polar BRF map."""

    model: Optional[Path] = _b(None, MODEL_HELP)
    gaussians: int = _b(50_000, "Gaussians of the synthetic model.")
    size: int = _b(128, "Square size of the arbitrary view (pixels).")
    repeats: int = _b(5, "Timed renders (median reported).")
    polar_repeats: int = _b(1, "Timed polar maps (median reported).")
    polar_azimuths: int = _b(60, "Azimuth sectors of the polar map.")
    polar_zeniths: int = _b(24, "Zenith rings of the polar map.")
    threads: int = _b(0, THREADS_HELP)
    json: Optional[Path] = _b(None, JSON_HELP)


@dataclass
class BenchViewOptions:
    """``brfgs bench view``: one 164-band view with the fused and the reference decoder and a linear basis."""

    model: Optional[Path] = _b(None, MODEL_HELP)
    gaussians: int = _b(50_000, "Gaussians of the synthetic model.")
    size: tuple[int, ...] = _b((128,), "Square view sizes in pixels, comma-separated.")
    repeats: int = _b(5, "Timed rounds per decoder (median reported).")
    simulator: bool = _b(False, "Also time the Mitsuba simulator rendering one view of the same size and bands.")
    threads: int = _b(0, THREADS_HELP)
    backend: str = _b("cpu", "Rasterizer: cpu, torch or cuda.")
    json: Optional[Path] = _b(None, JSON_HELP)


@dataclass
class BenchViewerOptions:
    """``brfgs bench viewer``: one interaction frame of ``brfgs view`` per display mode."""

    model: Optional[Path] = _b(None, "Run folder or model file (default: a synthetic model).")
    gaussians: int = _b(50_000, "Gaussians of the synthetic model.")
    size: int = _b(256, "Square frame size (pixels).")
    modes: tuple[str, ...] = _b(("cir", "depth", "index", "kernel:geo"), "Display modes to time, comma-separated.")
    repeats: int = _b(7, "Timed frames per mode (median reported).")
    threads: int = _b(2, THREADS_HELP)
    backend: str = _b("cpu", "Rasterizer: auto, torch, cpu or cuda.")
    json: Optional[Path] = _b(None, JSON_HELP)


@dataclass
class BenchTrainOptions:
    """``brfgs bench train`` and ``bench parallel``: timed training runs (every training option applies)."""

    train: TrainConfig = field(default_factory=TrainConfig, metadata={"flatten": True})
    repeats: int = _b(1, "Alternating rounds (median reported).")
    nprocs: tuple[int, ...] = _b((1, 2), "bench parallel: process counts to compare (first = reference).")
    json: Optional[Path] = _b(None, JSON_HELP)


@dataclass
class BenchManifestOptions:
    """``brfgs bench manifest``: the dry run of ``brfgs batch`` on a synthetic manifest of many scenes."""

    scenes: int = _b(10_000, "Scenes of the synthetic manifest (1..1000000).")
    repeats: int = _b(3, "Timed dry runs (median reported).")
    json: Optional[Path] = _b(None, JSON_HELP)


def check_bench(o) -> None:
    """UserError naming the option unless the benchmark options ``o`` are in range."""
    for name in ("repeats", "polar_repeats", "gaussians", "d"):
        v = getattr(o, name, 1)
        if isinstance(v, int) and v < 1:
            raise UserError(f"{name} must be >= 1, got {v}", field="--" + name.replace("_", "-"))
    for name in ("sizes", "gaussians", "channels", "size", "nprocs"):
        v = getattr(o, name, None)
        if isinstance(v, tuple) and (not v or any(x <= 0 for x in v)) or isinstance(v, int) and v < 8 and name == "size":
            raise UserError(f"expected positive values, got {v}", field="--" + name)
    if not 1 <= getattr(o, "scenes", 1) <= 1_000_000:
        raise UserError(f"scenes must be in 1..1000000, got {o.scenes}", field="--scenes")
    if getattr(o, "threads", 0) < 0:
        raise UserError(f"threads must be >= 0, got {o.threads}", field="--threads")
    if o.json is not None and o.json.is_dir():
        raise UserError("is a folder; expected a JSON file path", file=o.json, field="--json")
