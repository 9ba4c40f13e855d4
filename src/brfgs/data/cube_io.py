"""Reading and writing reflectance cubes (ENVI via SPy, .npy, multi-band GeoTIFF).

Cubes are float32 reflectance, [H, W, B] (rows, columns, bands). ENVI files are
written band-interleaved-by-pixel (``bip``) so that the on-disk layout is the numpy
layout and row blocks can be read from a memory map without touching the rest.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from brfgs.errors import UserError

CUBE_SUFFIXES = (".hdr", ".npy", ".tif", ".tiff")


def write_envi(path_hdr: str | Path, cube: np.ndarray, wavelengths_nm, fwhm_nm=None,
               extra: dict | None = None) -> Path:
    """Write ``cube`` [H, W, B] as an ENVI float32 cube ``path_hdr`` + ``.img``.

    The header holds ``wavelength`` (nm), ``wavelength units`` and ``fwhm``. Byte-identical
    output for identical input (no timestamps). Returns the header path.
    """
    import spectral.io.envi as envi

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
    path_hdr.parent.mkdir(parents=True, exist_ok=True)
    envi.save_image(str(path_hdr), cube, metadata=meta, interleave="bip", force=True, ext=".img", dtype=np.float32)
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
    import spectral.io.envi as envi

    try:
        return envi.read_envi_header(str(path_hdr))
    except Exception as exc:  # SPy raises several types for malformed headers
        raise UserError(f"unreadable ENVI header ({exc})", file=path_hdr) from None
