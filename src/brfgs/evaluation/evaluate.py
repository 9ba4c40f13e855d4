"""``brfgs evaluate OUT``: render every test view of a trained run and score it.

Writes ``OUT/metrics.json`` (docs/data-format.md schema: per view and mean psnr, ssim, lpips,
sam, psnr_spectral, and the mean per view ring under "rings"; each view and ring also carries the
angle to the nearest training view, "nearest_train_view_deg"; "observed" = the test images,
"truth" = the clean cubes of
``<scene>/truth/images/<name>.hdr`` when present), ENVI renders
``OUT/eval/renders/<name>.hdr`` and side-by-side CIR PNGs with error maps
``OUT/eval/cir/<name>.png``.

Another flight of the same site (``--scene OTHER`` whose frames are not the model's: another hour,
day or sun) is rendered from each of its frames' own cameras under each frame's own sun and
scored the same way (a model trained with shadows lit by each frame's sky, its diffuse fraction); its
results go to ``OUT/evaluate/<OTHER folder>-sun-scene/`` so that the run's own metrics stay.
``sun="model"`` renders every view under the sun (and sky) the model was trained under instead (what
the model predicts without relighting), into ``...-sun-model/``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tqdm import tqdm

from brfgs.evaluation import by_material
from brfgs.evaluation.shadows import ShadowScores, canopy_pixels, truth_visibility
from brfgs.evaluation import metrics as M
from brfgs.analysis.output import SPLITS, metrics_file
from brfgs.analysis.plots import save_cir_comparison
from brfgs.data import atomic, read_scene
from brfgs.data.cir import cir_composite
from brfgs.data.cube_io import write_envi
from brfgs.data.georef import check_same_origin
from brfgs.data.splits import split_rule_of
from brfgs.errors import UserError
from brfgs.model import MODEL_FILE, TrainedModel, camera_from_intrinsics, render

SUN_SOURCES = ("scene", "model")



def _scene_for(lm: TrainedModel, scene_path: str | Path | None, split: str = "test"):
    """The model's scene (or ``scene_path``), read as in training; UserError if it does not match."""
    cfg = lm.config
    root = Path(scene_path) if scene_path else Path(lm.scene["root"])
    if split not in SPLITS:
        raise UserError(f"split must be one of {SPLITS}, got {split!r}", field="split")
    if split == "validation" and not cfg.get("validation", False):
        raise UserError("the model was trained on every training view: there is no validation split "
                        "(train with --validation)", field="split")
    scene = read_scene(root, downscale=cfg["downscale"], split_seed=cfg["split_seed"],
                       split_rule=split_rule_of(cfg),
                       value_range=tuple(cfg["value_range"]), validation=bool(cfg.get("validation", False)),
                       allow_outside_links=bool(cfg.get("allow_outside_links", False)))
    where = root / "transforms.json"
    if len(scene.wavelengths_nm) != len(lm.wavelengths_nm) or not np.allclose(scene.wavelengths_nm, lm.wavelengths_nm):
        raise UserError("the scene's wavelengths differ from the model's", file=where, field="wavelengths_nm")
    if another_scene(lm, scene):  # another flight must share the model's world frame
        check_same_origin(lm.scene.get("origin"), scene.origin.to_json() if scene.origin else None, where)
    if not scene.indices_of(split):
        raise UserError(f"the scene has no {split} views", file=where, field="frames")
    return scene


def another_scene(lm: TrainedModel, scene) -> bool:
    """True when ``scene`` is not the flight the model was trained on: other frame names, or the same
    names under other suns (two flights of one layout at another hour)."""
    if [f.name for f in scene.frames] != [f["name"] for f in lm.scene["frames"]]:
        return True
    return any(not np.allclose((f.sun_zenith_deg, f.sun_azimuth_deg), lm.frame_sun(i), rtol=0.0, atol=1e-6)
               for i, f in enumerate(scene.frames))


