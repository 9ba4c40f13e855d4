"""Where do a run's held-out views lose accuracy? CIR PSNR against truth per view ring and per
surface class (simulated scenes: truth/materials/<view>.npy holds the material ids).

Classes: far field (the simulator's flat surroundings beyond its 120 m core, from the truth
depth), canopy (broadleaf, needles, bark, shrub), water, other ground. Also the share of
pixels and of squared error each class has, the mean rendered alpha and the median
|rendered − true depth| (m, along the optical axis, pixels with alpha > 0.5) per class.

    python scripts/diagnose_rings.py RUN [RUN ...] [--split test|validation|train] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from brfgs.evaluation.evaluate import _scene_for
from brfgs.data.cameras import pixel_rays
from brfgs.data.cir import cir_composite
from brfgs.model import MODEL_FILE, TrainedModel, render
from brfgs.sim.geometry import CORE_HALF_M
from brfgs.sim.materials import MATERIAL_IDS

CLASSES = {
    "canopy": ("broadleaf", "needles", "bark", "shrub"),
    "water": ("water",),
}


def _far_field(depth_m: np.ndarray, c2w: np.ndarray, intr) -> np.ndarray:  # [H, W] bool
    """Pixels whose truth surface point lies outside the simulator's core (|x| or |y| > CORE_HALF_M)."""
    o, d = pixel_rays(c2w, intr)  # [H, W, 3]
    fwd = -np.asarray(c2w)[:3, 2]  # OpenGL camera: looks down -z
    p = o + (depth_m / (d @ fwd))[..., None] * d
    return (np.abs(p[..., 0]) > CORE_HALF_M) | (np.abs(p[..., 1]) > CORE_HALF_M)


def _classes(mat: np.ndarray, far: np.ndarray) -> dict[str, np.ndarray]:
    out, used = {"far_field": far}, far.copy()
    for name, mats in CLASSES.items():
        m = np.isin(mat, [MATERIAL_IDS[x] for x in mats]) & ~far
        out[name] = m
        used |= m
    out["other"] = ~used & (mat > 0)
    return out


def _psnr(se: np.ndarray) -> float | None:
    return None if se.size == 0 else float(-10 * np.log10(max(se.mean(), 1e-12)))


def diagnose(run: Path, split: str = "test") -> dict:
    tm = TrainedModel.load(run / MODEL_FILE)
    scene = _scene_for(tm, None, "test" if split == "train" else split)  # train: how well the fit holds
    rings = scene.rings()
    acc: dict[str, dict[str, list]] = {}
    for i in scene.indices_of(split):
        name = scene.frames[i].name
        truth = scene.load_truth(i)
        mat = np.load(scene.truth_dir / "materials" / f"{name}.npy")
        depth = np.load(scene.truth_dir / "depth" / f"{name}.npy")
        far = _far_field(depth, scene.frames[i].c2w, scene.intrinsics)
        r = render(tm, tm.cameras[i])
        derr = np.where(r.alpha > 0.5, np.abs(r.depth - depth), np.nan)  # [H, W] m
        se = ((r.cir - cir_composite(truth, tm.cir_indices, tm.cir_scale)) ** 2).mean(-1)  # [H, W]
        ring = acc.setdefault(rings[name], {})
        for cls, m in {"all": np.ones(mat.shape, bool), **_classes(mat, far)}.items():
            ring.setdefault(cls, []).append((se[m], r.alpha[m], derr[m]))
    report = {}
    for ring, per in sorted(acc.items(), key=lambda kv: float(kv[0])):
        total = np.concatenate([x for x, _, _ in per["all"]])
        report[ring] = {}
        for cls, parts in per.items():
            se = np.concatenate([x for x, _, _ in parts])
            al = np.concatenate([a for _, a, _ in parts])
            de = np.concatenate([d for _, _, d in parts])
            de = de[np.isfinite(de)]
            report[ring][cls] = {"psnr": _psnr(se), "pixel_share": se.size / total.size,
                                 "error_share": float(se.sum() / max(total.sum(), 1e-12)),
                                 "mean_alpha": float(al.mean()) if al.size else None,
                                 "median_depth_error_m": float(np.median(de)) if de.size else None}
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--split", default="test", choices=("test", "validation", "train"))
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    out = {}
    for run in a.runs:
        rep = out[str(run)] = diagnose(run, a.split)
        print(f"\n{run} ({a.split})")
        print(f"{'ring':>5} {'class':>10} {'PSNR':>7} {'pixels':>7} {'error':>7} {'alpha':>6} {'|dz| m':>7}")
        for ring, per in rep.items():
            for cls, m in per.items():
                p = "-" if m["psnr"] is None else f"{m['psnr']:.2f}"
                al = "-" if m["mean_alpha"] is None else f"{m['mean_alpha']:.3f}"
                dz = "-" if m["median_depth_error_m"] is None else f"{m['median_depth_error_m']:.2f}"
                print(f"{ring:>5} {cls:>10} {p:>7} {m['pixel_share']:>7.1%} {m['error_share']:>7.1%} {al:>6} {dz:>7}")
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
