"""Stage 2 of a new run from the end of another run's stage 1 (``brfgs train --from-stage1 CKPT``).

Only the geometry comes from the checkpoint: the Gaussians (means, scales, rotations, opacities, with
the stage-1 colours and background they were fitted with), the camera poses the geometry was fitted in
(known or SfM), the band selection and the scene extent, and the stage-1 run's random stream. Everything
else is this command's: the scene's frames and fields (root, sun, diffuse fraction, georeference; its
images, read with its irradiance and dark frames) and the options. The spectral decoder is reused when
the options ask for the checkpoint's basis; another basis is fitted anew on this scene's pixels.

The checkpoint is refused, naming it and the field, when this scene's frames are not those the
geometry was fitted on: other frame names or order, another split, another camera (image size,
intrinsics, downscale, region of interest) or other wavelengths.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from brfgs.data.cir import cir_scale
from brfgs.errors import UserError
from brfgs.model import DensifyState, scene_description
from brfgs.spectral.decoders import basis_kind
from brfgs.train.config import TrainConfig
from brfgs.train.phases import Phase
from brfgs.train.state import TrainState

# the pixel model the geometry was fitted with: must be the same in stage 2
PIXEL_MODEL_OPTIONS = ("supersample", "antialias")
# the stage-1 run's timings this run keeps (the set-up it did not repeat)
KEPT_TIMINGS = ("bands", "init", "autoencoder", "stage1")
NOT_STAGE1 = "not a stage-1 checkpoint (expected checkpoints/stage1.safetensors of a decoupled run)"


def check_stage1_options(saved: TrainConfig, cfg: TrainConfig, path: Path) -> None:
    """UserError unless ``saved`` (the checkpoint's options) made a decoupled stage 1 that ``cfg`` can
    continue: a decoupled spectral variant, the same latent size and pixel model."""
    if saved.variant == "cir" or saved.joint:
        raise UserError(NOT_STAGE1, file=path)
    if cfg.variant == "cir" or cfg.joint:
        raise UserError("--from-stage1 needs a decoupled spectral variant (brf, sh, neural)", field="from_stage1")
    if saved.latent_dim != cfg.latent_dim:
        raise UserError("latent_dim differs from the stage-1 run", file=path, field="latent_dim")
    for name in PIXEL_MODEL_OPTIONS:
        if getattr(saved, name) != getattr(cfg, name):
            raise UserError(f"{name} is {getattr(cfg, name)}, but the stage-1 run fitted its geometry with "
                            f"{getattr(saved, name)}: give the same (e.g. the stage-1 run's --preset)",
                            file=path, field=name)


def _close(a, b, rel: float = 1e-9, abs_: float = 1e-9) -> bool:
    return all(math.isclose(float(x), float(y), rel_tol=rel, abs_tol=abs_) for x, y in zip(a, b)) and len(a) == len(b)


def check_same_frames(saved: dict, scene, path: Path) -> None:
    """UserError naming the checkpoint ``path`` and the field unless ``scene`` (this command's
    :class:`brfgs.data.Scene`) has the frames the checkpoint's scene description ``saved`` was fitted
    on: the same wavelengths (nm), camera, downscale, region of interest, frame names in order and split."""
    def refuse(field: str, message: str) -> None:
        raise UserError(f"{message}: the stage-1 geometry was fitted on other frames (give the scene the "
                        "stage-1 run was trained on, or a copy with the same frames)", file=path, field=field)

    wl = [float(w) for w in scene.wavelengths_nm]
    if not _close(saved["wavelengths_nm"], wl, abs_=1e-6):
        refuse("scene.wavelengths_nm", f"this scene has {len(wl)} bands at {wl[0]:g}-{wl[-1]:g} nm, the checkpoint "
               f"{len(saved['wavelengths_nm'])} at {saved['wavelengths_nm'][0]:g}-{saved['wavelengths_nm'][-1]:g} nm")
    intr, si = scene.intrinsics, saved["intrinsics"]
    if (int(si["w"]), int(si["h"])) != (int(intr.w), int(intr.h)):
        refuse("scene.intrinsics",
               f"this scene's images are {intr.w}x{intr.h} px, the checkpoint's {si['w']}x{si['h']}")
    if not _close([si[k] for k in ("fl_x", "fl_y", "cx", "cy")], [intr.fl_x, intr.fl_y, intr.cx, intr.cy]):
        refuse("scene.intrinsics", "this scene's camera (focal length, principal point) differs from the checkpoint's")
    roi = getattr(scene, "roi", None)
    for key, mine in (("downscale", int(getattr(scene, "downscale", 1))), ("roi", None if roi is None else list(roi))):
        theirs = saved.get(key, 1 if key == "downscale" else None)
        if (list(theirs) if isinstance(theirs, (list, tuple)) else theirs) != mine:
            refuse(f"scene.{key}", f"this scene is read with {key} {mine!r}, the checkpoint with {saved.get(key)!r}")
    names = [f.name for f in scene.frames]
    theirs = [f["name"] for f in saved["frames"]]
    if len(names) != len(theirs):
        refuse("scene.frames", f"this scene has {len(names)} frames, the checkpoint {len(theirs)}")
    if names != theirs:
        k = next(i for i, (a, b) in enumerate(zip(names, theirs)) if a != b)
        refuse(f"scene.frames[{k}].name", f"this scene's frame {k} is {names[k]!r}, the checkpoint's {theirs[k]!r}")
    mine_split, their_split = scene.split_record(), saved.get("split") or {}
    for part in ("train", "test", "validation"):
        if mine_split.get(part, []) != their_split.get(part, []):
            refuse(f"scene.split.{part}", f"this scene's {part} frames differ from the checkpoint's (another "
                   "split_seed or split?)")


def start_from_stage1(st: TrainState, scene, cfg: TrainConfig, path: Path, fit_decoder) -> None:
    """Load the stage-1 checkpoint ``path`` into ``st`` for a run of ``cfg`` on ``scene`` (see the module
    docstring); ``fit_decoder()`` fits the spectral decoder of ``cfg`` anew (called when the checkpoint
    holds another basis). Leaves ``st`` ready for stage 2's set-up."""
    tensors, meta = st.load_checkpoint(path)
    saved = TrainConfig.from_written(meta["config"], source=str(path))  # another build's options: name the file
    if meta["phase"] != Phase.STAGE1.value or int(meta["step"]) != saved.stage1_steps:
        raise UserError(NOT_STAGE1, file=path)
    check_stage1_options(saved, cfg, path)
    check_same_frames(meta["scene"], scene, path)
    # this scene's description (root, sun, sky, georeference, split) with the poses the geometry was fitted in
    c2w = np.asarray([fr["c2w"] for fr in meta["scene"]["frames"]], float).reshape(-1, 4, 4)
    st.meta["scene"] = scene_description(scene, c2w)
    st.meta["cir_scale"] = [float(v) for v in cir_scale(scene)]
    st.meta["stage1_from"] = str(Path(path).resolve())
    st.neural = None
    st.densify = DensifyState(st.gaussians.n)
    st.timings = {k: v for k, v in st.timings.items() if k in KEPT_TIMINGS}
    if basis_kind(st.decoder) != cfg.spectral_basis:
        st.timings.pop("autoencoder", None)
        st.meta.pop("autoencoder_report", None)
        fit_decoder()
    # continue the stage-1 run's random stream (view order, ray samples): with the same options and
    # scene, a run started from a stage-1 checkpoint reproduces the continuous run exactly
    if "rng.torch" in tensors:
        st.gen.set_state(tensors["rng.torch"])
    st.perm = list(meta.get("perm", []))