def _view(lm: TrainedModel, scene, i: int, other: bool, sun: str):
    """(camera, sun zenith, sun azimuth) of frame ``i``: the model's camera and the frame's own sun, or for
    another flight the scene's camera and sun; ``sun="model"``: the sun the model was trained under."""
    f = scene.frames[i]
    cam = camera_from_intrinsics(f.c2w, scene.intrinsics, f.name) if other else lm.cameras[i]
    if sun == "model":
        return cam, lm.sun_zenith_deg, lm.sun_azimuth_deg
    return (cam, *lm.frame_sun(i)) if not other else (cam, float(f.sun_zenith_deg), float(f.sun_azimuth_deg))


def _sky(scene, i: int, sun: str):
    """The diffuse fraction [B] to light frame ``i`` of a model trained with shadows: the frame's own sky
    (its flight's), or for ``sun="model"`` the model's (None)."""
    return None if sun == "model" else scene.frame_diffuse_fraction(i)


def _references(scene, i: int) -> dict:
    """{"observed": (cube, valid), "truth": (cube, valid) when the scene has truth} of frame ``i``."""
    obs = scene.load_image(i)
    refs = {"observed": (obs, np.isfinite(obs).all(-1))}
    if scene.truth_dir is not None:
        tr = scene.load_truth(i)
        if tr is not None:
            refs["truth"] = (tr, np.isfinite(tr).all(-1))
    return refs


def _material_pixels(lm: TrainedModel, cam, scene, i: int, backend: str, r, ref: np.ndarray, ref_cir: np.ndarray,
                     ok: np.ndarray) -> dict | None:
    """Per-material pixels of view ``i`` against the truth (:func:`brfgs.evaluation.by_material.view_pixels`),
    or None when the scene has no material maps for it."""
    if r.cir is None:
        return None
    maps = by_material.truth_maps(scene, i, r.cir.shape[:2])
    if maps is None:
        return None
    alpha, depth, spread, normal = by_material.ray_depth_moments(lm, cam, backend)
    return by_material.view_pixels(maps[0], r.cir, ref_cir, ok, alpha, depth, spread, maps[1],
                                   r.cube if lm.spectral else None, ref if lm.spectral else None,
                                   (normal, cam.viewmat.numpy(), cam.K.numpy()))


def _score_view(lm: TrainedModel, scene, i: int, backend: str, out: Path | None, other: bool = False,
                sun: str = "scene") -> tuple[dict, dict | None]:
    """({against: metrics}, per-material pixels against the truth or None) of held-out view ``i`` (of
    another flight when ``other``); with ``out``, the CIR comparison PNGs and the ENVI render."""
    name = scene.frames[i].name
    cam, sun_z, sun_a = _view(lm, scene, i, other, sun)          # a held-out view under its own sun
    r = render(lm, cam, sun_zenith_deg=sun_z, sun_azimuth_deg=sun_a, backend=backend,
               diffuse_fraction=_sky(scene, i, sun))
    scores, materials = {}, None
    for against, (ref, ok) in _references(scene, i).items():
        ref_cir = cir_composite(ref, lm.cir_indices, lm.cir_scale)
        if against == "truth":
            materials = _material_pixels(lm, cam, scene, i, backend, r, ref, ref_cir, ok)
        m = M.image_metrics(r.cube, ref, r.cir, ref_cir, ok, spectral=lm.spectral,
                            spectral_reason="RGB-style model trained on CIR composites: no spectra (SAM '-')")
        scores[against] = m = {"name": name, **m}
        if out is not None:
            save_cir_comparison(out / "eval" / "cir" / f"{name}_vs_{against}.png", ref_cir, r.cir,
                                f"{scene.name} {name} [{lm.appearance}] vs {against}: PSNR {m['psnr'] or float('nan'):.2f} dB"
                                + (f", SAM {m['sam']:.4f} rad" if m.get("sam") is not None else ""))
    if out is not None and r.cube is not None:
        write_envi(out / "eval" / "renders" / f"{name}.hdr", r.cube, scene.wavelengths_nm, scene.fwhm_nm,
                   default_bands=lm.cir_indices, ignore_value=float("nan"))
    return scores, materials


