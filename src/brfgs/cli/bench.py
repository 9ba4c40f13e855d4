"""``brfgs bench``: speed and memory benchmarks (render: the rasterizer; kernels: the BRDF head;
analysis: an arbitrary view and a polar BRF map; view: one view with the fused and the reference
decoder; train: a training run with both decoders; viewer: one viewer frame per display mode)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import typer

from brfgs.cli._config import config_command
from brfgs.cli.train import build_config
from brfgs.errors import UserError
from brfgs.train.config import TrainConfig

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).

bench_app = typer.Typer(help="Speed and memory benchmarks; results go in BENCHMARKS.md.", no_args_is_help=True)


def _write_json(path: Path, doc: dict) -> None:
    from brfgs.data import atomic

    atomic.write_json(path, doc)


def _int_list(text: str, field: str) -> list[int]:
    try:
        vals = [int(float(v)) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"expected comma-separated integers, got {text!r}", field=field) from None
    if not vals or any(v <= 0 for v in vals):
        raise UserError(f"expected positive integers, got {text!r}", field=field)
    return vals


def _check_backend(name: str, flag: str) -> None:
    """A benchmark times one named rasterizer backend: torch, cpu or cuda (not "auto")."""
    if name not in ("torch", "cpu", "cuda"):
        raise UserError(f"unknown backend {name!r}; expected torch, cpu or cuda", field=flag)


@bench_app.command("render")
def render_cmd(
    sizes: str = typer.Option("128,256", "--sizes", help="Square image sizes in pixels, comma-separated."),
    gaussians: str = typer.Option("10000,20000,50000,200000", "--gaussians", help="Numbers of Gaussians."),
    channels: str = typer.Option("3,16,164", "--channels", help="Feature channels C."),
    repeats: int = typer.Option(5, "--repeats", min=1, help="Timed repetitions per row (median reported)."),
    backends: str = typer.Option("torch,cpu", "--backends", help="Backends to time; 'torch' is the reference."),
    torch_limit_s: float = typer.Option(10.0, "--torch-limit-s",
                                        help="Stop timing torch for larger N once a frame takes longer."),
    threads: int = typer.Option(0, "--threads", min=0, help="numba/torch threads (0: all cores)."),
    seed: int = typer.Option(0, "--seed", help="Scene seed."),
    json_path: Path = typer.Option(None, "--json", help="Also write the rows as JSON to this file."),
):
    """Forward and forward+backward ms per frame of each backend, × vs torch (same run), peak memory."""
    from brfgs.render import configure_threads
    from brfgs.render.bench import accelerator_record, format_table, run_bench

    be = [b.strip() for b in backends.split(",") if b.strip()]
    for b in be:
        _check_backend(b, "--backends")
    if json_path is not None and json_path.exists() and json_path.is_dir():
        raise UserError("is a folder; expected a JSON file path", file=json_path, field="--json")
    n_threads = configure_threads(threads or None)
    load = os.getloadavg()
    typer.echo(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
               f"threads {n_threads}, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")

    def progress(r):
        ratio = "" if r.ratio_vs_torch is None else f"  x{r.ratio_vs_torch:.2f} vs torch"
        typer.echo(f"  {r.backend:5s} {r.width}x{r.height} N={r.n_gaussians} C={r.channels} {r.pass_}: "
                   f"{r.ms_median:.1f} ms{ratio} {r.note}")

    rows = run_bench(sizes=_int_list(sizes, "--sizes"), gaussians=_int_list(gaussians, "--gaussians"),
                     channels=_int_list(channels, "--channels"), repeats=repeats, backends=be,
                     torch_limit_s=torch_limit_s, seed=seed, progress=progress)
    typer.echo(format_table(rows))
    load_end = os.getloadavg()
    typer.echo(f"load average at end: {load_end[0]:.2f} {load_end[1]:.2f} {load_end[2]:.2f}")
    if json_path is not None:
        doc = {"machine": {"processor": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                           "threads": n_threads, "loadavg_start": list(load), "loadavg_end": list(load_end),
                           **accelerator_record()},
               "rows": [r.to_json() for r in rows]}
        _write_json(json_path, doc)
        typer.echo(f"wrote {json_path}")


@bench_app.command("kernels")
def kernels_cmd(
    n_gaussians: int = typer.Option(1_000_000, "--gaussians", min=1, help="Number of Gaussians (one view)."),
    d: int = typer.Option(16, "--d", min=1, help="Latent dimension."),
    repeats: int = typer.Option(5, "--repeats", min=1, help="Timed repetitions (median reported)."),
    threads: int = typer.Option(0, "--threads", min=0, help="torch threads (0: leave as is)."),
    json_path: Path = typer.Option(None, "--json", help="Also write the rows as JSON to this file."),
):
    """BRDF head evaluation time, forward and forward+backward (brfgs.brdf.bench.bench_head)."""
    try:
        from brfgs.brdf.bench import bench_head, format_table
    except ImportError as exc:
        raise UserError(f"the BRDF head benchmark is not part of this build ({exc})", field="bench kernels") from None
    if json_path is not None and json_path.is_dir():
        raise UserError("is a folder; expected a JSON file path", file=json_path, field="--json")
    load = os.getloadavg()
    typer.echo(f"{os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    rows = bench_head(n_gaussians, d, repeats, threads or None)
    typer.echo(format_table(rows))
    if json_path is not None:
        _write_json(json_path, {"loadavg_start": list(load), "rows": rows})
        typer.echo(f"wrote {json_path}")


@bench_app.command("analysis")
def bench_analysis_cmd(
    model: Path = typer.Option(None, "--model", help="Run folder or model file (default: a synthetic model of "
                               "a 128-px testsite run's size)."),
    gaussians: int = typer.Option(50_000, "--gaussians", min=100, help="Gaussians of the synthetic model."),
    size: int = typer.Option(128, "--size", min=8, help="Square size of the arbitrary view (pixels)."),
    repeats: int = typer.Option(5, "--repeats", min=1, help="Timed renders (median reported)."),
    polar_repeats: int = typer.Option(1, "--polar-repeats", min=1, help="Timed polar maps (median reported)."),
    polar_azimuths: int = typer.Option(60, "--polar-azimuths", min=1, help="Azimuth sectors of the polar map."),
    polar_zeniths: int = typer.Option(24, "--polar-zeniths", min=1, help="Zenith rings of the polar map."),
    threads: int = typer.Option(0, "--threads", min=0, help="numba/torch threads (0: all cores)."),
    json_path: Path = typer.Option(None, "--json", help="Also write the result as JSON to this file."),
) -> None:
    """Time one 164-band arbitrary view and one 60x24 polar BRF map of one ROI in 4 bands (BENCHMARKS.md)."""
    from brfgs.analysis.bench import bench_analysis
    from brfgs.render import configure_threads

    configure_threads(threads or None)
    res = bench_analysis(model, n_gaussians=gaussians, size=size, repeats=repeats, polar_repeats=polar_repeats,
                         polar_azimuths=polar_azimuths, polar_zeniths=polar_zeniths)
    r, p, m = res["render"], res["polar_map"], res["machine"]
    typer.echo(f"model: {res['model']} ({res['n_gaussians']} Gaussians, {res['bands']} bands, d={res['latent_dim']}); "
               f"threads numba {m['numba_threads']}")
    la = m["load_average_1_5_15_before"]
    typer.echo(f"load average before: {la[0]:.1f} on {m['cpu_count']} cores (wall times include "
               f"other processes' load; CPU seconds are this process's)")
    typer.echo(f"arbitrary view {r['size'][0]}x{r['size'][1]}x{res['bands']}: median {r['median_s'] * 1000:.0f} ms wall, "
               f"{r['median_cpu_s'] * 1000:.0f} ms CPU (of {r['repeats']})")
    o = r.get("median_s_by_decode_order") or {}
    if o:
        typer.echo(f"decode order (model: {r['decode_order']}): pixel {o['pixel'] * 1000:.0f} ms, gaussian "
                   f"{o['gaussian'] * 1000:.0f} ms wall (x{o['gaussian_over_pixel']:.2f}, same run)")
    typer.echo(f"polar map {p['directions']} directions x {p['bands']} bands: {p['median_s']:.1f} s wall, "
               f"{p['median_cpu_s']:.1f} s CPU ({p['per_direction_ms']:.1f} ms wall per direction)")
    if json_path is not None:
        _write_json(json_path, res)


@bench_app.command("view")
def bench_view_cmd(
    model: Path = typer.Option(None, "--model", help="Run folder or model file (default: a synthetic model of "
                               "a 128-px testsite run's size)."),
    gaussians: int = typer.Option(50_000, "--gaussians", min=100, help="Gaussians of the synthetic model."),
    sizes: list[int] = typer.Option([128], "--size", min=8, help="Square view size in pixels (repeatable)."),
    repeats: int = typer.Option(5, "--repeats", min=1, help="Timed rounds per decoder (median reported)."),
    simulator: bool = typer.Option(False, "--simulator", help="Also time the Mitsuba simulator rendering one "
                                   "view of the same size and bands (needs the sim extra; minutes at 1024²)."),
    threads: int = typer.Option(0, "--threads", min=0, help="numba/torch threads (0: all cores)."),
    backend: str = typer.Option("cpu", "--backend", help="Rasterizer backend: cpu | torch | cuda (gsplat; the "
                                "model stays on the CPU, the decoder runs there)."),
    json_path: Path = typer.Option(None, "--json", help="Also write the result as JSON to this file."),
) -> None:
    """One arbitrary 164-band view per size: the fused decoder against the reference decoder in
    alternating rounds of one run (ratio, split rasterize/decode, largest difference), optionally the
    simulator's time for the same view (BENCHMARKS.md)."""
    from brfgs.analysis.bench import bench_view
    from brfgs.render import configure_threads

    if json_path is not None and json_path.is_dir():
        raise UserError("is a folder; expected a JSON file path", file=json_path, field="--json")
    configure_threads(threads or None)
    _check_backend(backend, "--backend")
    res = bench_view(model, n_gaussians=gaussians, sizes=tuple(sizes), repeats=repeats, simulator=simulator,
                     backend=backend)
    la = res["machine"]["load_average_1_5_15_before"]
    typer.echo(f"model: {res['model']} ({res['n_gaussians']} Gaussians, {res['bands']} bands); threads "
               f"{res['machine']['numba_threads']}; load average before {la[0]:.1f} on {res['machine']['cpu_count']} cores")
    for r in res["views"]:
        f, ref = r["fused"], r["reference"]
        typer.echo(f"{r['size'][0]}x{r['size'][1]}: fused {f['median_s'] * 1e3:.0f} ms (rasterize "
                   f"{f['median_rasterize_s'] * 1e3:.0f} + decode {f['median_decode_s'] * 1e3:.0f}), reference "
                   f"{ref['median_s'] * 1e3:.0f} ms (decode {ref['median_decode_s'] * 1e3:.0f}): x{r['speedup_vs_reference']:.2f} "
                   f"view, x{r['decode_speedup_vs_reference']:.2f} decode; max |diff| {r['max_abs_diff_vs_reference']:.1e}"
                   + (f"; simulator {r['simulator_view_s']:.1f} s (x{r['speedup_vs_simulator']:.0f})"
                      if "simulator_view_s" in r else ""))
    typer.echo(f"peak RSS {res['peak_rss_mib']:.0f} MiB")
    if json_path is not None:
        _write_json(json_path, res)


