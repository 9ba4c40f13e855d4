"""A tiny multi-view scene with consistent geometry for training tests (ray-traced plane).

Textured ground plane z = 0 of two spectra (soil / vegetation) mixed by a smooth pattern,
with a mild view-dependent factor, seen from paper_view_angles(13) at 60 m; 16 bands.
Writes the docs/data-format.md layout (ENVI cubes) plus truth/images (noise-free).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from brfgs.data.cameras import Intrinsics, paper_view_angles, pixel_rays, pose_from_view_angles
from brfgs.data.cube_io import write_envi


def make_plane_scene(root: Path, w: int = 48, h: int = 40, n_bands: int = 16, n_views: int = 13,
                     noise: float = 0.002, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    wl = np.linspace(400.0, 1000.0, n_bands)
    soil = 0.08 + 0.25 * (wl - 400) / 600
    veg = 0.04 + 0.04 * np.exp(-((wl - 550) / 30) ** 2) + 0.40 / (1 + np.exp(-(wl - 715) / 12))
    intr = Intrinsics.from_fov(40.0, w, h)
    k = rng.normal(size=(12, 2)) * 0.8
    ph = rng.uniform(0, 2 * np.pi, 12)
    sun_zen, sun_az = 35.0, 150.0
    s = np.array([np.sin(np.radians(sun_zen)) * np.sin(np.radians(sun_az)),
                  np.sin(np.radians(sun_zen)) * np.cos(np.radians(sun_az)), np.cos(np.radians(sun_zen))])
    frames = []
    for v, (zen, az) in enumerate(paper_view_angles(n_views)):
        c2w = pose_from_view_angles(zen, az, 60.0)
        o, d = pixel_rays(c2w, intr)
        t = -o[..., 2] / d[..., 2]
        p = o + t[..., None] * d  # [H,W,3] on z = 0
        f = sum(np.sin(p[..., 0] * k[j, 0] + p[..., 1] * k[j, 1] + ph[j]) for j in range(12))
        m = 1 / (1 + np.exp(-3.0 * f))  # [H,W] vegetation fraction
        view = -d / np.linalg.norm(d, axis=-1, keepdims=True)
        cos_phase = view @ s
        brdf = 1.0 + 0.15 * cos_phase  # brighter toward backscatter
        clean = (m[..., None] * veg + (1 - m[..., None]) * soil) * brdf[..., None]
        cube = clean + noise * rng.standard_normal(clean.shape)
        name = f"view_{v:02d}"
        write_envi(root / "images" / f"{name}.hdr", cube.astype(np.float32), wl)
        write_envi(root / "truth" / "images" / f"{name}.hdr", clean.astype(np.float32), wl)
        frames.append({"file_path": f"images/{name}.hdr", "transform_matrix": np.asarray(c2w).tolist(),
                       "view_zenith_deg": zen, "view_azimuth_deg": az})
    meta = {"camera_model": "PINHOLE", "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy,
            "w": w, "h": h, "wavelengths_nm": wl.tolist(), "sun_zenith_deg": sun_zen, "sun_azimuth_deg": sun_az,
            "dark_sigma": [noise] * n_bands, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))
    return root
