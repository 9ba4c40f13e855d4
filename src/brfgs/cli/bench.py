"""``brfgs bench``: speed and memory benchmarks (render: the rasterizer; kernels: the BRDF head)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.errors import UserError

bench_app = typer.Typer(help="Speed and memory benchmarks; results go in BENCHMARKS.md.", no_args_is_help=True)


def _int_list(text: str, field: str) -> list[int]:
    try:
        vals = [int(float(v)) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"expected comma-separated integers, got {text!r}", field=field) from None
    if not vals or any(v <= 0 for v in vals):
        raise UserError(f"expected positive integers, got {text!r}", field=field)
    return vals


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
    import json
    import os
    import platform

    from brfgs.render import configure_threads
    from brfgs.render.bench import format_table, run_bench

    be = [b.strip() for b in backends.split(",") if b.strip()]
    for b in be:
        if b not in ("torch", "cpu", "cuda"):
            raise UserError(f"unknown backend {b!r}; expected torch, cpu or cuda", field="--backends")
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
                           "threads": n_threads, "loadavg_start": list(load), "loadavg_end": list(load_end)},
               "rows": [r.to_json() for r in rows]}
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(doc, indent=1))
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
    import json
    import os

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
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps({"loadavg_start": list(load), "rows": rows}, indent=1))
        typer.echo(f"wrote {json_path}")


def register(app: typer.Typer) -> None:
    from brfgs.cli.analysis import bench_analysis_cmd

    bench_app.command("analysis")(bench_analysis_cmd)
    app.add_typer(bench_app, name="bench")
