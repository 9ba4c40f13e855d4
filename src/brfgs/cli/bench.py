"""``brfgs bench``: speed and memory benchmarks (render: the rasterizer; kernels: the BRDF head;
analysis: an arbitrary view and a polar BRF map; view: one view with the fused and the reference
decoder; train: a training run with both decoders; viewer: one viewer frame per display mode;
manifest: the dry run of brfgs batch on a manifest of many scenes)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import typer

from brfgs.cli._config import apply_options, config_command
from brfgs.cli.train import build_config
from brfgs.errors import UserError
from brfgs.workflows.options import (BenchAnalysisOptions, BenchKernelsOptions, BenchManifestOptions,
                                     BenchRenderOptions, BenchTrainOptions, BenchViewerOptions, BenchViewOptions,
                                     check_bench)

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).

bench_app = typer.Typer(help="Speed and memory benchmarks; results go in BENCHMARKS.md.", no_args_is_help=True)


def _write_json(path: Path, doc: dict) -> None:
    from brfgs.data import atomic

    atomic.write_json(path, doc)


def _check_backend(name: str, flag: str) -> None:
    """A benchmark times one named rasterizer backend: torch, cpu or cuda (not "auto")."""
    if name not in ("torch", "cpu", "cuda"):
        raise UserError(f"unknown backend {name!r}; expected torch, cpu or cuda", field=flag)


@config_command(bench_app, "render", BenchRenderOptions)
def render_cmd(options: dict | None = None) -> None:
    """Forward and forward+backward ms per frame of each backend, × vs torch (same run), peak memory."""
    from brfgs.render import configure_threads
    from brfgs.render.bench import accelerator_record, format_table, run_bench

    o = apply_options(BenchRenderOptions(), options)
    check_bench(o)
    for b in o.backends:
        _check_backend(b, "--backends")
    n_threads = configure_threads(o.threads or None)
    load = os.getloadavg()
    typer.echo(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
               f"threads {n_threads}, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")

    def progress(r):
        ratio = "" if r.ratio_vs_torch is None else f"  x{r.ratio_vs_torch:.2f} vs torch"
        typer.echo(f"  {r.backend:5s} {r.width}x{r.height} N={r.n_gaussians} C={r.channels} {r.pass_}: "
                   f"{r.ms_median:.1f} ms{ratio} {r.note}")

    rows = run_bench(sizes=list(o.sizes), gaussians=list(o.gaussians), channels=list(o.channels), repeats=o.repeats,
                     backends=list(o.backends), torch_limit_s=o.torch_limit_s, seed=o.seed, progress=progress)
    typer.echo(format_table(rows))
    load_end = os.getloadavg()
    typer.echo(f"load average at end: {load_end[0]:.2f} {load_end[1]:.2f} {load_end[2]:.2f}")
    if o.json is not None:
        doc = {"machine": {"processor": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                           "threads": n_threads, "loadavg_start": list(load), "loadavg_end": list(load_end),
                           **accelerator_record()},
               "rows": [r.to_json() for r in rows]}
        _write_json(o.json, doc)
        typer.echo(f"wrote {o.json}")


@config_command(bench_app, "kernels", BenchKernelsOptions)
def kernels_cmd(options: dict | None = None) -> None:
    """BRDF head evaluation time, forward and forward+backward (brfgs.brdf.bench.bench_head)."""
    try:
        from brfgs.brdf.bench import bench_head, format_table
    except ImportError as exc:
        raise UserError(f"the BRDF head benchmark is not part of this build ({exc})", field="bench kernels") from None
    o = apply_options(BenchKernelsOptions(), options)
    check_bench(o)
    load = os.getloadavg()
    typer.echo(f"{os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    rows = bench_head(o.gaussians, o.d, o.repeats, o.threads or None)
    typer.echo(format_table(rows))
    if o.json is not None:
        _write_json(o.json, {"loadavg_start": list(load), "rows": rows})
        typer.echo(f"wrote {o.json}")


@config_command(bench_app, "analysis", BenchAnalysisOptions)
def bench_analysis_cmd(options: dict | None = None) -> None:
    """Time one 164-band arbitrary view and one 60x24 polar BRF map of one ROI in 4 bands (BENCHMARKS.md)."""
    from brfgs.analysis.bench import bench_analysis
    from brfgs.render import configure_threads

    opts = apply_options(BenchAnalysisOptions(), options)
    check_bench(opts)
    configure_threads(opts.threads or None)
    res = bench_analysis(opts.model, n_gaussians=opts.gaussians, size=opts.size, repeats=opts.repeats,
                         polar_repeats=opts.polar_repeats, polar_azimuths=opts.polar_azimuths,
                         polar_zeniths=opts.polar_zeniths)
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
    sm = res["shadow_map"]
    typer.echo(f"shadow map of that view (sun visibility from the model's geometry): median "
               f"{sm['median_s'] * 1000:.0f} ms wall (x{sm['over_view']:.2f} the view, same run)")
    typer.echo(f"polar map {p['directions']} directions x {p['bands']} bands: {p['median_s']:.1f} s wall, "
               f"{p['median_cpu_s']:.1f} s CPU ({p['per_direction_ms']:.1f} ms wall per direction)")
    if opts.json is not None:
        _write_json(opts.json, res)


@config_command(bench_app, "view", BenchViewOptions)
def bench_view_cmd(options: dict | None = None) -> None:
    """One arbitrary 164-band view per size: the fused decoder against the reference decoder and a linear
    spectral basis of the same size in alternating rounds of one run (ratios, split rasterize/decode,
    largest difference), optionally the simulator's time for the same view (BENCHMARKS.md)."""
    from brfgs.analysis.bench import bench_view
    from brfgs.render import configure_threads

    o = apply_options(BenchViewOptions(), options)
    check_bench(o)
    configure_threads(o.threads or None)
    _check_backend(o.backend, "--backend")
    res = bench_view(o.model, n_gaussians=o.gaussians, sizes=tuple(o.size), repeats=o.repeats, simulator=o.simulator,
                     backend=o.backend)
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
        if "linear" in r:
            li = r["linear"]
            typer.echo(f"  linear basis: {li['median_s'] * 1e3:.0f} ms (rasterize {li['median_rasterize_s'] * 1e3:.0f} + "
                       f"decode {li['median_decode_s'] * 1e3:.0f}): x{r['linear_speedup_vs_fused']:.2f} view, "
                       f"x{r['linear_decode_speedup_vs_fused']:.2f} decode against the fused autoencoder")
    if res.get("bases"):
        typer.echo("bases: " + "; ".join(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}"
                                         for k, v in res["bases"].items()))
    typer.echo(f"peak RSS {res['peak_rss_mib']:.0f} MiB")
    if o.json is not None:
        _write_json(o.json, res)


