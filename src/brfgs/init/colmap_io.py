"""COLMAP models in and out (pycolmap): ``brfgs import colmap`` and the model ``brfgs init`` writes.

**Import** (:func:`import_colmap`): a COLMAP sparse model (binary or text, as COLMAP writes it), the
folder of hyperspectral cubes whose file stems are the COLMAP image names' stems (``view_00.png`` →
``images/view_00.hdr``, ``.tif``, ``.tiff`` or ``.npy``) and a small JSON sidecar become a
``transforms.json`` (docs/data-format.md) in the project folder. The sidecar holds what COLMAP does not
know: ``wavelengths_nm`` (else read by the scene reader's checks from the cubes), ``fwhm_nm``,
``sun_zenith_deg``/``sun_azimuth_deg``, optionally ``origin``/``crs``, ``dark_frames``/``dark_sigma``, ``diffuse_fraction``,
per-image ``frames`` ({image stem: {"time": ..., "sun_zenith_deg": ..., "sun_azimuth_deg": ...,
"irradiance_scale": ..., "diffuse_fraction": ..., "split": ...}}), and how COLMAP's arbitrary frame maps to the scene's ENU metres: ``enu_from_colmap`` (a 4 × 4
similarity) or ``camera_positions_enu`` ({image stem: [x, y, z]} for at least three images, aligned
by pycolmap's ``estimate_sim3d``); without either the COLMAP frame is taken as ENU metres.

The model is read by brfgs's own reader (:mod:`brfgs.init.colmap_read`: the three- and five-file
layouts, binary or text, in bounded time and memory); a cut or corrupted file, an impossible value
(focal length, image size, pose, quaternion) and a repeated, non-UTF-8 or over-long image name are
refused in one line naming the file and the camera or image (:mod:`brfgs.init.colmap_model`). Image
names must have unique stems: the stem names the cube.

Cameras: PINHOLE, SIMPLE_PINHOLE, OPENCV, SIMPLE_RADIAL, RADIAL and FULL_OPENCV (with k3..k6 = 0)
map to transforms.json's PINHOLE / OPENCV keys (COLMAP's pixel centres are at +0.5, as brfgs's); every other
model is refused in one line naming it. The first image's camera is the
top-level camera, frames of other cameras carry their own keys (resampled on reading, see
:mod:`brfgs.data.undistort`). Poses: COLMAP's cam_from_world (OpenCV axes) → OpenGL camera-to-world.

**Export** (:func:`write_colmap_model`): cameras and sparse points as a COLMAP model (one PINHOLE
camera, one trivial rig and frame per image) that pycolmap and COLMAP open.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

import numpy as np

from brfgs.init.pycolmap_safe import pycolmap

from brfgs.data import atomic
from brfgs.data.cameras import GL_TO_CV
from brfgs.data.validation import camera_position, finite_number, read_json_file
from brfgs.errors import UserError
from brfgs.init.colmap_model import MAX_COMPONENT_BYTES, Camera
from brfgs.init.colmap_read import read_model

__all__ = ["CUBE_SUFFIXES", "read_colmap_model", "import_colmap", "write_colmap_model"]

CUBE_SUFFIXES = (".hdr", ".tif", ".tiff", ".npy")
_SIDECAR_KEYS = ("wavelengths_nm", "fwhm_nm", "sun_zenith_deg", "sun_azimuth_deg", "origin", "crs", "dark_frames",
                 "dark_sigma", "diffuse_fraction")


def read_colmap_model(path: Path):
    """pycolmap.Reconstruction of a sparse model folder (binary or text, three- or five-file layout),
    checked first by brfgs's own reader (:func:`brfgs.init.colmap_read.read_model`), so that a damaged
    model is refused in one line instead of reaching pycolmap's reader."""
    read_model(path)
    try:
        return pycolmap.Reconstruction(str(path))
    except Exception as exc:  # pycolmap raises RuntimeError/ValueError with COLMAP's message
        raise UserError(f"COLMAP model could not be read ({exc})", file=path) from None


# COLMAP camera models brfgs reads: name -> (fx, fy, cx, cy, k1, k2, p1, p2) of its parameters p, in
# OpenCV's radial-tangential model (transforms.json's OPENCV); the pinhole ones have no distortion.
_PINHOLE_MODELS = {"SIMPLE_PINHOLE": lambda p: (p[0], p[0], p[1], p[2]),
                   "PINHOLE": lambda p: (p[0], p[1], p[2], p[3])}
_OPENCV_MODELS = {"SIMPLE_RADIAL": lambda p: (p[0], p[0], p[1], p[2], p[3], 0.0, 0.0, 0.0),
                  "RADIAL": lambda p: (p[0], p[0], p[1], p[2], p[3], p[4], 0.0, 0.0),
                  "OPENCV": lambda p: tuple(p[:8]),
                  "FULL_OPENCV": lambda p: tuple(p[:8])}  # only when its k3..k6 are 0 (checked)
