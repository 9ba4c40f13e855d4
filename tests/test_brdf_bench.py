"""The head micro-benchmark runs and reports what BENCHMARKS.md needs (no timing asserted)."""

from __future__ import annotations

import torch

from brfgs.brdf.bench import bench_head, format_table, main


def test_bench_head_rows_small():
    before = torch.get_num_threads()
    try:
        rows = bench_head(n_gaussians=2000, d=4, repeats=2, threads=1)
    finally:
        torch.set_num_threads(before)
    names = {(r["name"], r["dtype"], r["pass"]) for r in rows}
    for name, dtype in [("hybrid-fused", "float32"), ("hybrid-torch", "float32"), ("naive-ref", "float32"),
                        ("naive-ref", "float64"), ("sh3", "float32"), ("color", "float32")]:
        for p in ("forward", "forward+backward"):
            assert (name, dtype, p) in names
    for r in rows:
        assert r["n_gaussians"] == 2000 and r["d"] == 4 and r["threads"] == 1
        assert len(r["runs_ms"]) == 2 and r["median_ms"] > 0
        assert r["speedup_vs_ref64"] > 0 and r["speedup_vs_ref32"] > 0
    ref = [r for r in rows if r["name"] == "naive-ref" and r["dtype"] == "float64"]
    assert all(r["speedup_vs_ref64"] == 1.0 for r in ref)
    table = format_table(rows)
    assert table.count("\n") == len(rows) + 1 and "hybrid-fused" in table


def test_bench_main_prints_table(capsys):
    before = torch.get_num_threads()
    try:
        assert main(["--n", "500", "--d", "2", "--repeats", "1"]) == 0
    finally:
        torch.set_num_threads(before)
    out = capsys.readouterr().out
    assert "| head | dtype | pass |" in out and "naive-ref" in out
