"""Issue 15's targets over several scenes: BRF-GS against SH-3 (same stage 1) and joint training.

    python scripts/scene_margins.py LABEL=DIR [LABEL=DIR ...] [--against truth|observed] > margins.md

Each DIR holds three ``brfgs train ... --validation`` runs of one scene:
``DIR/default`` (the default), ``DIR/sh`` (``--variant sh --from-stage1
DIR/default/checkpoints/stage1.safetensors``) and ``DIR/joint`` (``--joint``). A missing run shows
as "–". Per scene: CIR PSNR / SAM on the validation and test views, BRF-GS − SH-3 (test / val, dB),
SAM ratio BRF-GS / SH-3, the joint run, the test PSNR per view ring (the scene's own rings, e.g.
18 / 23 / 38 / 58° or tsC64's 12 / 30 / 45 / 60°), the gap from the lowest oblique ring (the lowest
ring of 5° or more) to the highest, and the pond where ``brfgs brf DIR/default --roi material:water
--bands 480,860 --no-polar --truth-size 64 --truth-spp 16`` has run: the backscatter side of its principal plane (view zenith ≥ 5° on the sun's
side), mean |model − truth| at the longest band (860 nm), and the principal plane's RMSE per band.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _load(run: Path, name: str, against: str) -> dict | None:
    path = run / name
    return json.loads(path.read_text())["against"][against] if path.exists() else None


def _pair(m: dict | None) -> str:
    return f"{m['mean']['psnr']:.2f} / {m['mean']['sam']:.4f}" if m else "–"


def _rings(m: dict) -> list[str]:
    """The view rings of a metrics dict (zenith labels in degrees), lowest first."""
    return sorted(m["rings"], key=float)


def _gap(m: dict | None) -> str:
    """PSNR of the lowest oblique ring (≥ 5°) minus that of the highest ring, dB."""
    rings = [k for k in _rings(m) if float(k) >= 5.0] if m else []
    if len(rings) < 2:
        return "–"
    return f"{m['rings'][rings[0]]['psnr'] - m['rings'][rings[-1]]['psnr']:.2f}"


def _pond(run: Path) -> str:
    """The pond's 860 nm backscatter-side error and its principal-plane RMSE per band, from brf.json."""
    path = run / "analysis" / "brf_water" / "brf.json"
    if not path.exists():
        return "–"
    vs = json.loads(path.read_text())["principal_plane"].get("vs_truth_render")
    if not vs:
        return "–"
    back = vs["mean_abs_error_by_side"]["backscatter"]
    longest = max(back, key=float)
    rmse = " / ".join("–" if v is None else f"{v:.4f}" for v in vs["rmse"].values())
    return f"{back[longest]:.4f} ({rmse})"


def _row(label: str, root: Path, against: str) -> str:
    test = {k: _load(root / k, "metrics.json", against) for k in ("default", "sh", "joint")}
    val = {k: _load(root / k, "metrics_validation.json", against) for k in ("default", "sh")}
    d, s, dv, sv = test["default"], test["sh"], val["default"], val["sh"]
    if d is None:
        return f"| {label} | (no finished default run in {root}) |" + " |" * 8
    margin = ratio = "–"
    if s and sv and dv:
        margin = f"{d['mean']['psnr'] - s['mean']['psnr']:+.2f} / {dv['mean']['psnr'] - sv['mean']['psnr']:+.2f}"
        ratio = f"{d['mean']['sam'] / s['mean']['sam']:.2f} / {dv['mean']['sam'] / sv['mean']['sam']:.2f}"
    names = _rings(d)
    rings = " / ".join(f"{d['rings'][k]['psnr']:.2f}" for k in names) + f" ({'/'.join(names)}°)"
    return (f"| {label} | {_pair(dv)} | {_pair(d)} | {_pair(s)} | {margin} | {ratio} | {_pair(test['joint'])} "
            f"| {rings} | {_gap(d)} / {_gap(dv)} | {_pond(root / 'default')} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", help="LABEL=DIR")
    ap.add_argument("--against", default="truth", choices=("truth", "observed"))
    args = ap.parse_args()
    print("| scene | default: val PSNR / SAM | default: test PSNR / SAM | SH-3 (same stage 1): test PSNR / SAM "
          "| BRF-GS − SH-3 dB (test / val) | SAM ratio (test / val) | joint: test PSNR / SAM "
          "| test PSNR per ring | lowest − highest ring dB (test / val) "
          "| pond: 860 nm backscatter error (principal-plane RMSE per band) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for item in args.scenes:
        label, _, path = item.partition("=")
        print(_row(label, Path(path or label), args.against))


if __name__ == "__main__":
    main()