SUPPORTED_CAMERA_MODELS = tuple(_PINHOLE_MODELS) + tuple(_OPENCV_MODELS)


def _camera_keys(cam: Camera, where: Path) -> dict:
    """transforms.json camera keys of a (checked) COLMAP camera; UserError naming the model and the camera
    for a model brfgs cannot represent exactly."""
    name, p = cam.model, list(cam.params)
    keys = {"w": cam.width, "h": cam.height}
    field = f"camera {cam.camera_id}"
    if name not in SUPPORTED_CAMERA_MODELS or (name == "FULL_OPENCV" and any(p[8:])):
        extra = " with k3..k6 not 0" if name == "FULL_OPENCV" else ""
        raise UserError(f"COLMAP camera model {name}{extra} is not supported ({', '.join(SUPPORTED_CAMERA_MODELS)} "
                        "are; FULL_OPENCV with k3..k6 = 0)", file=where, field=field)
    if name in _PINHOLE_MODELS:
        fx, fy, cx, cy = _PINHOLE_MODELS[name](p)
        return {"camera_model": "PINHOLE", "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, **keys}
    fx, fy, cx, cy, k1, k2, p1, p2 = _OPENCV_MODELS[name](p)
    return {"camera_model": "OPENCV", "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, **keys,
            "k1": k1, "k2": k2, "p1": p1, "p2": p2}


def _find_cube(images: Path, stem: str, where: Path) -> Path:
    for suffix in CUBE_SUFFIXES:
        if len(f"{stem}{suffix}".encode()) <= MAX_COMPONENT_BYTES and (images / f"{stem}{suffix}").is_file():
            return images / f"{stem}{suffix}"
    raise UserError(f"no cube {stem}{{{','.join(CUBE_SUFFIXES)}}} in {images} for COLMAP image {stem!r}", file=where)


def _number_array(value, shape: tuple[int, ...]) -> np.ndarray | None:
    """``value`` (nested JSON lists of numbers, not strings) as a finite float64 array of ``shape``; None
    if it is not one."""
    stack = [value]
    while stack:                                          # numpy would read the string "1" (or "١") as 1.0
        v = stack.pop()
        if isinstance(v, list):
            stack.extend(v)
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            return None
    try:
        a = np.asarray(value, dtype=float)
    except (ValueError, TypeError, OverflowError):
        return None
    return a if a.shape == shape and np.isfinite(a).all() else None


def _non_finite_field(value, where: str = "") -> str | None:
    """The field path (``frames.v0.irradiance_scale``, ``wavelengths_nm[2]``) of the first NaN, ±Infinity
    or integer beyond the float range in a parsed JSON value, or None."""
    stack = [(value, where)]
    while stack:
        v, at = stack.pop()
        if isinstance(v, dict):
            stack.extend((x, f"{at}.{k}" if at else str(k)) for k, x in reversed(list(v.items())))
        elif isinstance(v, list):
            stack.extend((x, f"{at}[{i}]") for i, x in reversed(list(enumerate(v))))
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and finite_number(v) is None:
            return at
    return None


def _check_stems(named, stems: list[str], images: Path, where: Path, field: str) -> list[str]:
    """The keys of ``named`` (a sidecar object keyed by image stem) that are no image of the COLMAP model
    but a cube in ``images`` (images COLMAP did not register: left out); UserError naming the first key
    that is neither (a typo would otherwise be ignored without a word)."""
    left_out = []
    for stem in named:
        if stem in stems:
            continue
        if not isinstance(stem, str) or "/" in stem or stem in ("", ".", "..") or \
                not any(_cube_exists(images, stem, sfx) for sfx in CUBE_SUFFIXES):
            known = ", ".join(stems[:6]) + (", ..." if len(stems) > 6 else "")
            raise UserError(f"no image of the COLMAP model and no cube in {images} has the stem {str(stem)[:80]!r} "
                            f"(the model's images: {known})", file=where, field=f"{field}.{str(stem)[:80]}")
        left_out.append(stem)
    return left_out


def _cube_exists(images: Path, stem: str, suffix: str) -> bool:
    name = f"{stem}{suffix}"
    return len(name.encode("utf-8", "replace")) <= MAX_COMPONENT_BYTES and (images / name).is_file()


def _check_gauge(regs, how: str, model_file: Path) -> None:
    """UserError for a model that is not in ENU metres: without an alignment, an image with the identity
    pose (COLMAP's own gauge: the model is in the frame of that image, not georeferenced)."""
    if not how.startswith("none"):
        return
    for im in regs:
        if np.allclose(np.asarray(im.cam_from_world, float), np.eye(4)[:3], atol=1e-9):
            raise UserError(f"the model is not georeferenced/aligned: its image {im.name!r} has the identity pose "
                            "(COLMAP's own frame, not ENU metres); give camera_positions_enu ({image stem: [east, "
                            "north, up] metres}, e.g. the flight's GNSS positions) or enu_from_colmap in spectral.json "
                            "(--sidecar), or align the model first (colmap model_aligner)", file=model_file,
                            field=f"image {im.name}")


def _similarity(sidecar: dict, stems: list[str], c2w: list[np.ndarray], where: Path, images: Path
                ) -> tuple[float, np.ndarray, np.ndarray, str]:
    """(scale, R [3, 3], t [3], how) of ENU = s R x + t (``images``: the cube folder, see _check_stems)."""
    if sidecar.get("enu_from_colmap") is not None:
        m = _number_array(sidecar["enu_from_colmap"], (4, 4))
        if m is None:
            raise UserError("expected a 4 x 4 similarity matrix", file=where, field="enu_from_colmap")
        s = float(np.cbrt(np.linalg.det(m[:3, :3])))
        r = m[:3, :3] / s
        if s <= 0 or not np.allclose(r @ r.T, np.eye(3), atol=1e-6):
            raise UserError("not a similarity (scale × rotation + translation)", file=where, field="enu_from_colmap")
        return s, r, m[:3, 3], "enu_from_colmap"
    pos = sidecar.get("camera_positions_enu")
    if pos is None:
        return 1.0, np.eye(3), np.zeros(3), "none (COLMAP frame taken as ENU metres)"
    if not isinstance(pos, dict):
        raise UserError("expected an object {image stem: [east, north, up] metres}", file=where,
                        field="camera_positions_enu")
    pairs = []
    for k, v in pos.items():
        xyz = _number_array(v, (3,))
        if xyz is None:
            raise UserError(f"expected [east, north, up] as three finite numbers (metres), got {str(v)[:60]}",
                            file=where, field=f"camera_positions_enu.{k}")
        if k in stems:
            pairs.append((c2w[stems.index(k)][:3, 3], xyz))
    _check_stems(pos, stems, images, where, "camera_positions_enu")
    if len(pairs) < 3:
        raise UserError(f"{len(pairs)} of the named images are in the COLMAP model; a similarity needs 3",
                        file=where, field="camera_positions_enu")
    src, dst = (np.stack(a) for a in zip(*pairs))
    sim = pycolmap.estimate_sim3d(src, dst)
    if sim is None:
        raise UserError("the camera positions do not determine a similarity (collinear?)", file=where,
                        field="camera_positions_enu")
    m = sim.matrix()                                                       # [3, 4] = [s R | t]
    return float(sim.scale), m[:3, :3] / float(sim.scale), m[:3, 3], \
        f"pycolmap.estimate_sim3d on {len(pairs)} camera positions"


_FRAME_KEYS = ("time", "sun_zenith_deg", "sun_azimuth_deg", "irradiance_scale", "diffuse_fraction", "split")


def _frame_extras(sidecar: dict, stem: str, where: Path) -> dict:
    """The sidecar's per-image fields of ``stem`` (checked later by the scene reader)."""
    per = sidecar.get("frames", {})
    if not isinstance(per, dict):
        raise UserError("expected an object {image stem: {time, sun_zenith_deg, ...}}", file=where, field="frames")
    extra = per.get(stem, {})
    if not isinstance(extra, dict) or set(extra) - set(_FRAME_KEYS):
        raise UserError(f"expected an object with keys among {', '.join(_FRAME_KEYS)}", file=where,
                        field=f"frames.{stem}")
    return dict(extra)


def import_colmap(project: Path, sparse: Path, images: Path, sidecar_path: Path | None, overwrite: bool = False
                  ) -> tuple[Path, dict]:
    """Write ``project/transforms.json`` from a COLMAP model, a cube folder and a sidecar (module
    docstring). Returns (its path, a summary). Refuses to replace an existing transforms.json unless
    ``overwrite``; the cubes must lie inside ``project``."""
    project = Path(project)
    tf = project / "transforms.json"
    if tf.exists() and not overwrite:
        raise UserError("already exists; pass --overwrite to replace it", file=tf)
    images = Path(images)
    if not images.resolve().is_relative_to(project.resolve()):
        raise UserError(f"the cube folder must lie inside the project folder {project}", file=images)
    sidecar = {}
    if sidecar_path is not None:
        sidecar = read_json_file(Path(sidecar_path), "JSON sidecar")
        if not isinstance(sidecar, dict):
            raise UserError("expected a JSON object", file=sidecar_path)
        bad = _non_finite_field(sidecar)
        if bad is not None:           # json reads NaN, Infinity and 1e400; transforms.json would hold null
            raise UserError("expected a finite number (NaN, Infinity and numbers beyond the float range are not "
                            "values)", file=sidecar_path, field=bad)
    model = read_model(sparse)
    regs = model.images
    if not regs:
        raise UserError("the COLMAP model has no registered image", file=sparse)
    stems = [PurePosixPath(im.name).stem for im in regs]
    c2w = []
    for im in regs:
        w2c = np.eye(4)
        w2c[:3, :] = im.cam_from_world
        with np.errstate(over="ignore", invalid="ignore"):                 # refused just below
            c2w.append(np.linalg.inv(w2c) @ GL_TO_CV)
        if not np.isfinite(c2w[-1]).all():
            raise UserError("the camera position is out of range", file=model.files["images"], field=f"image {im.name}")
    where = Path(sidecar_path) if sidecar_path else sparse
    s, r, t, how = _similarity(sidecar, stems, c2w, where, images)
    _check_gauge(regs, how, model.files["images"])
    per = sidecar.get("frames", {})
    if not isinstance(per, dict):
        raise UserError("expected an object {image stem: {time, sun_zenith_deg, ...}}", file=where, field="frames")
    unregistered = _check_stems(per, stems, images, where, "frames")
    top = _camera_keys(model.cameras[regs[0].camera_id], model.files["cameras"])
    frames = []
    for im, stem, m in zip(regs, stems, c2w):
        cube = _find_cube(images, stem, sparse)
        enu = np.eye(4)
        enu[:3, :3] = r @ m[:3, :3]
        with np.errstate(over="ignore", invalid="ignore"):                 # refused just below
            enu[:3, 3] = s * r @ m[:3, 3] + t
        if not np.isfinite(enu).all():
            raise UserError("the camera position is out of range after the alignment to ENU", file=model.files["images"],
                            field=f"image {im.name}")
        _check_enu_camera(enu, how, model.files["images"], im.name)
        fr = {"file_path": cube.resolve().relative_to(project.resolve()).as_posix(), "transform_matrix": enu.tolist(),
              "colmap_image_id": int(im.image_id)}
        own = _camera_keys(model.cameras[im.camera_id], model.files["cameras"])
        fr.update({k: v for k, v in own.items() if top.get(k) != v})
        fr.update(_frame_extras(sidecar, stem, where))
        frames.append(fr)
    meta = {**top, **{k: sidecar[k] for k in _SIDECAR_KEYS if k in sidecar}, "frames": frames,
            "colmap": {"model": str(Path(sparse).resolve()), "enu_from_colmap": how, "scale": s}}
    atomic.write_json(tf, meta)
    return tf, {"frames": len(frames), "cameras": len({im.camera_id for im in regs}), "alignment": how,
                "unregistered": unregistered}


def _check_enu_camera(enu: np.ndarray, how: str, model_file: Path, name: str) -> None:
    """UserError naming the image when its camera, in ENU metres, is at the scene origin or beyond
    MAX_CAMERA_DISTANCE_M (brfgs.data.validation.camera_position), or, after an alignment, at or below
    the ground (z <= 0): every command would refuse the scene."""
    hint = "; check camera_positions_enu / enu_from_colmap in the sidecar" if not how.startswith("none") else \
        "; give camera_positions_enu or enu_from_colmap in spectral.json (--sidecar) to align the model to ENU metres"
    try:
        camera_position(enu, model_file, f"image {name}")
    except UserError as exc:
        raise UserError(f"after the alignment to ENU ({how}): {exc.detail}{hint}", file=model_file,
                        field=f"image {name}") from None
    if not how.startswith("none") and not enu[2, 3] > 0:
        raise UserError(f"after the alignment to ENU ({how}) the camera is at or below the ground (z = "
                        f"{enu[2, 3]:.4g} m){hint}", file=model_file, field=f"image {name}")


def write_colmap_model(out: Path, intr, names: list[str], c2w_gl: np.ndarray, registered: np.ndarray,
                       points: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """``out`` (binary COLMAP model: cameras, rigs, frames, images, points3D) of ENU-metre cameras
    ``c2w_gl`` [F, 4, 4] (registered ones only) and ``points`` [P, 3]; ``colors`` [P, 3] in [0, 1]."""
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", float(intr.fl_x), int(intr.w), int(intr.h))
    cam.params = np.array([intr.fl_x, intr.fl_y, intr.cx, intr.cy], float)
    rec.add_camera_with_trivial_rig(cam)
    for k, name in enumerate(names):
        if not registered[k]:
            continue
        w2c = np.linalg.inv(np.asarray(c2w_gl[k], float) @ GL_TO_CV)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=k + 1), pose)
    rgb = np.zeros((len(points), 3), np.uint8) if colors is None else np.clip(np.asarray(colors) * 255, 0, 255)
    for p, c in zip(np.asarray(points, float), np.asarray(rgb, np.uint8)):
        rec.add_point3D(p, pycolmap.Track(), c)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rec.write(str(out))
    return out
