"""Scene reader for the data-set layout of docs/data-format.md.

A scene folder holds ``transforms.json`` (cameras, wavelengths, sun angles, frames),
``images/`` with one reflectance cube per frame (ENVI, ``.npy`` [H, W, B] or multi-band
GeoTIFF) and optionally ``calibration/dark_*`` dark frames and ``truth/``.

:func:`read_scene` parses and validates the metadata and every cube header at once
(cheap), and returns a :class:`Scene` whose :meth:`Scene.load_image` reads one cube
on demand: band subset, region of interest and integer area-average downscaling are
applied while reading row blocks from a memory map, so a full-resolution cube is never
held in memory. Pixel values are checked as they are read (``value_range``), NaN/Inf
are kept as NaN and excluded by :meth:`Scene.valid_mask`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from brfgs.data import validation as V
from brfgs.data.angles import angles_from_direction, direction_from_angles_deg
from brfgs.data.cameras import Intrinsics, camera_centre, pose_from_view_angles, viewmat_from_c2w
from brfgs.data.cube_io import CubeSource, open_cube, read_block_averaged
from brfgs.data.validation import RangeTally
from brfgs.data.georef import Origin, read_georef
from brfgs.data.sky import clear_sky_diffuse_fraction, read_diffuse_fraction, read_frame_diffuse_fraction
from brfgs.data.sun import frame_suns
from brfgs.data.undistort import DIST_KEYS, FrameCamera, read_frame_camera, resample_cube
from brfgs.data.splits import DEFAULT_SPLIT_RULE, SPLIT_RULES, assign_split, nearest_view_angle_deg, ring_name, view_rings
from brfgs.errors import UserError

TRANSFORMS = "transforms.json"
DEFAULT_VALUE_RANGE = (-0.5, 10.0)


@dataclass
class Frame:
    """One image of the acquisition."""

    name: str
    path: Path                      # cube file (header for ENVI)
    c2w: np.ndarray                 # [4, 4] OpenGL camera-to-world
    view_zenith_deg: float
    view_azimuth_deg: float
    split: str                      # "train" | "validation" | "test"
    split_given: bool = False       # True if transforms.json fixed it
    camera: FrameCamera | None = None   # its own (distorted or other) camera, resampled on reading
    sun_zenith_deg: float = float("nan")    # the sun of this frame (brfgs.data.sun)
    sun_azimuth_deg: float = float("nan")
    time_utc: str | None = None
    irradiance_scale: float = 1.0           # downwelling irradiance / nominal (sensor or panel): images are divided
    diffuse_fraction: np.ndarray | None = None  # [B] its own sky share of the irradiance (else the scene's)


@dataclass
class Scene:
    """A validated scene; cubes are read lazily. See the module docstring."""

    root: Path
    name: str
    wavelengths_nm: np.ndarray              # [B] after band subset
    fwhm_nm: np.ndarray | None              # [B] or None
    band_indices: np.ndarray                # [B] indices into the file's bands
    intrinsics: Intrinsics                  # after ROI and downscale
    sun_zenith_deg: float
    sun_azimuth_deg: float
    frames: list[Frame]
    dark_sigma: np.ndarray                  # [B] σ_b (reflectance units)
    dark_sigma_source: str                  # "dark_frames" | "transforms.json" | "estimated"
    downscale: int = 1
    roi: tuple[int, int, int, int] | None = None   # (x0, y0, w, h) in full-resolution pixels
    value_range: tuple[float, float] = DEFAULT_VALUE_RANGE
    split_seed: int = 0
    split_rule: str = DEFAULT_SPLIT_RULE
    validation: bool = False                # 1 in 6 training views held out as the validation split
    full_intrinsics: Intrinsics | None = None
    _sources: list[CubeSource] = field(default_factory=list, repr=False)
    _file_wavelengths: np.ndarray | None = field(default=None, repr=False)  # [B_file] before the subset
    allow_outside_links: bool = False       # files that links lead to outside the scene folder may be read
    invalid_counts: dict[str, int] = field(default_factory=dict)   # NaN/Inf pixels per frame (as loaded)
    bright_counts: dict[str, int] = field(default_factory=dict)    # pixels above value_range per frame (kept)
    origin: Origin | None = None            # the ENU frame on the Earth (brfgs.data.georef), if given
    crs: str | None = None                  # map CRS of products (default: the origin's UTM zone)
    diffuse_fraction: np.ndarray | None = None   # [B] sky share of the irradiance (brfgs.data.sky; default: at the sun)
    diffuse_fraction_source: str = "clear-sky default"

    # ----- geometry -------------------------------------------------------------------------------
    @property
    def width(self) -> int:
        return self.intrinsics.w

    @property
    def height(self) -> int:
        return self.intrinsics.h

    @property
    def n_bands(self) -> int:
        return len(self.wavelengths_nm)

    def K(self) -> np.ndarray:
        """Intrinsic matrix [3, 3] of the loaded images."""
        return self.intrinsics.K()

    def viewmat(self, i: int) -> np.ndarray:
        """World-to-camera [4, 4] with OpenCV axes (what brfgs.render.rasterize takes)."""
        return viewmat_from_c2w(self.frames[i].c2w)

    def camera_centre(self, i: int) -> np.ndarray:
        """Camera centre [3] of frame i (metres, ENU)."""
        return camera_centre(self.frames[i].c2w)

    def sun_direction(self) -> np.ndarray:
        """Unit vector [3] toward the sun (ENU)."""
        return direction_from_angles_deg(self.sun_zenith_deg, self.sun_azimuth_deg)

    def band_index_nearest(self, wavelength_nm: float) -> int:
        """Index (into the loaded bands) of the band nearest ``wavelength_nm``."""
        return int(np.argmin(np.abs(self.wavelengths_nm - wavelength_nm)))

    @property
    def train_indices(self) -> list[int]:
        return [i for i, f in enumerate(self.frames) if f.split == "train"]

    @property
    def test_indices(self) -> list[int]:
        return [i for i, f in enumerate(self.frames) if f.split == "test"]

    @property
    def validation_indices(self) -> list[int]:
        return [i for i, f in enumerate(self.frames) if f.split == "validation"]

    def indices_of(self, split: str) -> list[int]:
        """Frame indices of ``split`` ("train", "validation" or "test")."""
        return [i for i, f in enumerate(self.frames) if f.split == split]

    def sky_at(self, sun_zenith_deg: float) -> np.ndarray:  # [B]
        """The scene's diffuse fraction (its field), else the clear-sky default for that sun (brfgs.data.sky)."""
        given = self.diffuse_fraction_source != "clear-sky default"
        return self.diffuse_fraction if given else clear_sky_diffuse_fraction(
            self.wavelengths_nm, sun_zenith_deg, self.origin.altitude_m if self.origin else 0.0)

    def frame_diffuse_fraction(self, i: int) -> np.ndarray:  # [B]
        """The sky share of the irradiance frame ``i`` was taken under: its own, else :meth:`sky_at` its sun."""
        own = self.frames[i].diffuse_fraction
        return self.sky_at(self.frames[i].sun_zenith_deg) if own is None else own

    def rings(self) -> dict[str, str]:
        """{frame name: view ring} (ring = view zenith class, e.g. "0", "18", "58"; brfgs.data.splits)."""
        labels = view_rings([f.view_zenith_deg for f in self.frames])
        return {f.name: ring_name(r) for f, r in zip(self.frames, labels)}

    def split_record(self) -> dict:
        """The split as recorded in run folders (split.json) and metrics files."""
        how = ("spread over the view directions (farthest-point)" if self.split_rule == "spread"
               else "chosen at random within each ring")
        rec = {"seed": self.split_seed, "split_rule": self.split_rule,
               "rule": f"6:1 train:test stratified by view ring (test views from every ring in proportion, {how}), "
                       "per-frame 'split' honoured" + ("; validation: 1 in 6 training views, the same way, "
                                                       "seed + 1" if self.validation else ""),
               "train": [self.frames[i].name for i in self.train_indices],
               "test": [self.frames[i].name for i in self.test_indices]}
        if self.validation:
            rec["validation"] = [self.frames[i].name for i in self.validation_indices]
        rec["nearest_train_view_deg"] = self.nearest_train_view_deg()
        rings = self.rings()
        rec["rings"] = {r: {s: [n for n in rec.get(s, []) if rings[n] == r] for s in ("train", "validation", "test")
                            if s in rec} for r in sorted(set(rings.values()), key=float)}
        return rec

    def nearest_train_view_deg(self) -> dict[str, float]:
        """{held-out frame name: angle (deg, 0.1) from its view direction to the nearest training view's}
        for the test and validation views (brfgs.data.splits.nearest_view_angle_deg)."""
        d = np.stack([direction_from_angles_deg(f.view_zenith_deg, f.view_azimuth_deg) for f in self.frames])
        held = self.test_indices + self.validation_indices
        ang = nearest_view_angle_deg(d[held], d[self.train_indices])
        return {self.frames[i].name: round(float(a), 1) for i, a in zip(held, ang)}

    @property
    def truth_dir(self) -> Path | None:
        """``<scene>/truth`` for simulated scenes (never read for training), else None."""
        p = self.root / "truth"
        return p if p.is_dir() else None

    def frame_index(self, name: str) -> int:
        names = [f.name for f in self.frames]
        if name in names:
            return names.index(name)
        raise UserError(f"no frame named {name!r}; frames are {[f.name for f in self.frames][:8]}...",
                        file=self.root / TRANSFORMS, field="frames")

    # ----- pixels ---------------------------------------------------------------------------------
    def load_image(self, i: int, bands: list[int] | np.ndarray | None = None) -> np.ndarray:
        """Reflectance cube of frame ``i`` as float32 [H, W, b].

        ``bands`` indexes the scene's (already subset) bands; default all. Downscale and
        ROI are applied while reading; a downscaled pixel containing a NaN/Inf input pixel is
        NaN. Values below ``value_range`` are masked (NaN) and values above it kept and counted
        (``bright_counts``: specular glints), as long as they are at most 5 % (above) and 1 %
        (below) of the frame's pixels; more raises UserError (brfgs.data.validation.RangeTally).
        """
        src = self._sources[i]
        file_bands = self.band_indices if bands is None else self.band_indices[np.asarray(bands, dtype=int)]
        tally = RangeTally(self.value_range)
        cube = self._read(i, src, file_bands, tally)
        if self.frames[i].irradiance_scale != 1.0:   # reflectance under the nominal irradiance
            cube /= np.float32(self.frames[i].irradiance_scale)
        n_bad = int((~np.isfinite(cube)).any(-1).sum())
        if bands is None:
            self.invalid_counts[self.frames[i].name] = n_bad
            self.bright_counts[self.frames[i].name] = tally.n_high
        if n_bad:
            cube[~np.isfinite(cube)] = np.nan
        return cube

    def load_truth(self, i: int) -> np.ndarray | None:
        """Clean truth cube [H, W, B] of frame ``i`` from ``truth/images`` (simulated scenes), or None.

        Band subset, ROI and downscale are applied as for :meth:`load_image`. For evaluation
        only: truth is never read for training.
        """
        if self.truth_dir is None:
            return None
        hdr = self.truth_dir / "images" / f"{self.frames[i].name}.hdr"
        if not hdr.is_file():
            return None
        full_wl = self._file_wavelengths
        src = open_cube(hdr, full_wl, self.root / TRANSFORMS, f"truth of {self.frames[i].name}",
                        self.allow_outside_links)
        if (src.lines, src.samples) != (self._sources[i].lines, self._sources[i].samples):
            raise UserError(f"truth cube is {src.samples}x{src.lines}, the image "
                            f"{self._sources[i].samples}x{self._sources[i].lines}", file=hdr)
        return self._read(i, src, self.band_indices, RangeTally((-np.inf, np.inf)))

    def _read(self, i: int, src: CubeSource, file_bands: np.ndarray, tally: RangeTally) -> np.ndarray:
        """Bands of frame ``i``'s cube on the scene's pinhole camera, ROI and downscale applied; a frame
        with its own camera is read whole and resampled first (brfgs.data.undistort)."""
        cam = self.frames[i].camera
        if cam is None or (src.lines, src.samples) != (cam.intrinsics.h, cam.intrinsics.w):
            return read_block_averaged(src, file_bands, self.roi, self.downscale, tally, self.frames[i].name)
        full = read_block_averaged(src, file_bands, None, 1, tally, self.frames[i].name)
        full = resample_cube(full, cam, self.full_intrinsics)
        x0, y0, rw, rh = self.roi if self.roi is not None else (0, 0, full.shape[1], full.shape[0])
        f = self.downscale
        crop = full[y0:y0 + rh // f * f, x0:x0 + rw // f * f]
        return crop.reshape(rh // f, f, rw // f, f, -1).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)

    def valid_mask(self, i: int, image: np.ndarray | None = None) -> np.ndarray:
        """Bool [H, W]: pixels whose every band is finite (pass ``image`` to avoid re-reading)."""
        img = self.load_image(i) if image is None else image
        return np.isfinite(img).all(-1)


# ---------------------------------------------------------------------------------------------------
def read_scene(path: str | Path, *, downscale: int = 1, bands: list[int] | np.ndarray | None = None,
               roi: tuple[int, int, int, int] | None = None,
               value_range: tuple[float, float] = DEFAULT_VALUE_RANGE, split_seed: int = 0,
               split_rule: str = DEFAULT_SPLIT_RULE, allow_outside_links: bool = False, validation: bool = False) -> Scene:
    """Read and validate the scene folder ``path`` (see docs/data-format.md, "Data set layout").

    Args:
        downscale: integer area-average factor applied while reading.
        bands: indices of the bands to keep (default all).
        roi: (x0, y0, w, h) region of interest in full-resolution pixels.
        value_range: plausible reflectance range; finite values outside it are an error.
        split_seed: seed of the deterministic 6:1 train/test split (stratified by view ring).
        split_rule: which views of a ring are held out: "spread" or "random" (brfgs.data.splits).
        validation: also hold out 1 in 6 training views as the "validation" split.
        allow_outside_links: read files that links (the cubes, dark frames, calibration/, truth/,
            transforms.json) lead to outside the scene folder; refused by default.
    """
    root = Path(path)
    tf, meta = _load_transforms(root, allow_outside_links)
    if not isinstance(downscale, int) or downscale < 1:
        raise UserError(f"downscale must be an integer >= 1, got {downscale!r}", field="downscale")
    lo, hi = value_range
    if not lo < hi:
        raise UserError(f"value range must have min < max, got {value_range}", field="value_range")
    full_intr, cam_keys = _read_intrinsics(meta, tf)
    wl_all = V.wavelengths(_required(meta, "wavelengths_nm", tf), tf, "wavelengths_nm")
    fwhm_all = None
    if meta.get("fwhm_nm") is not None:
        fwhm_all = V.number_list(meta["fwhm_nm"], tf, "fwhm_nm", length=len(wl_all))
    origin, crs = read_georef(meta, tf)
    band_idx = _band_subset(bands, len(wl_all))
    intr, roi = _crop_and_scale(full_intr, roi, downscale)
    frames, sources = _read_frames(root, tf, _required(meta, "frames", tf), wl_all, (full_intr, cam_keys),
                                   allow_outside_links)
    zen, azi, sun_zen, sun_az, times = frame_suns(meta, origin, tf)
    for k, (f, z, a, t) in enumerate(zip(frames, zen, azi, times)):
        f.sun_zenith_deg, f.sun_azimuth_deg, f.time_utc = float(z), float(a), None if t is None else t.isoformat()
        if meta["frames"][k].get("irradiance_scale") is not None:
            f.irradiance_scale = V.number(meta["frames"][k]["irradiance_scale"], tf, f"frames[{k}].irradiance_scale",
                                          lo=1e-3, hi=1e3)
        f.diffuse_fraction = read_frame_diffuse_fraction(meta["frames"][k], k, tf, len(wl_all), band_idx)
    if split_rule not in SPLIT_RULES:
        raise UserError(f"split rule must be one of {SPLIT_RULES}, got {split_rule!r}", field="split_rule")
    assign_split(frames, split_seed, split_rule, validation)
    if not any(f.split == "train" for f in frames):
        raise UserError("every frame is marked 'test'; at least one training frame is needed", file=tf,
                        field="frames[].split")

    sigma_all, source = _dark_sigma(root, meta, tf, wl_all, sources, (value_range, allow_outside_links))
    diffuse_all, diffuse_source = read_diffuse_fraction(meta, tf, wl_all, sun_zen, origin.altitude_m if origin else 0)
    return Scene(root=root, name=root.resolve().name, wavelengths_nm=wl_all[band_idx],
                 fwhm_nm=None if fwhm_all is None else fwhm_all[band_idx], band_indices=band_idx,
                 intrinsics=intr, sun_zenith_deg=sun_zen, sun_azimuth_deg=sun_az, frames=frames,
                 dark_sigma=sigma_all[band_idx], dark_sigma_source=source, downscale=downscale, roi=roi,
                 value_range=(float(lo), float(hi)), split_seed=split_seed, split_rule=split_rule,
                 validation=validation, full_intrinsics=full_intr, origin=origin, crs=crs,
                 diffuse_fraction=diffuse_all[band_idx], diffuse_fraction_source=diffuse_source,
                 _sources=sources, _file_wavelengths=wl_all, allow_outside_links=allow_outside_links)


def _load_transforms(root: Path, allow_outside_links: bool = False) -> tuple[Path, dict]:
    """(path, parsed object) of the scene's transforms.json (size, nesting depth and links checked)."""
    tf = root / TRANSFORMS
    if not root.is_dir():
        raise UserError("scene folder not found", file=root)
    if not tf.is_file():
        raise UserError(f"no {TRANSFORMS} in the scene folder", file=root)
    V.confined(tf, root, tf, None, allow_outside_links)
    if tf.stat().st_size > V.MAX_JSON_BYTES:
        raise UserError(f"{tf.stat().st_size} bytes, more than the {V.MAX_JSON_BYTES} bytes a scene description "
                        "may have", file=tf)
    try:
        meta = json.loads(tf.read_text())
    except RecursionError:
        raise UserError(f"nested deeper than {V.MAX_JSON_DEPTH} levels", file=tf) from None
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError, or an integer of > 4300 digits
        raise UserError(f"not valid JSON ({str(exc)[:200]})", file=tf) from None
    if not isinstance(meta, dict):
        raise UserError("expected a JSON object at the top level", file=tf)
    if V.json_depth(meta) > V.MAX_JSON_DEPTH:
        raise UserError(f"nested deeper than {V.MAX_JSON_DEPTH} levels", file=tf)
    return tf, meta


def _required(meta: dict, key: str, tf: Path):
    """``meta[key]``; UserError naming the field when it is missing."""
    if key not in meta:
        raise UserError("required field missing", file=tf, field=key)
    return meta[key]


def _read_intrinsics(meta: dict, tf: Path) -> tuple[Intrinsics, dict]:
    """(full-resolution pinhole intrinsics every frame is resampled to, the top-level camera keys
    that frames inherit): the top level's, or the first frame's when the top level has none."""
    base = {k: meta[k] for k in ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", *DIST_KEYS) if k in meta}
    cam = read_frame_camera(meta, tf, "")
    frames = meta.get("frames")
    if cam is None and isinstance(frames, list) and frames and isinstance(frames[0], dict):
        cam = read_frame_camera(frames[0], tf, "frames[0].", base)
    if cam is None:
        missing = [k for k in ("fl_x", "fl_y", "cx", "cy", "w", "h") if meta.get(k) is None]
        raise UserError("required field missing (at the top level or in every frame)", file=tf, field=missing[0])
    return cam.intrinsics, base


def _band_subset(bands, n_bands_file: int) -> np.ndarray:
    """Indices [B] of the bands to keep (all when ``bands`` is None), checked."""
    if bands is None:
        return np.arange(n_bands_file)
    band_idx = np.asarray(bands, dtype=int).reshape(-1)
    if band_idx.size == 0 or band_idx.min() < 0 or band_idx.max() >= n_bands_file:
        raise UserError(f"band indices must lie in 0..{n_bands_file - 1}", field="bands")
    if np.any(np.diff(band_idx) <= 0):
        raise UserError("band indices must be strictly increasing", field="bands")
    return band_idx


def _crop_and_scale(full_intr: Intrinsics, roi, downscale: int) -> tuple[Intrinsics, tuple | None]:
    """Intrinsics of the loaded images (ROI, then downscale) and the checked ROI (x0, y0, w, h) or None."""
    w, h = full_intr.w, full_intr.h
    if roi is not None:
        x0, y0, rw, rh = (int(v) for v in roi)
        if x0 < 0 or y0 < 0 or rw < 1 or rh < 1 or x0 + rw > w or y0 + rh > h:
            raise UserError(f"region of interest {roi} does not fit the {w}x{h} image", field="roi")
        intr = full_intr.cropped(x0, y0, rw, rh)
        roi = (x0, y0, rw, rh)
    else:
        intr = full_intr
    if intr.w // downscale < 1 or intr.h // downscale < 1:
        raise UserError(f"downscale {downscale} leaves no pixels of a {intr.w}x{intr.h} image", field="downscale")
    return intr.scaled(downscale), roi


def _read_frames(root: Path, tf: Path, frames_meta, wl_all: np.ndarray, cameras: tuple[Intrinsics, dict],
                 allow_outside_links: bool = False) -> tuple[list[Frame], list[CubeSource]]:
    """Frames of transforms.json (poses, nominal angles, requested split) and how to read their cubes."""
    if not isinstance(frames_meta, list):
        raise UserError("expected a list of frames", file=tf, field="frames")
    if len(frames_meta) < V.MIN_FRAMES:
        raise UserError(f"found {len(frames_meta)} frames, at least {V.MIN_FRAMES} are needed for a "
                        f"multi-angle reconstruction", file=tf, field="frames")
    frames: list[Frame] = []
    sources: list[CubeSource] = []
    names: set[str] = set()
    for k, fm in enumerate(frames_meta):
        frame, src = _read_frame(root, tf, k, fm, names, wl_all, (*cameras, allow_outside_links))
        frames.append(frame)
        sources.append(src)
    return frames, sources


def _read_frame(root: Path, tf: Path, k: int, fm, names: set[str], wl_all: np.ndarray,
                camera: tuple[Intrinsics, dict, bool]) -> tuple[Frame, CubeSource]:
    """Frame ``k`` of transforms.json and its cube source; adds its name to ``names``.
    ``camera``: (full-resolution pinhole intrinsics, top-level camera keys, allow_outside_links)."""
    full_intr, cam_keys, allow_outside_links = camera
    fld = f"frames[{k}]"
    if not isinstance(fm, dict):
        raise UserError("expected an object", file=tf, field=fld)
    if "file_path" not in fm:
        raise UserError("required field missing", file=tf, field=f"{fld}.file_path")
    cube_path = V.path_inside(root, fm["file_path"], tf, f"{fld}.file_path", allow_outside_links)
    name = Path(fm["file_path"]).stem
    if name in names:
        raise UserError(f"duplicate frame name {name!r}", file=tf, field=f"{fld}.file_path")
    names.add(name)
    fld = f"frames[{k}] ('{name}')"
    vz = va = None
    if fm.get("view_zenith_deg") is not None:
        vz = V.number(fm["view_zenith_deg"], tf, f"{fld}.view_zenith_deg", lo=0.0, hi=89.999)
    if fm.get("view_azimuth_deg") is not None:
        va = V.number(fm["view_azimuth_deg"], tf, f"{fld}.view_azimuth_deg", lo=-360.0, hi=360.0)
    if fm.get("transform_matrix") is not None:
        c2w = V.transform_matrix(fm["transform_matrix"], tf, f"{fld}.transform_matrix")
    else:
        if vz is None or va is None or fm.get("distance_m") is None:
            raise UserError("needs either transform_matrix or view_zenith_deg, view_azimuth_deg and "
                            "distance_m", file=tf, field=fld)
        c2w = pose_from_view_angles(vz, va, V.camera_distance(fm["distance_m"], tf, f"{fld}.distance_m"))
    V.camera_position(c2w, tf, f"{fld}.transform_matrix", above_ground=vz is None or va is None)
    if vz is None or va is None:  # derive nominal angles from the camera centre
        zr, ar = angles_from_direction(c2w[:3, 3])
        vz, va = float(np.degrees(zr)), float(np.degrees(ar))
    split = fm.get("split")
    if split is not None and split not in ("train", "test"):
        raise UserError(f"split must be 'train' or 'test', found {split!r}", file=tf, field=f"{fld}.split")
    src = open_cube(cube_path, wl_all, tf, name, allow_outside_links)
    own = read_frame_camera(fm, tf, f"{fld}.", cam_keys)
    w, h = own.intrinsics.w, own.intrinsics.h
    if (src.lines, src.samples) != (h, w):
        raise UserError(f"cube is {src.samples}x{src.lines} pixels but {TRANSFORMS} gives w={w}, h={h}; "
                        f"the intrinsics do not fit this image", file=cube_path, field="samples/lines")
    own = None if own.is_pinhole_like(full_intr) else own
    return Frame(name, cube_path, c2w, vz, va, split or "", split is not None, own), src


def _dark_sigma(root: Path, meta: dict, tf: Path, wl: np.ndarray, sources: list[CubeSource],
                reading: tuple) -> tuple[np.ndarray, str]:
    """σ_b [B]: std over dark frames and pixels; else ``dark_sigma``; else estimated from the images.
    ``reading``: (plausible value range, allow_outside_links); dark-frame values must lie in the range."""
    value_range, allow = reading
    n_bands = len(wl)
    listed = meta.get("dark_frames")
    if listed is not None:
        if not isinstance(listed, list):
            raise UserError("expected a list of paths", file=tf, field="dark_frames")
        paths = [V.path_inside(root, p, tf, f"dark_frames[{i}]", allow) for i, p in enumerate(listed)]
    else:
        paths = sorted((root / "calibration").glob("dark_*.hdr")) if (root / "calibration").is_dir() else []
    if paths:
        s1 = np.zeros(n_bands)
        s2 = np.zeros(n_bands)
        n = 0
        for p in paths:
            src = open_cube(p, wl, tf, f"dark frame {p.name}", allow)
            cube = read_block_averaged(src, np.arange(n_bands), None, 1, RangeTally(value_range), p.name)
            cube = cube.reshape(-1, n_bands).astype(np.float64)
            cube = cube[np.isfinite(cube).all(1)]
            s1 += cube.sum(0)
            s2 += (cube * cube).sum(0)
            n += len(cube)
        if n < 2:
            raise UserError("dark frames contain no finite pixels", file=paths[0])
        var = np.maximum(s2 / n - (s1 / n) ** 2, 0.0) * n / (n - 1)
        return np.sqrt(var), "dark_frames"
    if meta.get("dark_sigma") is not None:
        sig = V.number_list(meta["dark_sigma"], tf, "dark_sigma", length=n_bands)
        if np.any(sig < 0):
            raise UserError("dark_sigma values must be >= 0", file=tf, field="dark_sigma")
        return sig, "transforms.json"
    return _estimate_sigma(sources[: min(3, len(sources))], n_bands, value_range), "estimated"


def _estimate_sigma(sources: list[CubeSource], n_bands: int, value_range) -> np.ndarray:
    """Per-band noise σ from images (no dark frames): robust MAD of a 3×3 Laplacian residual (Immerkær 1996)."""
    ests = []
    for src in sources:
        cube = read_block_averaged(src, np.arange(n_bands), None, 1, RangeTally(value_range), src.path.stem)
        lap = (4 * cube[1:-1, 1:-1] - cube[:-2, 1:-1] - cube[2:, 1:-1] - cube[1:-1, :-2] - cube[1:-1, 2:])
        lap = lap.reshape(-1, n_bands)
        lap = lap[np.isfinite(lap).all(1)]
        # std of 4x - 4 neighbours for i.i.d. noise σ is sqrt(20) σ; MAD → σ via 1.4826
        ests.append(1.4826 * np.median(np.abs(lap - np.median(lap, 0)), 0) / np.sqrt(20.0))
    return np.median(np.stack(ests), 0)
