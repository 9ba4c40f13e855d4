"""Micro-benchmark of the reflectance head: N Gaussians × 1 view, forward and backward, CPU.

``python -m brfgs.brdf.bench [--n 1000000] [--d 16] [--repeats 5] [--threads 1]``
(also ``brfgs bench kernels``, which calls :func:`bench_head`).

Measured in one run, median of ``repeats`` timed runs after one warm-up:

* ``hybrid-fused``: :func:`brfgs.brdf.head.hybrid_latent` with the numba-fused CPU kernels
  and combination (:mod:`brfgs.brdf.fused`), float32 — what CPU training uses;
* ``hybrid-torch``: the same head with ``backend="torch"`` (cosine form, shared dot
  products, custom autograd for the singular scalar functions) — the CUDA path;
* ``naive-ref``: :func:`brfgs.brdf.reference.hybrid_latent_ref` (angles via acos/atan2,
  textbook formulas, explicit half vector), in float32 and float64;
* baselines of the same interface: ``sh3`` (degree-3 SH in latent space) and ``color``.

Backward differentiates a fixed random projection of the output with respect to the
latent coefficients, the raw roughness, the normals and ω_o (the paths that reach the
Gaussians' means, rotations and reflectance in training). Each row reports the ratio of
the naive float64 reference time to that row's time (``speedup_vs_ref64``) and to the
float32 naive reference (``speedup_vs_ref32``).
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time

import torch

from brfgs.brdf.head import HeadConfig, evaluate_head, hybrid_latent, roughness_from_raw
from brfgs.brdf.reference import hybrid_latent_ref

__all__ = ["bench_head", "format_table", "main"]


def _inputs(n: int, d: int, dtype: torch.dtype, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    z = [torch.randn(n, d, generator=g).to(dtype) for _ in range(4)]
    rho_raw = torch.randn(n, generator=g).to(dtype)
    tz = torch.rand(n, generator=g) * math.radians(60.0)
    az = torch.rand(n, generator=g) * (2 * math.pi)
    wo = torch.stack([tz.sin() * az.sin(), tz.sin() * az.cos(), tz.cos()], -1).to(dtype)
    nrm = torch.randn(n, 3, generator=g) * 0.3
    nrm[:, 2] += 1.0
    nrm = (nrm / nrm.norm(dim=-1, keepdim=True)).to(dtype)
    wi = torch.tensor([0.3, -0.4, math.sqrt(1 - 0.25)], dtype=dtype)
    proj = torch.randn(n, d, generator=g).to(dtype)
    return z, rho_raw, nrm, wi, wo, proj


def _time(fn, repeats: int) -> tuple[float, list[float]]:
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(ts), ts


def bench_head(n_gaussians: int = 1_000_000, d: int = 16, repeats: int = 5, threads: int | None = None) -> list[dict]:
    """Time head evaluation (forward, forward+backward) for N Gaussians × 1 view, latent dim d.

    Returns one dict per (variant, pass) with keys: name, dtype, pass ("forward" or
    "forward+backward"), n_gaussians, d, threads, median_ms, runs_ms, speedup_vs_ref64,
    speedup_vs_ref32.
    """
    if threads is not None:
        torch.set_num_threads(int(threads))  # the fused numba path follows torch's thread count
    nthreads = torch.get_num_threads()

    def hybrid_fn(z, rho_raw, nrm, wi, wo):
        return hybrid_latent(*z, roughness_from_raw(rho_raw), nrm, wi, wo, backend="fused")

    def hybrid_torch_fn(z, rho_raw, nrm, wi, wo):
        return hybrid_latent(*z, roughness_from_raw(rho_raw), nrm, wi, wo, backend="torch")

    def ref_fn(z, rho_raw, nrm, wi, wo):
        return hybrid_latent_ref(*z, roughness_from_raw(rho_raw), nrm, wi, wo)

    sh_cfg = HeadConfig(kind="sh", sh_degree=3)

    def sh_fn(z, rho_raw, nrm, wi, wo, _coeffs={}):
        key = (z[0].shape, z[0].dtype)
        if key not in _coeffs:  # parameters allocated once, like a model's
            _coeffs.clear()
            gen = torch.Generator().manual_seed(1)
            _coeffs[key] = torch.randn(z[0].shape[0], 16, z[0].shape[1], generator=gen).to(z[0].dtype).requires_grad_(
                z[0].requires_grad
            )
        return evaluate_head(sh_cfg, {"sh": _coeffs[key]}, None, wi, wo)

    def color_fn(z, rho_raw, nrm, wi, wo):
        return z[0] * 1.0

    variants = [
        ("hybrid-fused", torch.float32, hybrid_fn),
        ("hybrid-torch", torch.float32, hybrid_torch_fn),
        ("naive-ref", torch.float32, ref_fn),
        ("naive-ref", torch.float64, ref_fn),
        ("sh3", torch.float32, sh_fn),
        ("color", torch.float32, color_fn),
    ]
    rows: list[dict] = []
    for name, dtype, fn in variants:
        z, rho_raw, nrm, wi, wo, proj = _inputs(n_gaussians, d, dtype)

        def fwd():
            with torch.no_grad():
                return fn(z, rho_raw, nrm, wi, wo)

        leaves = [t.clone().requires_grad_(True) for t in (*z, rho_raw, nrm, wo)]

        def fwd_bwd():
            for t in leaves:
                t.grad = None
            out = fn(leaves[:4], leaves[4], leaves[5], wi, leaves[6])
            out.backward(proj)

        for pass_name, f in (("forward", fwd), ("forward+backward", fwd_bwd)):
            med, runs = _time(f, repeats)
            rows.append(
                dict(
                    name=name,
                    dtype=str(dtype).replace("torch.", ""),
                    **{"pass": pass_name},
                    n_gaussians=n_gaussians,
                    d=d,
                    threads=nthreads,
                    median_ms=round(med, 2),
                    runs_ms=[round(t, 2) for t in runs],
                )
            )
        del z, rho_raw, nrm, wo, proj, leaves
    for r in rows:
        ref64 = next(x for x in rows if x["name"] == "naive-ref" and x["dtype"] == "float64" and x["pass"] == r["pass"])
        ref32 = next(x for x in rows if x["name"] == "naive-ref" and x["dtype"] == "float32" and x["pass"] == r["pass"])
        r["speedup_vs_ref64"] = round(ref64["median_ms"] / r["median_ms"], 2)
        r["speedup_vs_ref32"] = round(ref32["median_ms"] / r["median_ms"], 2)
    return rows


def format_table(rows: list[dict]) -> str:
    """Markdown table of :func:`bench_head` rows."""
    head = "| head | dtype | pass | N | d | threads | median ms | runs ms | ×ref64 | ×ref32 |"
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(
            f"| {r['name']} | {r['dtype']} | {r['pass']} | {r['n_gaussians']} | {r['d']} | {r['threads']} | "
            f"{r['median_ms']:.1f} | {', '.join(f'{t:.0f}' for t in r['runs_ms'])} | "
            f"{r['speedup_vs_ref64']:.2f} | {r['speedup_vs_ref32']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m brfgs.brdf.bench", description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=1_000_000, help="number of Gaussians")
    p.add_argument("--d", type=int, default=16, help="latent dimension")
    p.add_argument("--repeats", type=int, default=5, help="timed runs (median reported)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    a = p.parse_args(argv)
    if a.n < 1 or a.d < 1 or a.repeats < 1 or a.threads < 1:
        p.error("--n, --d, --repeats and --threads must be positive")
    rows = bench_head(a.n, a.d, a.repeats, a.threads)
    print(f"# brfgs head benchmark: torch {torch.__version__}, {platform.processor() or platform.machine()}, "
          f"{platform.python_version()}")
    print(format_table(rows))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