@config_command(bench_app, "train", TrainConfig)
def bench_train_cmd(
    scene: Path = typer.Argument(..., help="Scene folder (with truth/ for scores against the clean truth)."),
    out: Path = typer.Argument(..., help="Folder for the timed runs (fused_<r>, reference_<r>; replaced)."),
    repeats: int = typer.Option(1, "--repeats", min=1, help="Alternating rounds per decoder (median reported)."),
    json_path: Path = typer.Option(None, "--json", help="Also write the result as JSON to this file."),
    options: dict | None = None,
) -> None:
    """Train SCENE with the fused spectral decoder and with the reference decoder, alternating in one
    process (same options and seed; any training option applies), and report seconds per phase and per
    step, their ratio, and CIR PSNR / SAM of both against truth (BENCHMARKS.md)."""
    from brfgs.workflows.bench_train import bench_train

    if json_path is not None and json_path.is_dir():
        raise UserError("is a folder; expected a JSON file path", file=json_path, field="--json")
    res = bench_train(scene, out, build_config(options or {}), repeats=repeats)
    la = res["machine"]["load_average_1_5_15_before"]
    typer.echo(f"load average before {la[0]:.1f} on {res['machine']['cpu_count']} cores; {repeats} round(s)")
    for name, s in res["summary"].items():
        ph = ", ".join(f"{k} {v:.1f} s" for k, v in s["median_phase_s"].items())
        per = ", ".join(f"{k} {v:.1f} ms/step" for k, v in s["ms_per_step"].items())
        typer.echo(f"{name:9s}: {ph}; {per}; CIR PSNR {s['psnr'][0]:.3f} dB, SAM {s['sam'][0]:.4f}")
    sp = ", ".join(f"{k} x{v:.2f}" for k, v in res["speedup_vs_reference"].items())
    typer.echo(f"speed-up vs reference (same run): {sp}; PSNR difference {res['psnr_difference_db']:+.3f} dB, "
               f"SAM ratio {res['sam_ratio']:.4f}")
    if json_path is not None:
        _write_json(json_path, res)


