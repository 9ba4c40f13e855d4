"""Checks on a scene's ``transforms.json`` and cubes.

Every check raises :class:`brfgs.errors.UserError` naming the file and the field
(``frames[3].transform_matrix``), what was found and what was expected. The reader
(:mod:`brfgs.data.scene`) calls these; nothing here writes anything.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np

from brfgs.data.paths import inside, resolved
from brfgs.errors import UserError

MAX_JSON_BYTES = 64 * 2**20   # transforms.json larger than this is refused before parsing
MAX_JSON_DEPTH = 32           # nesting depth of transforms.json (the layout needs 4)
CONTROL_CHARS = re.compile(r"[\x00-\x1f\x7f]")
ALLOW_LINKS_HINT = "pass --allow-outside-links to read files that links lead to outside the scene"
ORTHONORMAL_TOL = 1e-3
WAVELENGTH_TOL_NM = 0.5
MIN_FRAMES = 3
MAX_CAMERA_DISTANCE_M = 100_000.0   # a camera farther than this from the scene origin is an input error
MIN_CAMERA_DISTANCE_M = 1e-3        # a camera nearer than this to the scene origin sits on the scene centre
# Numbers written as text (header fields, option values): ASCII digits only. Python's int() and
# float() also read other scripts' digits ('١٦' is 16), '1_000' and blanks around the number.
ASCII_INTEGER = re.compile(r"[+-]?[0-9]+")
ASCII_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")
ASCII_NON_FINITE = re.compile(r"[+-]?(nan|inf|infinity)", re.IGNORECASE)


def number(value, file: Path, field: str, *, lo: float | None = None, hi: float | None = None,
           integer: bool = False) -> float:
    """``value`` as a finite float (or int) inside [lo, hi]; UserError otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(f"expected a number, found {value!r}", file=file, field=field)
    try:
        finite = math.isfinite(value)
    except OverflowError:  # an integer beyond the float range
        finite = False
    if not finite:
        shown = repr(value) if not isinstance(value, int) else f"an integer of {len(str(abs(value)))} digits"
        raise UserError(f"expected a finite number, found {shown}", file=file, field=field)
    if integer and int(value) != value:
        raise UserError(f"expected an integer, found {value!r}", file=file, field=field)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise UserError(f"value {value} out of range, expected {lo} to {hi}", file=file, field=field)
    return int(value) if integer else float(value)


def ascii_float(text: str, *, non_finite: bool = False) -> float:
    """The number ``text`` (a str, already stripped) written with ASCII digits, an optional sign,
    decimal point and exponent (and, with ``non_finite``, nan / inf / infinity); ValueError otherwise."""
    if not isinstance(text, str) or len(text) > 64:
        raise ValueError(f"not a number: {str(text)[:40]!r}")
    if ASCII_DECIMAL.fullmatch(text) or (non_finite and ASCII_NON_FINITE.fullmatch(text)):
        return float(text)
    raise ValueError(f"not a number written with the digits 0-9: {text[:40]!r}")


def ascii_int(text: str) -> int:
    """The integer ``text`` (a str, already stripped) written with ASCII digits and an optional sign,
    at most 18 digits; ValueError otherwise."""
    if isinstance(text, str) and len(text) <= 19 and ASCII_INTEGER.fullmatch(text):
        return int(text)
    raise ValueError(f"not an integer written with the digits 0-9: {str(text)[:40]!r}")


def number_list(value, file: Path, field: str, *, length: int | None = None) -> np.ndarray:
    """A list of finite numbers as float64 [n]; optional exact length."""
    if not isinstance(value, (list, tuple)) or len(value) == 0:
        raise UserError(f"expected a non-empty list of numbers, found {type(value).__name__}", file=file, field=field)
    out = np.empty(len(value))
    for i, v in enumerate(value):
        out[i] = number(v, file, f"{field}[{i}]")
    if length is not None and len(out) != length:
        raise UserError(f"expected {length} values (one per band), found {len(out)}", file=file, field=field)
    return out


def wavelengths(values, file: Path, field: str) -> np.ndarray:
    """Band centre wavelengths (nm), positive and strictly increasing."""
    wl = number_list(values, file, field)
    if np.any(wl <= 0):
        raise UserError("wavelengths must be positive (nanometres)", file=file, field=field)
    bad = np.nonzero(np.diff(wl) <= 0)[0]
    if bad.size:
        i = int(bad[0])
        raise UserError(f"wavelengths must be strictly increasing: {wl[i]:g} nm at index {i} is followed by "
                        f"{wl[i + 1]:g} nm", file=file, field=field)
    return wl