def _settings(lm: TrainedModel, scene, backend: str) -> dict:
    return {
        "config": lm.config,
        "n_gaussians": lm.n_gaussians,
        "backend": backend,
        "bands_used": len(scene.wavelengths_nm),
        "cir_indices": list(lm.cir_indices),
        "cir_wavelengths_nm": [float(scene.wavelengths_nm[j]) for j in lm.cir_indices],
        "cir_scale": [float(v) for v in lm.cir_scale],
        "metric_definitions": "docs/data-format.md: PSNR/SSIM/LPIPS on CIR composites (data range 1), SAM (rad) and "
                              "psnr_spectral over all bands; SSIM 11x11 Gaussian window sigma 1.5",
        "autoencoder": lm.meta.get("autoencoder_report", {}).get("test"),
        "train_timings_s": lm.meta.get("timings_s"),
        "eval_seconds": None,
    }


def ring_means(views: list[dict], rings: dict[str, str]) -> dict:
    """{ring: {"n_views", mean metrics}} of per-view metric dicts (``rings``: frame name -> ring).

    Where the views carry "nearest_train_view_deg" (held-out views: the angle to the nearest training
    view), the ring gets its {"mean", "max"}: how far the ring's metrics extrapolate (docs/flights.md).
    """
    out = {}
    for r in sorted({rings[v["name"]] for v in views}, key=float):
        sel = [v for v in views if rings[v["name"]] == r]
        out[r] = {"n_views": len(sel), **M.mean_metrics(sel)}
        ang = [v["nearest_train_view_deg"] for v in sel if "nearest_train_view_deg" in v]
        if ang:
            out[r]["nearest_train_view_deg"] = {"mean": round(float(np.mean(ang)), 1), "max": float(max(ang))}
    return out


def material_means(by_view: dict[str, dict], rings: dict[str, str], names: dict[int, str]) -> dict:
    """{"definitions", "mean": {material: stats}, "rings": {ring: {material: stats}}} pooled over the
    views (:func:`brfgs.evaluation.by_material.summarise`) of per-material pixels ``by_view`` (name -> pixels)."""
    ring_of = {r: [v for n, v in by_view.items() if rings[n] == r] for r in sorted({rings[n] for n in by_view}, key=float)}
    return {"definitions": by_material.DEFINITIONS, "mean": by_material.summarise(list(by_view.values()), names),
            "rings": {r: by_material.summarise(v, names) for r, v in ring_of.items()}}


def evaluate_run(out_dir: str | Path, scene_path: str | Path | None = None, backend: str | None = None,
                 write_images: bool = True, progress: bool = True, model_file: str = MODEL_FILE,
                 split: str = "test", sun: str = "scene") -> dict:
    """Evaluate the trained model of ``out_dir`` on its ``split`` views ("test", "validation" for
    a run trained with ``--validation``, or "train": the fit of its own training views); writes and
    returns the metrics dict (metrics.json, metrics_validation.json or metrics_train.json), whose
    "evaluation" block says where (``OUT``, or ``OUT/evaluate/<scene>-sun-<sun>`` for another flight
    or ``sun="model"``: see the module docstring).

    ``backend`` None: the rasterizer backend the model was trained with (recorded in
    metrics.json), so that the evaluation at the end of ``brfgs train`` and a later
    ``brfgs evaluate`` give the same digits.
    """
    out = Path(out_dir)
    mpath = out / model_file
    if not mpath.is_file():
        raise UserError(f"no {model_file}: train first (brfgs train SCENE {out})", file=out)
    lm = TrainedModel.load(mpath)
    backend = backend or lm.config.get("backend", "auto")
    if sun not in SUN_SOURCES:
        raise UserError(f"sun must be one of {', '.join(SUN_SOURCES)}, got {sun!r}", field="--sun")
    scene = _scene_for(lm, scene_path, split)
    other = another_scene(lm, scene)
    dest = out if not other and sun == "scene" else out / "evaluate" / f"{Path(scene.root).resolve().name}-sun-{sun}"
    views = {"observed": [], "truth": []}
    by_mat: dict[str, dict] = {}                              # view name -> per-material pixels
    t0 = time.perf_counter()
    images_out = dest if write_images and split == "test" else None
    shadows = ShadowScores(lm, backend)
    for i in tqdm(scene.indices_of(split), desc=f"evaluate ({split})", leave=False, disable=not progress):
        scores, materials = _score_view(lm, scene, i, backend, images_out, other, sun)
        true_vis = truth_visibility(scene, i, (scene.height, scene.width))
        if true_vis is not None:
            shadows.add(*_view(lm, scene, i, other, sun), true_vis, canopy_pixels(scene, i, true_vis.shape))
        for against, m in scores.items():
            views[against].append(m)
        if materials is not None:
            by_mat[scene.frames[i].name] = materials
    rings, record = scene.rings(), scene.split_record()
    nearest = {} if other else record["nearest_train_view_deg"]  # held-out views of the model's own flight
    for v in views["observed"] + views["truth"]:
        if v["name"] in nearest:
            v["nearest_train_view_deg"] = nearest[v["name"]]
    result = {"scene": scene.name, "scene_root": str(Path(scene.root).resolve()), "model": _model_name(lm),
              "evaluated_split": split, "split": record, "settings": _settings(lm, scene, backend),
              "evaluation": {"another_scene": other, "sun": sun, "folder": str(dest.resolve())},
              "against": {k: {"mean": M.mean_metrics(v), "rings": ring_means(v, rings), "views": v}
                          for k, v in views.items() if v}}
    if by_mat and "truth" in result["against"]:
        result["against"]["truth"]["materials"] = material_means(by_mat, rings, by_material.material_names(
            scene.truth_dir))
    if shadows.summary() is not None and "truth" in result["against"]:
        result["against"]["truth"]["shadows"] = shadows.summary()
    result["settings"]["eval_seconds"] = time.perf_counter() - t0
    atomic.write_json(dest / metrics_file(split), result)
    return result


