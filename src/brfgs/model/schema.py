"""Validation of a model file's metadata and tensors (``model.safetensors``, checkpoints).

A model file is written by brfgs, but it travels: it may be truncated, edited or come from
another version. Everything :class:`brfgs.model.trained.TrainedModel` reads is checked here
first, and a problem is a :class:`brfgs.errors.UserError` naming the file and the field.
"""

from __future__ import annotations

import math
from pathlib import Path

from torch import Tensor

from brfgs.data.sky import MAX_DIFFUSE_FRACTION
from brfgs.errors import UserError
from brfgs.model.gaussians import APPEARANCES, GEOMETRY_KEYS
from brfgs.model.layout import DescriptionError, layout_problem
from brfgs.spectral.decoders import DESCRIPTION_KEYS, SPECTRAL_BASES

INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check(cond: bool, message: str, path: Path, field: str) -> None:
    if not cond:
        raise UserError(message, file=path, field=field)


def _check_scene(scene, path: Path) -> None:
    """The scene description (brfgs.model.camera.scene_description)."""
    _check(isinstance(scene, dict), "expected an object", path, "scene")
    wl = scene.get("wavelengths_nm")
    _check(isinstance(wl, list) and len(wl) > 0 and all(_number(w) and w > 0 for w in wl),
           "expected a non-empty list of positive wavelengths (nm)", path, "scene.wavelengths_nm")
    _check(_number(scene.get("sun_zenith_deg")) and 0 <= scene["sun_zenith_deg"] < 90,
           "expected a sun zenith in [0, 90) degrees", path, "scene.sun_zenith_deg")
    _check(_number(scene.get("sun_azimuth_deg")), "expected a finite sun azimuth (deg)", path, "scene.sun_azimuth_deg")
    _check_diffuse(scene.get("diffuse_fraction"), len(wl), path, "scene.diffuse_fraction")
    intr = scene.get("intrinsics")
    _check(isinstance(intr, dict) and all(_number(intr.get(k)) for k in INTRINSIC_KEYS)
           and intr["fl_x"] > 0 and intr["fl_y"] > 0 and int(intr["w"]) >= 1 and int(intr["h"]) >= 1,
           f"expected positive numbers {', '.join(INTRINSIC_KEYS)}", path, "scene.intrinsics")
    frames = scene.get("frames")
    _check(isinstance(frames, list), "expected a list of frames", path, "scene.frames")
    for k, fr in enumerate(frames):
        ok = isinstance(fr, dict) and isinstance(fr.get("name"), str) and isinstance(fr.get("c2w"), list) \
            and len(fr["c2w"]) == 4 and all(isinstance(r, list) and len(r) == 4 and all(_number(x) for x in r)
                                            for r in fr["c2w"])
        _check(ok, "expected {name, c2w: 4x4 finite numbers}", path, f"scene.frames[{k}]")
        _check_diffuse(fr.get("diffuse_fraction"), len(wl), path, f"scene.frames[{k}].diffuse_fraction")


def _check_diffuse(df, n_bands: int, path: Path, field: str) -> None:
    _check(df is None or (isinstance(df, list) and len(df) == n_bands
                          and all(_number(v) and 0 <= v <= MAX_DIFFUSE_FRACTION for v in df)),
           f"expected one diffuse fraction in [0, {MAX_DIFFUSE_FRACTION}] per band", path, field)


def check_metadata(meta: dict, path: Path) -> None:
    """UserError (file and field named) unless ``meta`` has what a trained model needs."""
    _check_scene(meta.get("scene"), path)
    _check(meta.get("appearance") in APPEARANCES, f"expected one of {APPEARANCES}", path, "appearance")
    for key in ("latent_dim", "n_colors"):
        v = meta.get(key)
        _check(isinstance(v, int) and not isinstance(v, bool) and v >= 1, "expected a positive integer", path, key)
    _check(isinstance(meta.get("config"), dict), "expected an object (the training options)", path, "config")
    _check(isinstance(meta.get("head"), dict) and isinstance(meta["head"].get("kind"), str),
           "expected an object with a 'kind'", path, "head")
    n_bands = len(meta["scene"]["wavelengths_nm"])
    ci = meta.get("cir_indices")
    _check(isinstance(ci, list) and len(ci) == 3 and all(isinstance(i, int) and 0 <= i < n_bands for i in ci),
           f"expected three band indices in 0..{n_bands - 1}", path, "cir_indices")
    cs = meta.get("cir_scale")
    _check(isinstance(cs, list) and len(cs) == 3 and all(_number(v) and v > 0 for v in cs),
           "expected three positive numbers", path, "cir_scale")
    if meta["appearance"] != "cir":
        basis = meta.get("spectral_basis", "autoencoder")  # files written before the linear basis: the autoencoder
        _check(basis in SPECTRAL_BASES, f"expected one of {', '.join(SPECTRAL_BASES)}", path, "spectral_basis")
        key = DESCRIPTION_KEYS[basis]
        _check(isinstance(meta.get(key), str), f"expected the {basis} decoder's description", path, key)


def check_tensors(tensors: dict[str, Tensor], meta: dict, path: Path) -> None:
    """UserError unless the Gaussian tensors exist, agree in their row count and are finite, and the
    file holds exactly the tensors a model of its kind holds (:func:`brfgs.model.layout.layout_problem`:
    a missing one or one of another kind is refused, checksum or not)."""
    n = None
    for key in GEOMETRY_KEYS:
        t = tensors.get("param." + key)
        _check(t is not None, "missing tensor", path, "param." + key)
        n = t.shape[0] if n is None else n
        _check(t.shape[0] == n, f"has {t.shape[0]} rows, expected {n}", path, "param." + key)
    for name, t in tensors.items():
        if name.startswith("param.") and t.shape[:1] != (n,):
            raise UserError(f"has shape {tuple(t.shape)}, expected {n} rows", file=path, field=name)
        if t.is_floating_point() and not bool(t.isfinite().all()) and not name.startswith("rng."):
            raise UserError("holds NaN or infinite values (damaged file?)", file=path, field=name)
    if meta["appearance"] != "cir":
        _check(any(k.startswith("decoder.") for k in tensors), "missing the decoder's tensors", path, "decoder.")
    try:
        problem = layout_problem(tensors, meta)
    except DescriptionError as exc:  # a description the tensor names cannot come from
        raise UserError(f"not a description brfgs writes ({exc})", file=path, field=exc.field) from None
    if problem is not None:
        raise UserError(problem[1], file=path, field=problem[0])