@config_command(bench_app, "train", BenchTrainOptions, skip=("nprocs",))
def bench_train_cmd(
    scene: Path = typer.Argument(..., help="Scene folder (with truth/ for scores against the clean truth)."),
    out: Path = typer.Argument(..., help="Folder for the timed runs (fused_<r>, reference_<r>; replaced)."),
    options: dict | None = None,
) -> None:
    """Train SCENE with the fused spectral decoder and with the reference decoder, alternating in one
    process (same options and seed; any training option applies), and report seconds per phase and per
    step, their ratio, and CIR PSNR / SAM of both against truth (BENCHMARKS.md)."""
    from brfgs.workflows.bench_train import bench_train

    o, cfg = _bench_train_options(options)
    repeats = o.repeats
    res = bench_train(scene, out, cfg, repeats=repeats)
    la = res["machine"]["load_average_1_5_15_before"]
    typer.echo(f"load average before {la[0]:.1f} on {res['machine']['cpu_count']} cores; {repeats} round(s)")
    for name, s in res["summary"].items():
        ph = ", ".join(f"{k} {v:.1f} s" for k, v in s["median_phase_s"].items())
        per = ", ".join(f"{k} {v:.1f} ms/step" for k, v in s["ms_per_step"].items())
        typer.echo(f"{name:9s}: {ph}; {per}; CIR PSNR {s['psnr'][0]:.3f} dB, SAM {s['sam'][0]:.4f}")
    sp = ", ".join(f"{k} x{v:.2f}" for k, v in res["speedup_vs_reference"].items())
    typer.echo(f"speed-up vs reference (same run): {sp}; PSNR difference {res['psnr_difference_db']:+.3f} dB, "
               f"SAM ratio {res['sam_ratio']:.4f}")
    if o.json is not None:
        _write_json(o.json, res)


