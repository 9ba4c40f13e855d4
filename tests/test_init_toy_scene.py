"""A tiny self-made multi-angle hyperspectral scene for the band-selection and init tests.

``make_toy_scene`` writes a scene folder (docs/data-format.md layout) of a textured height field
seen from the paper's view angles: ground truth is analytic, so tests know the surface,
the cameras and which bands are noisy. Also writes ``truth/depth/<name>.npy`` (metres
along the optical axis) like the simulator. The tests at the bottom check the builder.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from brfgs.data.cameras import Intrinsics, paper_view_angles, pixel_rays, pose_from_view_angles, project_points
from brfgs.data.cube_io import write_envi


def height_m(x, y):
    """Height field [..] (m): a few smooth bumps on a gentle slope."""
    h = 0.02 * x - 0.01 * y
    for cx, cy, a, s in ((2.0, 1.0, 0.8, 1.5), (-3.0, -2.0, 0.6, 1.2), (-1.0, 3.0, 0.5, 1.0), (3.5, -3.0, 0.7, 1.3)):
        h = h + a * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    return h


def texture(x, y, seed=0):
    """Smooth random texture in [0, 1] (sum of sinusoids of 0.4–4 m wavelength)."""
    rng = np.random.default_rng(seed)
    f = np.zeros(np.broadcast(x, y).shape)
    for _ in range(48):
        lam = np.exp(rng.uniform(np.log(0.4), np.log(4.0)))
        th = rng.uniform(0, np.pi)
        ph = rng.uniform(0, 2 * np.pi)
        f += np.cos(2 * np.pi * (x * np.cos(th) + y * np.sin(th)) / lam + ph) * (lam / 4.0) ** 0.5
    return 1.0 / (1.0 + np.exp(-1.2 * f))


def spectra(wl_nm):
    """(vegetation, soil) reflectance spectra [B] each."""
    veg = 0.04 + 0.04 * np.exp(-((wl_nm - 550) / 40) ** 2) + 0.42 / (1 + np.exp(-(wl_nm - 715) / 15))
    soil = 0.08 + 0.25 * (wl_nm - 350) / 650
    return veg, soil


def sigma_profile(wl_nm, flat_sigma=0.002):
    """Dark noise σ_b: small in the middle, large at both ends of 350–1000 nm."""
    return flat_sigma + 0.06 * np.exp(-(wl_nm - 350) / 25) + 0.06 * np.exp((wl_nm - 1000) / 25)


def trace_heightfield(o, d, iters=40):
    """First intersection of rays with z = height_m(x, y) by fixed-point iteration. Returns t [..]."""
    t = (o[..., 2] - 0.0) / -d[..., 2]
    for _ in range(iters):
        p = o + t[..., None] * d
        t = (o[..., 2] - height_m(p[..., 0], p[..., 1])) / -d[..., 2]
    return t


def make_toy_scene(root, size=48, n_bands=12, n_views=13, distance_m=20.0, fov_deg=40.0, seed=0,
                   noise=True, flat=False, with_truth=True, poses=True, wl_range=(350.0, 1000.0)):
    """Write a toy scene to ``root`` and return ``root``.

    ``flat``: constant reflectance (no texture: nothing to match). ``poses``: write
    transform_matrix (else only view angles + distance_m, i.e. nominal poses).
    """
    root = Path(root)
    (root / "images").mkdir(parents=True, exist_ok=True)
    wl = np.linspace(*wl_range, n_bands)
    sigma = sigma_profile(wl)
    veg, soil = spectra(wl)
    intr = Intrinsics.from_fov(fov_deg, size, size)
    rng = np.random.default_rng(seed)
    frames = []
    for k, (vz, va) in enumerate(paper_view_angles(n_views)):
        name = f"v{k:03d}"
        c2w = pose_from_view_angles(vz, va, distance_m)
        o, d = pixel_rays(c2w, intr)
        t = trace_heightfield(o, d)
        p = o + t[..., None] * d
        a = np.zeros(p.shape[:2]) + 0.5 if flat else texture(p[..., 0], p[..., 1], seed)
        cube = a[..., None] * veg + (1 - a[..., None]) * soil  # [H, W, B]
        if noise:
            cube = cube + rng.normal(size=cube.shape) * sigma
        write_envi(root / "images" / f"{name}.hdr", cube.astype(np.float32), wl)
        fr = {"file_path": f"images/{name}.hdr", "view_zenith_deg": vz, "view_azimuth_deg": va}
        if poses:
            fr["transform_matrix"] = c2w.tolist()
        else:
            fr["distance_m"] = distance_m
        frames.append(fr)
        if with_truth:
            fwd = -c2w[:3, 2]
            depth = (t * (d @ fwd)).astype(np.float32)
            (root / "truth" / "depth").mkdir(parents=True, exist_ok=True)
            np.save(root / "truth" / "depth" / f"{name}.npy", depth)
    meta = {"camera_model": "PINHOLE", "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy,
            "w": size, "h": size, "wavelengths_nm": wl.tolist(), "sun_zenith_deg": 40.0,
            "sun_azimuth_deg": 150.0, "dark_sigma": sigma.tolist(), "frames": frames}
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))
    return root


# ----------------------------------------------------------------------------------- builder checks
def test_toy_scene_depth_lies_on_heightfield(tmp_path):
    from brfgs.data import read_scene

    root = make_toy_scene(tmp_path / "s", size=24, n_bands=4, n_views=13)
    scene = read_scene(root)
    i = 5
    depth = np.load(root / "truth" / "depth" / f"{scene.frames[i].name}.npy")
    o, d = pixel_rays(scene.frames[i].c2w, scene.intrinsics)
    fwd = -scene.frames[i].c2w[:3, 2]
    p = o + (depth / (d @ fwd))[..., None] * d
    assert np.abs(p[..., 2] - height_m(p[..., 0], p[..., 1])).max() < 1e-4
    uv, z = project_points(p.reshape(-1, 3), scene.frames[i].c2w, scene.intrinsics)
    j, k = np.meshgrid(np.arange(24) + 0.5, np.arange(24) + 0.5, indexing="ij")
    assert np.allclose(uv[:, 0], k.ravel(), atol=1e-6) and np.allclose(uv[:, 1], j.ravel(), atol=1e-6)
    assert np.allclose(z, depth.ravel(), atol=1e-4)