def transform_matrix(value, file: Path, field: str) -> np.ndarray:
    """A 4×4 camera-to-world with an orthonormal, right-handed rotation and last row (0, 0, 0, 1)."""
    rows = value if isinstance(value, (list, tuple)) else []
    if any(not isinstance(x, (int, float)) or isinstance(x, bool) for row in rows
           for x in (row if isinstance(row, (list, tuple)) else [row])):
        raise UserError("expected a 4x4 matrix of numbers (rows of four JSON numbers, not strings or booleans)",
                        file=file, field=field)
    try:
        m = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise UserError("expected a 4x4 matrix of numbers", file=file, field=field) from None
    except OverflowError:  # an integer beyond the float range
        raise UserError("a matrix element is an integer beyond the range of a float", file=file,
                        field=field) from None
    if m.shape != (4, 4):
        raise UserError(f"expected a 4x4 matrix, found shape {m.shape}", file=file, field=field)
    if not np.all(np.isfinite(m)):
        raise UserError("matrix contains NaN or Inf", file=file, field=field)
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise UserError(f"last row must be [0, 0, 0, 1], found {m[3].tolist()}", file=file, field=field)
    R = m[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > ORTHONORMAL_TOL:
        raise UserError(f"rotation part is not orthonormal (max |R^T R - I| = {err:.3g}, tolerance "
                        f"{ORTHONORMAL_TOL}); scale or shear in a camera-to-world matrix is not supported",
                        file=file, field=field)
    if np.linalg.det(R) < 0:
        raise UserError("rotation part has determinant -1 (a reflection), expected a proper rotation",
                        file=file, field=field)
    return m


def camera_distance(value, file: Path, field: str) -> float:
    """A frame's ``distance_m``: a number between MIN_CAMERA_DISTANCE_M and MAX_CAMERA_DISTANCE_M."""
    return number(value, file, field, lo=MIN_CAMERA_DISTANCE_M, hi=MAX_CAMERA_DISTANCE_M)


def camera_position(c2w: np.ndarray, file: Path, field: str, above_ground: bool = False) -> None:
    """UserError unless the camera centre of ``c2w`` [4, 4] lies between MIN_CAMERA_DISTANCE_M and
    MAX_CAMERA_DISTANCE_M from the scene origin (a camera on the scene centre has no view direction;
    one farther than 100 km is not a camera of the scene: wrong units or an unaligned model) and, with
    ``above_ground`` (its view angles come from its position), above the ground plane z = 0."""
    centre = np.asarray(c2w, float)[:3, 3]
    far = float(np.abs(centre).max())                      # before the norm: 1e300 squared overflows
    dist = far if far > MAX_CAMERA_DISTANCE_M else float(np.linalg.norm(centre))
    if dist < MIN_CAMERA_DISTANCE_M:
        raise UserError("the camera sits at the scene origin (0, 0, 0), where its view direction is undefined; "
                        "cameras are positions in ENU metres around the scene (an unaligned COLMAP model puts its "
                        "first image there)", file=file, field=field)
    if dist > MAX_CAMERA_DISTANCE_M:
        raise UserError(f"the camera is {dist:.4g} m from the scene origin, farther than the {MAX_CAMERA_DISTANCE_M / 1000:g}"
                        " km a camera of a scene may be; positions are ENU metres around the scene", file=file,
                        field=field)
    if above_ground and not centre[2] > 0:
        raise UserError(f"the camera is at or below the ground plane (z = {centre[2]:.6g} m), where its view angles "
                        "are undefined: give view_zenith_deg and view_azimuth_deg, or a camera above the scene",
                        file=file, field=field)


def json_depth(obj) -> int:
    """Nesting depth of a parsed JSON value (a scalar is 0), without recursion."""
    depth, stack = 0, [(obj, 1)]
    while stack:
        o, d = stack.pop()
        if isinstance(o, (dict, list)):
            depth = max(depth, d)
            stack.extend((v, d + 1) for v in (o.values() if isinstance(o, dict) else o))
    return depth


def read_json_file(path: Path, what: str = "JSON file"):
    """The parsed content of a JSON file a user gives (transforms.json, an ROI GeoJSON, a sidecar):
    at most MAX_JSON_BYTES and MAX_JSON_DEPTH levels; UserError naming the file for a missing,
    oversized, undecodable or malformed file (an integer of > 4300 digits included)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_JSON_BYTES:
            raise UserError(f"{size} bytes, more than the {MAX_JSON_BYTES} bytes a {what} may have", file=path)
        text = path.read_bytes().decode("utf-8")
        data = json.loads(text)
    except FileNotFoundError:
        raise UserError(f"{what} not found", file=path) from None
    except IsADirectoryError:
        raise UserError(f"a folder, not a {what}", file=path) from None
    except RecursionError:
        raise UserError(f"nested deeper than {MAX_JSON_DEPTH} levels", file=path) from None
    except UnicodeDecodeError:
        raise UserError(f"not a text (UTF-8) {what}", file=path) from None
    except ValueError as exc:  # JSONDecodeError, or an integer of > 4300 digits
        raise UserError(f"not valid JSON ({str(exc)[:200]})", file=path) from None
    if json_depth(data) > MAX_JSON_DEPTH:
        raise UserError(f"nested deeper than {MAX_JSON_DEPTH} levels", file=path)
    return data


def finite_number(value) -> float | None:
    """``value`` as a finite float, or None when it is not a number (bool included), is NaN/inf or an
    integer beyond the float range."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        f = float(value)
    except OverflowError:
        return None
    return f if math.isfinite(f) else None


def path_text(rel: object, file: Path, field: str) -> str:
    """A path string as written in a file: non-empty, no control characters, valid Unicode."""
    if not isinstance(rel, str) or not rel:
        raise UserError(f"expected a relative path string, found {rel!r}", file=file, field=field)
    if CONTROL_CHARS.search(rel):
        raise UserError(f"path {rel!r} contains control characters", file=file, field=field)
    try:
        rel.encode("utf-8")
    except UnicodeEncodeError:
        raise UserError(f"path {rel!r} is not valid Unicode (a lone surrogate)", file=file, field=field) from None
    if rel.endswith(("/", "\\")) or rel.rsplit("/", 1)[-1] in (".", ".."):
        raise UserError(f"path {rel[:200]!r} names a folder, not a file (remove the trailing '{rel[-1]}')"
                        if rel.endswith(("/", "\\")) else f"path {rel[:200]!r} does not end in a file name",
                        file=file, field=field)
    return rel


def plain_text(value: str, file: Path | None, field: str, what: str = "name") -> str:
    """``value`` unless it holds control characters or lone surrogates (it goes into titles, messages and
    file names); UserError naming the file and the field otherwise."""
    if CONTROL_CHARS.search(value):
        raise UserError(f"the {what} {value[:80]!r} contains control characters", file=file, field=field)
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise UserError(f"the {what} {value[:80]!r} is not valid Unicode (a lone surrogate)", file=file,
                        field=field) from None
    return value


def confined(path: Path, root: Path, file: Path, field: str | None, allow_outside_links: bool) -> Path:
    """``path`` unless, after following links, it lies outside the scene folder ``root``."""
    if not allow_outside_links and not inside(path, root):
        raise UserError(f"{path.name} leads outside the scene folder {root} (a link to "
                        f"{Path(path).resolve()}); {ALLOW_LINKS_HINT}", file=file, field=field)
    return path


def path_inside(root: Path, rel: object, file: Path, field: str, allow_outside_links: bool = False) -> Path:
    """``root / rel``; refuse absolute paths, paths that climb out of ``root`` with '..', and (unless
    ``allow_outside_links``) paths that links lead out of ``root``."""
    rel = path_text(rel, file, field)
    if Path(rel).is_absolute():
        raise UserError(f"absolute path {rel!r} not allowed: paths are relative to the scene folder",
                        file=file, field=field)
    if os.path.normpath(rel).split(os.sep)[0] == "..":
        raise UserError(f"path {rel!r} leads outside the scene folder {root}", file=file, field=field)
    full = root / rel
    if not allow_outside_links and not inside(full, root):
        raise UserError(f"path {rel!r} leads outside the scene folder {root} (through a link); "
                        f"{ALLOW_LINKS_HINT}", file=file, field=field)
    return resolved(full)


def header_matches(hdr: dict, expected_wl: np.ndarray, cube_file: Path, transforms_file: Path,
                   n_bands: int) -> None:
    """A cube's ENVI header agrees with ``transforms.json`` (band count, wavelengths)."""
    if hdr.get("bands") is not None and ascii_int(str(hdr["bands"]).strip()) != n_bands:
        raise UserError(f"header has {int(hdr['bands'])} bands but {transforms_file.name} lists "
                        f"{n_bands} wavelengths", file=cube_file, field="bands")
    if "wavelength" in hdr:
        try:
            wl = np.asarray([ascii_float(str(v).strip()) for v in hdr["wavelength"]])
        except (TypeError, ValueError):
            raise UserError("wavelength values are not numbers written with the digits 0-9", file=cube_file,
                            field="wavelength") from None
        if len(wl) != n_bands:
            raise UserError(f"header lists {len(wl)} wavelengths, expected {n_bands}", file=cube_file,
                            field="wavelength")
        units = str(hdr.get("wavelength units", "nanometers")).lower()
        if units.startswith("micro") or units in ("um", "µm"):
            wl = wl * 1000.0
        if np.any(np.diff(wl) <= 0):
            raise UserError("header wavelengths are not strictly increasing", file=cube_file, field="wavelength")
        diff = np.abs(wl - expected_wl)
        if diff.max() > WAVELENGTH_TOL_NM:
            i = int(diff.argmax())
            raise UserError(f"band {i} is {wl[i]:g} nm in the header but {expected_wl[i]:g} nm in "
                            f"{transforms_file.name} (tolerance {WAVELENGTH_TOL_NM} nm)", file=cube_file,
                            field="wavelength")


# A unit error (digital numbers, radiance, percent, a missing scale factor) moves most of a frame's
# pixels out of the plausible range. A specular glint (water, glass, car paint: BRF 10-100 at a
# pixel) moves a few above it, a dead pixel one below it. A frame with more than these shares of
# its pixels above / below the range is refused.
GLINT_PIXEL_SHARE = 0.05
BAD_PIXEL_SHARE = 0.01


class RangeTally:
    """Pixels of one frame outside the plausible reflectance range, counted over its row blocks.

    ``add`` takes each block [h, w, b] as read (NaN/Inf allowed: they are masked elsewhere, whatever
    their share), masks the values below the range (no surface reflects less than nothing: such
    values are sensor artefacts) and counts the pixels with a value above it (kept: glints are data).
    ``check`` refuses the frame when more than ``GLINT_PIXEL_SHARE`` of its pixels were above the
    range or more than ``BAD_PIXEL_SHARE`` below it.
    """

    def __init__(self, value_range: tuple[float, float]):
        self.lo, self.hi = value_range
        self.n_pixels = self.n_low = self.n_high = 0
        self.low_min, self.high_max = np.inf, -np.inf

    def add(self, block: np.ndarray) -> np.ndarray:
        """Count one float block [h, w, b]; returns it with the values below the range NaN (a new array
        only when there are any: a read-only memory map passes through)."""
        self.n_pixels += block.shape[0] * block.shape[1]
        finite = np.isfinite(block)                             # NaN and ±Inf are masked, not outliers
        with np.errstate(invalid="ignore"):
            low, high = finite & (block < self.lo), finite & (block > self.hi)
        if high.any():
            self.n_high += int(high.any(-1).sum())
            self.high_max = max(self.high_max, float(block[high].max()))
        if not low.any():
            return block
        self.n_low += int(low.any(-1).sum())
        self.low_min = min(self.low_min, float(block[low].min()))
        return np.where(low, np.float32(np.nan), block)

    def check(self, cube_file: Path, frame: str) -> None:
        """UserError when too many of the frame's pixels were outside the range (see the shares above)."""
        n = max(self.n_pixels, 1)
        if self.n_high <= GLINT_PIXEL_SHARE * n and self.n_low <= BAD_PIXEL_SHARE * n:
            return
        n_out = self.n_low + self.n_high
        found = ", ".join(s for s in (f"min {self.low_min:.4g}" if self.n_low else "",
                                      f"max {self.high_max:.4g}" if self.n_high else "") if s)
        raise UserError(f"frame '{frame}': {n_out} of {self.n_pixels} pixels ({100 * n_out / self.n_pixels:.1f} %) "
                        f"have values outside the plausible reflectance range [{self.lo:g}, {self.hi:g}] "
                        f"(found {found}; up to {100 * GLINT_PIXEL_SHARE:g} % above it are accepted as glints, "
                        f"{100 * BAD_PIXEL_SHARE:g} % below it as bad pixels); is the cube in reflectance units? "
                        f"Widen the range with --value-range if these values are real", file=cube_file,
                        field="reflectance")
