"""Issue 15's targets over several scenes: BRF-GS against SH-3 (same stage 1) and joint training.

    python scripts/scene_margins.py LABEL=DIR [LABEL=DIR ...] [--against truth|observed] > margins.md

Each DIR holds three ``brfgs train ... --validation`` runs of one scene:
``DIR/default`` (the default), ``DIR/sh`` (``--variant sh --from-stage1
DIR/default/checkpoints/stage1.safetensors``) and ``DIR/joint`` (``--joint``). A missing run shows
as "–". Per scene: CIR PSNR / SAM on the validation and test views, BRF-GS − SH-3 (test / val, dB),
SAM ratio BRF-GS / SH-3, the joint run, the test PSNR per view ring, and the 18° − 58° gap.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

RINGS = ("18", "23", "38", "58")


def _load(run: Path, name: str, against: str) -> dict | None:
    path = run / name
    return json.loads(path.read_text())["against"][against] if path.exists() else None


def _pair(m: dict | None) -> str:
    return f"{m['mean']['psnr']:.2f} / {m['mean']['sam']:.4f}" if m else "–"


def _gap(m: dict | None) -> str:
    if not m or not all(k in m["rings"] for k in ("18", "58")):
        return "–"
    return f"{m['rings']['18']['psnr'] - m['rings']['58']['psnr']:.2f}"


def _row(label: str, root: Path, against: str) -> str:
    test = {k: _load(root / k, "metrics.json", against) for k in ("default", "sh", "joint")}
    val = {k: _load(root / k, "metrics_validation.json", against) for k in ("default", "sh")}
    d, s, dv, sv = test["default"], test["sh"], val["default"], val["sh"]
    if d is None:
        return f"| {label} | (no finished default run in {root}) |" + " |" * 7
    margin = ratio = "–"
    if s and sv and dv:
        margin = f"{d['mean']['psnr'] - s['mean']['psnr']:+.2f} / {dv['mean']['psnr'] - sv['mean']['psnr']:+.2f}"
        ratio = f"{d['mean']['sam'] / s['mean']['sam']:.2f} / {dv['mean']['sam'] / sv['mean']['sam']:.2f}"
    rings = " / ".join(f"{d['rings'][k]['psnr']:.2f}" if k in d["rings"] else "–" for k in RINGS)
    return (f"| {label} | {_pair(dv)} | {_pair(d)} | {_pair(s)} | {margin} | {ratio} | {_pair(test['joint'])} "
            f"| {rings} | {_gap(d)} / {_gap(dv)} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", help="LABEL=DIR")
    ap.add_argument("--against", default="truth", choices=("truth", "observed"))
    args = ap.parse_args()
    print("| scene | default: val PSNR / SAM | default: test PSNR / SAM | SH-3 (same stage 1): test PSNR / SAM "
          "| BRF-GS − SH-3 dB (test / val) | SAM ratio (test / val) | joint: test PSNR / SAM "
          "| test PSNR 18° / 23° / 38° / 58° | 18° − 58° dB (test / val) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for item in args.scenes:
        label, _, path = item.partition("=")
        print(_row(label, Path(path or label), args.against))


if __name__ == "__main__":
    main()