def _model_name(lm: TrainedModel) -> str:
    c = lm.config
    if c["variant"] == "brf":
        comps = tuple(c["components"])
        name = "BRF-GS" if comps == ("iso", "vol", "geo", "spec") else "BRF-GS[" + "+".join(comps) + "]"
        return name + (" (joint)" if c["joint"] else "")
    return {"sh": "SH-3 (latent)", "neural": "Neural decoder (MS-Splatting-style)", "cir": "3DGS (CIR)"}[c["variant"]] + (
        " (joint)" if c["joint"] and c["variant"] != "cir" else "")


def summary_lines(result: dict) -> list[str]:
    """Short human-readable lines of a metrics dict."""
    lines = []
    for against, block in result["against"].items():
        m = block["mean"]

        def f(k, fmt):
            return "-" if m.get(k) is None else format(m[k], fmt)

        lines.append(f"{result['model']:<28} vs {against:<8}: PSNR {f('psnr', '.2f')} dB  SSIM {f('ssim', '.3f')}  "
                     f"SAM {f('sam', '.4f')} rad  PSNR-spectral {f('psnr_spectral', '.2f')} dB  LPIPS {f('lpips', '.3f')}")
        rings = block.get("rings") or {}
        if len(rings) > 1:
            near = any(v.get("nearest_train_view_deg") for v in rings.values())
            lines.append(" " * 29 + "per ring" + (" [angle to the nearest training view]" if near else "") + ": " + ", ".join(
                f"{r}° {v['psnr']:.2f} dB" + (f"/{v['sam']:.4f}" if v.get("sam") is not None else "")
                + (f" [{v['nearest_train_view_deg']['mean']:.0f}°]" if v.get("nearest_train_view_deg") else "")
                for r, v in rings.items() if v.get("psnr") is not None))
        sh = block.get("shadows")
        if sh and sh.get("iou") is not None:
            cast = sh.get("cast") or {}
            lines.append(" " * 29 + f"shadows (model geometry vs truth): IoU {sh['iou']:.2f}, accuracy "
                         f"{sh['accuracy']:.2f}, shadow share {sh['shadow_share_model']:.0%} vs {sh['shadow_share_truth']:.0%}"
                         + (f"; outside crowns IoU {cast['iou']:.2f}" if cast.get("iou") is not None else ""))
        mats = list((block.get("materials") or {}).get("mean", {}).items())[:4]
        if mats:
            lines.append(" " * 29 + "largest error: " + ", ".join(
                f"{n} {v['error_share']:.0%} ({v['psnr']:.1f} dB, alpha {v['alpha']:.2f})" for n, v in mats
                if v.get("error_share") is not None and v.get("alpha") is not None))
    return lines