def _bench_train_options(options: dict | None):
    """(the benchmark's own options, the TrainConfig of the training options given: preset < options)."""
    options = dict(options or {})
    o = apply_options(BenchTrainOptions(), {k: v for k, v in options.items() if k[0] != "train"})
    check_bench(o)
    return o, build_config({k[1:]: v for k, v in options.items() if k[0] == "train"})


def register(app: typer.Typer) -> None:
    app.add_typer(bench_app, name="bench")


@config_command(bench_app, "viewer", BenchViewerOptions)
def bench_viewer_cmd(options: dict | None = None) -> None:
    """Time one interaction frame of `brfgs view` (render + colouring, 256² by default) per display mode."""
    from brfgs.render import configure_threads
    from brfgs.viewer.bench import bench_viewer
    from brfgs.viewer.frames import parse_mode

    o = apply_options(BenchViewerOptions(), options)
    check_bench(o)
    for m in o.modes:
        parse_mode(m)
    configure_threads(o.threads or None)
    size = o.size
    res = bench_viewer(o.model, n_gaussians=o.gaussians, size=size, modes=o.modes, repeats=o.repeats,
                       backend=o.backend)
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
    if o.json is not None:
        _write_json(o.json, res)


@config_command(bench_app, "parallel", BenchTrainOptions)
def bench_parallel_cmd(
    scene: Path = typer.Argument(..., help="Scene folder."),
    out: Path = typer.Argument(..., help="Folder for the timed runs (n<k>_<r>; replaced)."),
    options: dict | None = None,
) -> None:
    """Train SCENE in 1 and in N data-parallel processes (same seed and --views-per-step, default 2 here),
    alternating in one run; report seconds per phase and per step, the speed-up, the bytes all-reduced per
    step and the largest model difference (docs/scaling.md)."""
    from brfgs.workflows.bench_parallel import bench_parallel

    options = dict(options or {})
    options.setdefault(("train", "views_per_step"), 2)
    o, cfg = _bench_train_options(options)
    repeats = o.repeats
    res = bench_parallel(scene, out, cfg, nprocs=o.nprocs, repeats=repeats)
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
    if o.json is not None:
        _write_json(o.json, res)


@config_command(bench_app, "manifest", BenchManifestOptions)
def bench_manifest_cmd(options: dict | None = None) -> None:
    """Time `brfgs batch MANIFEST --dry-run` (read, check every option and path, plan every scene) on a
    synthetic manifest of --scenes scene folders written to a temporary folder (docs/scaling.md)."""
    from brfgs.workflows.bench_manifest import bench_manifest

    o = apply_options(BenchManifestOptions(), options)
    check_bench(o)
    res = bench_manifest(o.scenes, o.repeats)
    m = res["machine"]
    la, lb = m["load_average_1_5_15_before"], m["load_average_1_5_15_after"]
    typer.echo(f"{res['scenes']} scenes (written in {res['write_s']:.1f} s); {m['cpu_count']} cores, load average "
               f"{la[0]:.2f} {la[1]:.2f} {la[2]:.2f} before, {lb[0]:.2f} {lb[1]:.2f} {lb[2]:.2f} after")
    typer.echo(f"dry run: median {res['median_s']:.2f} s of {res['repeats']} ("
               + ", ".join(f"{t:.2f}" for t in res["rounds_s"]) + f" s), {res['per_scene_us']:.0f} us per scene")
    if o.json is not None:
        _write_json(o.json, res)
