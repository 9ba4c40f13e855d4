"""Reading and writing reflectance cubes (ENVI via SPy, .npy, multi-band GeoTIFF).

Cubes are float32 reflectance, [H, W, B] (rows, columns, bands). ENVI files are
written band-interleaved-by-pixel (``bip``) so that the on-disk layout is the numpy
layout and row blocks can be read from a memory map without touching the rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import spectral.io.envi as envi
import tifffile

from brfgs.data.validation import header_matches, pixel_range
from brfgs.errors import UserError
from brfgs.data.atomic import atomic_path

CUBE_SUFFIXES = (".hdr", ".npy", ".tif", ".tiff")
CHUNK_BYTES = 64 * 2**20  # read at most ~64 MiB of raw cube per block


def write_envi(path_hdr: str | Path, cube: np.ndarray, wavelengths_nm, fwhm_nm=None,
               extra: dict | None = None) -> Path:
    """Write ``cube`` [H, W, B] as an ENVI float32 cube ``path_hdr`` + ``.img``.

    The header holds ``wavelength`` (nm), ``wavelength units`` and ``fwhm``. Byte-identical
    output for identical input (no timestamps). Returns the header path.
    """
    path_hdr = Path(path_hdr)
    cube = np.ascontiguousarray(cube, dtype=np.float32)
    if cube.ndim == 2:
        cube = cube[:, :, None]
    meta = {"wavelength units": "Nanometers",
            "wavelength": [f"{w:.4f}" for w in np.asarray(wavelengths_nm, float)]}
    if fwhm_nm is not None:
        meta["fwhm"] = [f"{w:.4f}" for w in np.asarray(fwhm_nm, float)]
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


def open_cube(path: Path, wl: np.ndarray, tf: Path, frame: str) -> CubeSource:
    """Header-level checks of one cube; returns how to read it."""
    n_bands = len(wl)
    suffix = path.suffix.lower()
    if suffix == ".hdr":
        if not path.is_file():
            raise UserError(f"frame '{frame}': cube header not found", file=path)
        hdr = read_envi_header(path)
        img = envi_image_path(path)
        if img is None:
            raise UserError(f"frame '{frame}': ENVI data file (.img) next to the header not found", file=path)
        for key in ("lines", "samples", "bands", "data type", "interleave"):
            if key not in hdr:
                raise UserError(f"frame '{frame}': required header field missing", file=path, field=key)
        header_matches(hdr, wl, path, tf, n_bands)
        lines, samples = int(hdr["lines"]), int(hdr["samples"])
        try:
            obj = envi.open(str(path), str(img))
        except Exception as exc:
            raise UserError(f"frame '{frame}': unreadable ENVI cube ({exc})", file=path) from None
        expected = lines * samples * n_bands * obj.sample_size + int(hdr.get("header offset", 0))
        if img.stat().st_size < expected:
            raise UserError(f"frame '{frame}': data file is {img.stat().st_size} bytes, the header needs "
                            f"{expected}", file=img)
        return CubeSource("envi", path, lines, samples, n_bands)
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
        except Exception as exc:
            raise UserError(f"frame '{frame}': unreadable GeoTIFF ({exc})", file=path) from None
        if len(shape) == 3 and shape[0] == n_bands and shape[2] != n_bands:
            return CubeSource("tiff", path, shape[1], shape[2], n_bands, band_axis_first=True)
        if len(shape) == 3 and shape[2] == n_bands:
            return CubeSource("tiff", path, shape[0], shape[1], n_bands)
        raise UserError(f"frame '{frame}': expected {n_bands} bands, found shape {shape}", file=path, field="shape")
    raise UserError(f"frame '{frame}': unsupported cube format {suffix!r} (expected .hdr, .npy, .tif)",
                    file=tf, field="file_path")


def _raw_array(src: CubeSource):
    """A lazily indexable [lines, samples, bands] view of the cube (memory map where possible)."""
    if src.kind == "envi":
        return envi.open(str(src.path), str(envi_image_path(src.path))).open_memmap(interleave="bip")
    if src.kind == "npy":
        return np.load(src.path, mmap_mode="r")
    try:
        arr = tifffile.memmap(src.path, mode="r")
    except Exception:  # compressed or tiled TIFF: read whole (small files in practice)
        arr = tifffile.imread(src.path)
    return np.moveaxis(arr, 0, -1) if src.band_axis_first else arr


def read_block_averaged(src: CubeSource, file_bands: np.ndarray, roi, factor: int,
                         value_range: tuple[float, float], frame: str) -> np.ndarray:
    """Read bands ``file_bands`` of the ROI and area-average by ``factor``, a row block at a time.

    The memory map is reopened for each block and dropped after it, so the pages it touched
    leave the process's resident set: peak memory is one block, not the cube.
    """
    x0, y0, rw, rh = roi if roi is not None else (0, 0, src.samples, src.lines)
    out_h, out_w = rh // factor, rw // factor
    nb = len(file_bands)
    out = np.empty((out_h, out_w, nb), dtype=np.float32)
    row_bytes = src.samples * src.bands * 4 * factor
    rows_per_block = max(1, CHUNK_BYTES // max(1, row_bytes))
    contiguous = nb == src.bands and np.array_equal(file_bands, np.arange(src.bands))
    try:
        for r0 in range(0, out_h, rows_per_block):
            r1 = min(out_h, r0 + rows_per_block)
            raw = _raw_array(src)
            rows = slice(y0 + r0 * factor, y0 + r1 * factor)
            cols = slice(x0, x0 + out_w * factor)
            block = raw[rows, cols] if contiguous else raw[rows, cols][:, :, file_bands]
            block = np.asarray(block, dtype=np.float32)
            del raw
            pixel_range(block, value_range, src.path, frame)
            if factor > 1:
                block = block.reshape(r1 - r0, factor, out_w, factor, nb).mean(axis=(1, 3), dtype=np.float64)
            out[r0:r1] = block
    except UserError:
        raise
    except (OSError, ValueError) as exc:
        raise UserError(f"frame '{frame}': could not read cube data ({exc})", file=src.path) from None
    return out