def register(app: typer.Typer) -> None:
    app.add_typer(bench_app, name="bench")


@bench_app.command("viewer")
def bench_viewer_cmd(
    model: Path = typer.Option(None, "--model", help="Run folder or model file (default: a synthetic model)."),
    gaussians: int = typer.Option(50_000, "--gaussians", min=100, help="Gaussians of the synthetic model."),
    size: int = typer.Option(256, "--size", min=8, max=4096, help="Square frame size (pixels)."),
    modes: str = typer.Option("cir,depth,index,kernel:geo", "--modes",
                              help="Display modes to time, comma-separated (brfgs view's modes)."),
    repeats: int = typer.Option(7, "--repeats", min=1, help="Timed frames per mode (median reported)."),
    threads: int = typer.Option(2, "--threads", min=0, help="numba/torch threads (0: all cores)."),
    backend: str = typer.Option("cpu", "--backend", help="Rasterizer backend: auto | torch | cpu | cuda."),
    json_path: Path = typer.Option(None, "--json", help="Also write the result as JSON to this file."),
) -> None:
    """Time one interaction frame of `brfgs view` (render + colouring, 256² by default) per display mode."""
    from brfgs.render import configure_threads
    from brfgs.viewer.bench import bench_viewer
    from brfgs.viewer.frames import parse_mode

    ms = tuple(m.strip() for m in modes.split(",") if m.strip())
    for m in ms:
        parse_mode(m)
    if json_path is not None and json_path.is_dir():
        raise UserError("is a folder; expected a JSON file path", file=json_path, field="--json")
    configure_threads(threads or None)
    res = bench_viewer(model, n_gaussians=gaussians, size=size, modes=ms, repeats=repeats, backend=backend)
    m = res["machine"]
    typer.echo(f"model: {res['model']} ({res['n_gaussians']} Gaussians, {res['bands']} bands); {size}x{size} px; "
               f"threads numba {m['numba_threads']}, torch {m['torch_threads']}; load average before "
               f"{m['load_average_1_5_15_before'][0]:.1f} on {m['cpu_count']} cores")
    for name, r in res["modes"].items():
        dec = r.get("decode")
        extra = "" if dec is None else (f"; decoding {len(dec['bands'])} band(s) {dec['median_s'] * 1e3:.1f} ms vs full "
                                        f"decode {dec['reference_median_s'] * 1e3:.1f} ms (x{dec['speedup_vs_reference']:.1f}"
                                        f", max |diff| {dec['max_abs_difference']:.1e})")
        typer.echo(f"{name:12s} median {r['median_s'] * 1e3:6.1f} ms wall, {r['median_cpu_s'] * 1e3:6.1f} ms CPU{extra}")
    if json_path is not None:
        _write_json(json_path, res)


