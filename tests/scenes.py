"""Small scenes made on the fly for tests (docs/data-format.md layout, ENVI cubes)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.data.cube_io import write_envi


def make_scene(root: Path, *, n_frames: int = 7, w: int = 24, h: int = 16, n_bands: int = 6,
               n_dark: int = 3, dark_sigma: float = 0.01, seed: int = 0, fmt: str = "envi",
               angles_only: bool = False) -> Path:
    """Write a textured random scene to ``root``; returns ``root``.

    Views: nadir plus a ring at 30° zenith; sun at 35° zenith, 150° azimuth. Dark frames
    (Gaussian noise of std ``dark_sigma``) in calibration/ when ``n_dark`` > 0.
    """
    rng = np.random.default_rng(seed)
    wl = np.linspace(420.0, 880.0, n_bands)
    intr = Intrinsics.from_fov(35.0, w, h)
    frames = []
    for k in range(n_frames):
        zen, az = (0.0, 0.0) if k == 0 else (30.0, (k - 1) * 360.0 / (n_frames - 1))
        cube = (0.05 + 0.4 * rng.random((h, w, n_bands))).astype(np.float32)
        name = f"view_{k:02d}"
        if fmt == "envi":
            rel = f"images/{name}.hdr"
            write_envi(root / rel, cube, wl, np.full(n_bands, 4.0))
        else:
            rel = f"images/{name}.npy"
            (root / "images").mkdir(parents=True, exist_ok=True)
            np.save(root / rel, cube)
        fr = {"file_path": rel, "view_zenith_deg": zen, "view_azimuth_deg": az}
        if angles_only:
            fr["distance_m"] = 100.0
        else:
            fr["transform_matrix"] = pose_from_view_angles(zen, az, 100.0).tolist()
        frames.append(fr)
    meta = {"camera_model": "PINHOLE", "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy,
            "w": w, "h": h, "wavelengths_nm": wl.tolist(), "fwhm_nm": [4.0] * n_bands,
            "sun_zenith_deg": 35.0, "sun_azimuth_deg": 150.0, "frames": frames}
    for k in range(n_dark):
        write_envi(root / "calibration" / f"dark_{k:02d}.hdr",
                   rng.normal(0.0, dark_sigma, (h, w, n_bands)).astype(np.float32), wl)
    if n_dark == 0:
        meta["dark_sigma"] = [dark_sigma] * n_bands
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))
    return root


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """{relative path: (size, mtime_ns)} of every file under ``root`` (to prove nothing was written)."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}
