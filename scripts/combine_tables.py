"""Combine one study's tables over several scenes (choose defaults over all of them, not one).

    python scripts/combine_tables.py --study additions [--validation] [--against truth] OUT1 OUT2 ... > combined.md

Each OUT is a ``brfgs ablate SCENE OUT --study S`` folder holding ``table_<S>[_validation].csv``.
For every run name present in all of them: CIR PSNR and SAM per scene, their means over the scenes,
and the worst (over scenes) gap between the lowest and the highest view ring's PSNR.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def _read(path: Path) -> dict[str, dict]:
    with open(path, newline="") as fh:
        return {r["run"]: r for r in csv.DictReader(fh)}


def _num(v) -> float | None:
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def _ring_gap(row: dict, against: str) -> float | None:
    pre = f"psnr_{against}_ring"
    rings = {float(k[len(pre):]): _num(v) for k, v in row.items() if k.startswith(pre) and _num(v) is not None}
    rings = {k: v for k, v in rings.items() if k > 0}  # nadir has one view at most
    if len(rings) < 2:
        return None
    return rings[min(rings)] - rings[max(rings)]  # lowest-zenith ring minus highest-zenith ring (dB)


def combine(outs: list[Path], study: str, validation: bool, against: str) -> str:
    name = f"table_{study}{'_validation' if validation else ''}.csv"
    tables = {o.name or str(o): _read(o / name) for o in outs}
    runs = [r for r in next(iter(tables.values())) if all(r in t for t in tables.values())]
    scenes = list(tables)
    head = ["run", "setting"] + [f"{s} PSNR / SAM" for s in scenes] + ["mean PSNR", "mean SAM", "worst ring gap (dB)"]
    lines = [f"# Study '{study}' over {len(scenes)} scenes ({'validation' if validation else 'test'} views, "
             f"against {against})", "",
             "ring gap = PSNR of the lowest-zenith ring minus that of the highest (e.g. 18° − 58°), worst scene.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for run in runs:
        ps = [_num(tables[s][run].get(f"psnr_{against}")) for s in scenes]
        ss = [_num(tables[s][run].get(f"sam_{against}")) for s in scenes]
        gaps = [g for g in (_ring_gap(tables[s][run], against) for s in scenes) if g is not None]
        cells = [run, tables[scenes[0]][run]["setting"]]
        cells += [("–" if p is None else f"{p:.2f}") + " / " + ("–" if q is None else f"{q:.4f}") for p, q in zip(ps, ss)]
        okp, oks = [p for p in ps if p is not None], [q for q in ss if q is not None]
        cells += [f"{sum(okp) / len(okp):.2f}" if len(okp) == len(ps) else "–",
                  f"{sum(oks) / len(oks):.4f}" if len(oks) == len(ss) else "–",
                  f"{max(gaps):.2f}" if gaps else "–"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outs", nargs="+", type=Path)
    ap.add_argument("--study", default="additions")
    ap.add_argument("--validation", action="store_true")
    ap.add_argument("--against", default="truth")
    a = ap.parse_args()
    print(combine(a.outs, a.study, a.validation, a.against), end="")


if __name__ == "__main__":
    main()
