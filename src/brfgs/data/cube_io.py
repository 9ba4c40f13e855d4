"""Reading and writing reflectance cubes (ENVI via SPy, .npy, multi-band GeoTIFF).

Cubes are float32 reflectance, [H, W, B] (rows, columns, bands). ENVI files are
written band-interleaved-by-pixel (``bip``) so that the on-disk layout is the numpy
layout and row blocks can be read from a memory map without touching the rest.
"""

from __future__ import annotations

import contextlib
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import spectral.io.envi as envi
import tifffile

from brfgs.data.validation import RangeTally, ascii_float, confined, header_matches
from brfgs.errors import UserError
from brfgs.data.atomic import atomic_path
from brfgs.data.tiff_window import read_tiff_window


@contextlib.contextmanager
def _spy_quiet():
    """SPy's reading without its note that it lower-cased a header key: keys are case-insensitive
    (docs/data-format.md), so that is no news to the user."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Parameters with non-lowercase names", category=UserWarning)
        yield

CUBE_SUFFIXES = (".hdr", ".npy", ".tif", ".tiff")
CHUNK_BYTES = 64 * 2**20  # read at most ~64 MiB of raw cube per block
GDAL_NODATA_TAG = 42113   # GeoTIFF tag (ASCII) of the no-data value, as GDAL and rasterio write it


def write_envi(path_hdr: str | Path, cube: np.ndarray, wavelengths_nm, fwhm_nm=None,
               extra: dict | None = None, *, default_bands=None, ignore_value: float | None = None) -> Path:
    """Write ``cube`` [H, W, B] as an ENVI float32 cube ``path_hdr`` + ``.img``.

    The header holds ``wavelength`` (nm), ``wavelength units``, ``fwhm``, ``band names``
    ("<wavelength> nm", which GDAL shows as band descriptions), ``default bands`` (the RGB a
    viewer shows first; ``default_bands`` are 0-based band indices, written 1-based as ENVI
    wants) and ``data ignore value`` (``ignore_value``; NaN is written as ``nan``, which GDAL
    reads as the no-data value). Byte-identical output for identical input (no timestamps).
    Returns the header path.
    """
    path_hdr = Path(path_hdr)
    cube = np.ascontiguousarray(cube, dtype=np.float32)
    if cube.ndim == 2:
        cube = cube[:, :, None]
    meta = {}
    if wavelengths_nm is not None:                 # None: a map that is not a spectrum (e.g. heights)
        meta = {"wavelength units": "Nanometers", "wavelength": [f"{w:.4f}" for w in np.asarray(wavelengths_nm, float)]}
        if len(meta["wavelength"]) == cube.shape[2]:
            meta["band names"] = [f"{w:.1f} nm" for w in np.asarray(wavelengths_nm, float)]
    if fwhm_nm is not None:
        meta["fwhm"] = [f"{w:.4f}" for w in np.asarray(fwhm_nm, float)]
    if default_bands is not None:
        idx = [int(i) for i in default_bands]
        if any(not 0 <= i < cube.shape[2] for i in idx):
            raise ValueError(f"default bands {idx} outside 0..{cube.shape[2] - 1}")
        meta["default bands"] = [str(i + 1) for i in idx]
    if ignore_value is not None:
        meta["data ignore value"] = "nan" if np.isnan(ignore_value) else f"{float(ignore_value):g}"
    if extra:
        meta.update(extra)
    # both files under temporary names (SPy writes the .img beside the .hdr it is given), the data
    # renamed into place first: a crash never leaves a header that describes missing or partial data
    with atomic_path(path_hdr) as tmp_hdr, atomic_path(path_hdr.with_suffix(".img")) as tmp_img:
        envi.save_image(str(tmp_hdr), cube, metadata=meta, interleave="bip", force=True, ext=".img", dtype=np.float32)
        tmp_hdr.with_suffix(".img").replace(tmp_img)
    return path_hdr


def envi_image_path(path_hdr: Path) -> Path | None:
    """The data file next to an ENVI header (``.img``, ``.dat``, ``.raw`` or no suffix)."""
    for suffix in (".img", ".dat", ".raw", ".bsq", ".bil", ".bip", ""):
        cand = path_hdr.with_suffix(suffix)
        if cand != path_hdr and cand.exists():
            return cand
    return None


def read_envi_header(path_hdr: Path) -> dict:
    """Parsed ENVI header (lower-case keys) of ``path_hdr``; UserError if unreadable."""
    try:
        with _spy_quiet():
            return envi.read_envi_header(str(path_hdr))
    except Exception as exc:  # SPy raises several types for malformed headers
        raise UserError(f"unreadable ENVI header ({exc})", file=path_hdr) from None


# ---------------------------------------------------------------------------------------------------
# reading the cubes of a scene: header checks, then row blocks from a memory map


@dataclass
class CubeSource:
    """How to read one cube of a scene: format and full-resolution shape."""

    kind: str                       # "envi" | "npy" | "tiff"
    path: Path
    lines: int
    samples: int
    bands: int
    band_axis_first: bool = False   # GeoTIFF stored as [B, H, W]
    nodata: float | None = None     # stored value that marks a pixel without data (read as NaN)
    scale: float = 1.0              # stored value / scale = reflectance (ENVI "reflectance scale factor")


# ENVI data types brfgs reads (header "data type" code -> numpy type); byte order 0 or 1 is honoured.
ENVI_DATA_TYPES = {"1": "uint8", "2": "int16", "3": "int32", "4": "float32", "5": "float64", "12": "uint16",
                   "13": "uint32", "14": "int64", "15": "uint64"}
ENVI_INTERLEAVES = ("bsq", "bil", "bip")


def _header_int(hdr: dict, key: str, path: Path, lo: int) -> int:
    """An integer header field written as digits, >= ``lo``; UserError naming the field otherwise."""
    v = hdr.get(key)
    text = v.strip() if isinstance(v, str) else None
    if text is None or not text.isascii() or not text.isdigit() or len(text) > 12 or int(text) < lo:
        raise UserError(f"expected an integer >= {lo} written with the digits 0-9, found {str(v)[:40]!r}", file=path,
                        field=key)
    return int(text)


def _header_number(value, path: Path, field: str, *, positive: bool = False, nan_ok: bool = False) -> float:
    """A number from a header field (ENVI or a GeoTIFF's GDAL_NODATA); UserError naming the field otherwise."""
    text = value.strip() if isinstance(value, str) else value
    try:
        x = ascii_float(text, non_finite=True)       # not float(): it reads other scripts' digits too
    except ValueError:
        x = None
    if x is None or (np.isnan(x) and not nan_ok) or np.isinf(x) or (positive and not x > 0):
        want = "a positive number" if positive else "a number" + (" or nan" if nan_ok else "")
        raise UserError(f"expected {want} written with the digits 0-9, found {str(value)[:40]!r}", file=path,
                        field=field)
    return x


def envi_value_meaning(hdr: dict, path: Path) -> tuple[float | None, float]:
    """(no-data value or None, reflectance scale factor) of an ENVI header: ``data ignore value``
    marks pixels without data; stored values divided by ``reflectance scale factor`` are reflectance."""
    nodata = hdr.get("data ignore value")
    nodata = None if nodata is None else _header_number(nodata, path, "data ignore value", nan_ok=True)
    scale = hdr.get("reflectance scale factor")
    scale = 1.0 if scale is None else _header_number(scale, path, "reflectance scale factor", positive=True)
    return nodata, scale


def check_envi_header(hdr: dict, path: Path, frame: str) -> tuple[int, int, int, int]:
    """Strictly typed (lines, samples, header offset, bytes per value) of an ENVI header."""
    for key in ("lines", "samples", "bands", "data type", "interleave"):
        if key not in hdr:
            raise UserError(f"frame '{frame}': required header field missing", file=path, field=key)
    lines, samples = _header_int(hdr, "lines", path, 1), _header_int(hdr, "samples", path, 1)
    _header_int(hdr, "bands", path, 1)
    offset = _header_int(hdr, "header offset", path, 0) if "header offset" in hdr else 0
    dtype = str(hdr["data type"]).strip()
    if dtype not in ENVI_DATA_TYPES:
        raise UserError(f"data type {hdr['data type']!r} not supported; expected one of {', '.join(ENVI_DATA_TYPES)}",
                        file=path, field="data type")
    if str(hdr["interleave"]).strip().lower() not in ENVI_INTERLEAVES:
        raise UserError(f"interleave {hdr['interleave']!r} not supported; expected bsq, bil or bip", file=path,
                        field="interleave")
    if "byte order" in hdr and str(hdr["byte order"]).strip() not in ("0", "1"):
        raise UserError(f"byte order must be 0 (little endian) or 1 (big endian), found {hdr['byte order']!r}",
                        file=path, field="byte order")
    return lines, samples, offset, np.dtype(ENVI_DATA_TYPES[dtype]).itemsize


def _open_envi(path: Path, wl: np.ndarray, tf: Path, frame: str, allow_outside_links: bool) -> CubeSource:
    """Header checks of an ENVI cube and its data file (size exactly as the header says)."""
    n_bands = len(wl)
    if not path.is_file():
        raise UserError(f"frame '{frame}': cube header not found", file=path)
    hdr = read_envi_header(path)
    img = envi_image_path(path)
    if img is None:
        raise UserError(f"frame '{frame}': ENVI data file (.img) next to the header not found", file=path)
    confined(img, tf.parent, img, None, allow_outside_links)
    lines, samples, offset, nbytes = check_envi_header(hdr, path, frame)
    header_matches(hdr, wl, path, tf, n_bands)
    expected = offset + lines * samples * n_bands * nbytes
    if img.stat().st_size != expected:
        raise UserError(f"frame '{frame}': data file is {img.stat().st_size} bytes, the header describes "
                        f"{expected} (header offset + lines x samples x bands x {nbytes} bytes)", file=img)
    nodata, scale = envi_value_meaning(hdr, path)      # before SPy, which parses them less strictly
    try:
        with _spy_quiet():
            envi.open(str(path), str(img))
    except Exception as exc:
        raise UserError(f"frame '{frame}': unreadable ENVI cube ({exc})", file=path) from None
    return CubeSource("envi", path, lines, samples, n_bands, nodata=nodata, scale=scale)


def open_cube(path: Path, wl: np.ndarray, tf: Path, frame: str, allow_outside_links: bool = False) -> CubeSource:
    """Header-level checks of one cube (``tf``: the scene's transforms.json); returns how to read it."""
    n_bands = len(wl)
    suffix = path.suffix.lower()
    confined(path, tf.parent, path, None, allow_outside_links)
    if suffix == ".hdr":
        return _open_envi(path, wl, tf, frame, allow_outside_links)
    if not path.is_file():
        raise UserError(f"frame '{frame}': cube file not found", file=path)
    if suffix == ".npy":
        try:
            arr = np.load(path, mmap_mode="r")
        except Exception as exc:
            raise UserError(f"frame '{frame}': unreadable .npy cube ({exc})", file=path) from None
        if arr.ndim != 3 or arr.shape[2] != n_bands:
            raise UserError(f"frame '{frame}': expected an array [H, W, {n_bands}], found shape {arr.shape}",
                            file=path, field="shape")
        return CubeSource("npy", path, arr.shape[0], arr.shape[1], n_bands)
    if suffix in (".tif", ".tiff"):
        try:
            with tifffile.TiffFile(path) as t:
                shape = t.series[0].shape
                tag = t.pages[0].tags.get(GDAL_NODATA_TAG)
                nodata_text = None if tag is None else str(tag.value).strip("\x00 ")
        except Exception as exc:
            raise UserError(f"frame '{frame}': unreadable GeoTIFF ({exc})", file=path) from None
        nodata = None if nodata_text is None else _header_number(nodata_text, path, "GDAL_NODATA", nan_ok=True)
        if len(shape) == 3 and shape[0] == n_bands and shape[2] != n_bands:
            return CubeSource("tiff", path, shape[1], shape[2], n_bands, band_axis_first=True, nodata=nodata)
        if len(shape) == 3 and shape[2] == n_bands:
            return CubeSource("tiff", path, shape[0], shape[1], n_bands, nodata=nodata)
        raise UserError(f"frame '{frame}': expected {n_bands} bands, found shape {shape}", file=path, field="shape")
    raise UserError(f"frame '{frame}': unsupported cube format {suffix!r} (expected .hdr, .npy, .tif)",
                    file=tf, field="file_path")


_BYTES_READ = [0]   # stored bytes taken out of cube files since the process started (bytes_read)


def bytes_read() -> int:
    """Bytes of stored cube data read so far by this process (the rows, columns and bands of each
    window or row block as stored; a TIFF's compressed strips or tiles as stored; a file that cannot be
    read by window counts whole): what a test of windowed reading compares with a cube's size."""
    return _BYTES_READ[0]


def _raw_array(src: CubeSource):
    """A lazily indexable [lines, samples, bands] view of the cube (a memory map), or None for a
    TIFF that cannot be memory-mapped (compressed, tiled or striped): read by window then."""
    if src.kind == "envi":
        with _spy_quiet():
            return envi.open(str(src.path), str(envi_image_path(src.path))).open_memmap(interleave="bip")
    if src.kind == "npy":
        return np.load(src.path, mmap_mode="r")
    try:
        arr = tifffile.memmap(src.path, mode="r")
    except Exception:  # compressed or segmented TIFF: strips or tiles (brfgs.data.tiff_window)
        return None
    return np.moveaxis(arr, 0, -1) if src.band_axis_first else arr


def _raw_window(src: CubeSource, rows: slice, cols: slice) -> np.ndarray:
    """Stored values [h, w, bands] of rows ``rows`` and columns ``cols`` (slices in pixels): a view of
    a memory map (dropped by the caller after use), or the decoded strips or tiles of a TIFF."""
    raw = _raw_array(src)
    if raw is not None:
        block = raw[rows, cols]
        _BYTES_READ[0] += block.nbytes
        return block
    got = read_tiff_window(src.path, rows, cols)
    if got is None:  # not one single-page image: read whole
        arr = tifffile.imread(src.path)
        _BYTES_READ[0] += arr.nbytes
        return (np.moveaxis(arr, 0, -1) if src.band_axis_first else arr)[rows, cols]
    block, n_bytes = got
    _BYTES_READ[0] += n_bytes
    return block


def iter_row_blocks(src: CubeSource, file_bands: np.ndarray, roi, factor: int, tally: RangeTally):
    """Row blocks (r0, r1, float32 [r1 - r0, w, b]) of rows r0..r1 of the ROI read and area-averaged by
    ``factor`` (:func:`read_block_averaged`, which collects them), at most ~``CHUNK_BYTES`` of stored
    data each; the frame-level range check is the caller's (``tally.check``)."""
    x0, y0, rw, rh = roi if roi is not None else (0, 0, src.samples, src.lines)
    out_h, out_w = rh // factor, rw // factor
    nb = len(file_bands)
    row_bytes = src.samples * src.bands * 4 * factor
    rows_per_block = max(1, CHUNK_BYTES // max(1, row_bytes))
    contiguous = nb == src.bands and np.array_equal(file_bands, np.arange(src.bands))
    for r0 in range(0, out_h, rows_per_block):
        r1 = min(out_h, r0 + rows_per_block)
        rows = slice(y0 + r0 * factor, y0 + r1 * factor)
        block = _raw_window(src, rows, slice(x0, x0 + out_w * factor))
        if not contiguous:
            block = block[:, :, file_bands]
        block = tally.add(_as_reflectance(block, src))
        if factor > 1:
            block = block.reshape(r1 - r0, factor, out_w, factor, nb).mean(axis=(1, 3), dtype=np.float64)
        yield r0, r1, block


def for_each_block(src: CubeSource, file_bands: np.ndarray, roi, factor: int, tally: RangeTally, frame: str,
                   visit, check: bool = True) -> None:
    """``visit(r0, r1, block)`` for each row block of :func:`iter_row_blocks`, then the frame-level range
    check (``tally.check``) unless ``check`` is False; a file that cannot be read gives UserError."""
    try:
        for r0, r1, block in iter_row_blocks(src, file_bands, roi, factor, tally):
            visit(r0, r1, block)
        if check:
            tally.check(src.path, frame)
    except UserError:
        raise
    except (OSError, ValueError) as exc:
        raise UserError(f"frame '{frame}': could not read cube data ({exc})", file=src.path) from None


def read_block_averaged(src: CubeSource, file_bands: np.ndarray, roi, factor: int, tally: RangeTally,
                         frame: str, check: bool = True) -> np.ndarray:
    """Read bands ``file_bands`` of the ROI and area-average by ``factor``, a row block at a time.

    Stored no-data values become NaN and stored values are divided by the source's scale. Values
    outside the plausible range are counted in ``tally`` (brfgs.data.validation.RangeTally: those
    below it masked, a frame with too many refused unless ``check`` is False: a window of a frame,
    whose share says nothing of the frame's). The memory map is reopened for each block and
    dropped after it, so the pages it touched leave the process's resident set: peak memory is one
    block, not the cube. Only the ROI's rows (and, by memory map or TIFF segment, its columns) are read.
    """
    x0, y0, rw, rh = roi if roi is not None else (0, 0, src.samples, src.lines)
    out = np.empty((rh // factor, rw // factor, len(file_bands)), dtype=np.float32)

    def put(r0: int, r1: int, block: np.ndarray) -> None:
        out[r0:r1] = block

    for_each_block(src, file_bands, roi, factor, tally, frame, put, check)
    return out


def _as_reflectance(block: np.ndarray, src: CubeSource) -> np.ndarray:
    """Stored values [h, w, b] as float32 reflectance: no-data values NaN, divided by the scale (a view
    of a float32 block that needs neither, else a new array)."""
    out = np.asarray(block, dtype=np.float32)
    if src.nodata is not None and not np.isnan(src.nodata):
        stored = np.asarray(block)
        # compare in the stored type: a float32 no-data written as text rounds back to itself
        nodata = stored == (stored.dtype.type(src.nodata) if stored.dtype.kind == "f" else src.nodata)
        if nodata.any():
            out = np.where(nodata, np.float32(np.nan), out)
    if src.scale != 1.0:
        out = out / np.float32(src.scale)
    return out