@config_command(bench_app, "parallel", TrainConfig)
def bench_parallel_cmd(
    scene: Path = typer.Argument(..., help="Scene folder."),
    out: Path = typer.Argument(..., help="Folder for the timed runs (n<k>_<r>; replaced)."),
    nprocs: str = typer.Option("1,2", "--nprocs", help="Process counts to compare, comma-separated (first = reference)."),
    repeats: int = typer.Option(1, "--repeats", min=1, help="Alternating rounds per process count (median reported)."),
    json_path: Path = typer.Option(None, "--json", help="Also write the result as JSON to this file."),
    options: dict | None = None,
) -> None:
    """Train SCENE in 1 and in N data-parallel processes (same seed and --views-per-step, default 2 here),
    alternating in one run; report seconds per phase and per step, the speed-up, the bytes all-reduced per
    step and the largest model difference (docs/scaling.md)."""
    from brfgs.workflows.bench_parallel import bench_parallel

    if json_path is not None and json_path.is_dir():
        raise UserError("is a folder; expected a JSON file path", file=json_path, field="--json")
    options = dict(options or {})
    options.setdefault(("views_per_step",), 2)
    counts = tuple(_int_list(nprocs, "--nprocs"))
    res = bench_parallel(scene, out, build_config(options), nprocs=counts, repeats=repeats)
    la = res["machine"]["load_average_1_5_15_before"]
    typer.echo(f"load average before {la[0]:.1f} on {res['machine']['cpu_count']} cores; {repeats} round(s); "
               f"{res['config']['views_per_step']} views per step")
    for n, s in res["summary"].items():
        per = ", ".join(f"{k} {v:.1f} ms/step" for k, v in s["ms_per_step"].items())
        mb = ", ".join(f"{k} {v / 1e6:.2f} MB" for k, v in s["allreduce_bytes_per_step"].items())
        acc = ", ".join(f"{a:.2f} dB / {b:.4f}" for a, b in zip(s["psnr"], s["sam"]))
        typer.echo(f"{n} process(es): wall {s['median_wall_s']:.1f} s; {per}; all-reduced per step: {mb or '-'}; "
                   f"CIR PSNR / SAM against {s['against']}: {acc}")
    for n, r in res["speedup_vs_one"].items():
        sp = ", ".join(f"{k} x{v:.2f}" for k, v in r.items())
        typer.echo(f"speed-up of {n} processes (same run): {sp}; max |model difference| "
                   f"{res['max_abs_model_difference'][n]:.2e}")
    if json_path is not None:
        _write_json(json_path, res)
