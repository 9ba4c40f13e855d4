"""Mesh primitives and noise of the procedural scenes (pure numpy, deterministic from a generator).

Meshes are (vertices [V, 3] m, faces [F, 3] int) pairs with outward-facing (counter-clockwise)
winding; :func:`merge` concatenates them. Used by :mod:`brfgs.sim.geometry`.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["fbm", "grid_mesh", "random_unit", "facets", "points_in_ellipsoid", "points_in_cone", "box",
           "cylinder", "dome", "ellipse_disk", "merge"]


def fbm(rng: np.random.Generator, n: int, scales_px: tuple[float, ...], weights: tuple[float, ...],
        wrap: bool = True) -> np.ndarray:
    """Fractal noise [n, n], zero mean, unit std: a weighted sum of Gaussian-filtered white noise.

    Filtering is done in the Fourier domain, so the noise is periodic (tileable) for any ``wrap``.
    """
    out = np.zeros((n, n))
    for s, w in zip(scales_px, weights):
        spec = np.fft.rfft2(rng.standard_normal((n, n)))
        layer = np.fft.irfft2(ndimage.fourier_gaussian(spec, s, n=n), s=(n, n))
        out += w * layer / (layer.std() + 1e-12)
    out -= out.mean()
    return out / (out.std() + 1e-12)


def grid_mesh(x0: float, x1: float, y0: float, y1: float, nx: int, ny: int):
    """Regular grid: vertices [(ny+1)(nx+1), 2] (x, y) and faces [2·nx·ny, 3] counter-clockwise seen from +z."""
    xs = np.linspace(x0, x1, nx + 1)
    ys = np.linspace(y0, y1, ny + 1)
    X, Y = np.meshgrid(xs, ys)
    idx = np.arange((ny + 1) * (nx + 1)).reshape(ny + 1, nx + 1)
    a = idx[:-1, :-1].ravel()
    b = idx[:-1, 1:].ravel()
    c = idx[1:, 1:].ravel()
    d = idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return np.stack([X.ravel(), Y.ravel()], 1), faces


def random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    """Uniform random unit vectors [n, 3]."""
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def facets(rng: np.random.Generator, centres: np.ndarray, size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Equilateral triangles of side ``size_m`` at ``centres`` [n, 3] with uniformly random normals
    (spherical leaf-angle distribution). Returns vertices [3n, 3], faces [n, 3]."""
    n = len(centres)
    nrm = random_unit(rng, n)
    a = np.cross(nrm, random_unit(rng, n))
    a /= np.linalg.norm(a, axis=1, keepdims=True) + 1e-12
    b = np.cross(nrm, a)
    r = size_m / np.sqrt(3.0)  # circumradius
    v = np.stack([centres + r * a,
                  centres + r * (-0.5 * a + 0.8660254 * b),
                  centres + r * (-0.5 * a - 0.8660254 * b)], 1).reshape(-1, 3)
    return v, np.arange(3 * n).reshape(n, 3)


def points_in_ellipsoid(rng, n, centre, radii) -> np.ndarray:
    """n uniform points [n, 3] inside an axis-aligned ellipsoid."""
    d = random_unit(rng, n) * rng.random((n, 1)) ** (1.0 / 3.0)
    return np.asarray(centre) + d * np.asarray(radii)


def points_in_cone(rng, n, base_centre, radius, height) -> np.ndarray:
    """n uniform points [n, 3] inside an upright cone (apex at base_centre + height·z)."""
    # height fraction from the base with density ∝ (1 − h)² (cross-section area)
    h = 1.0 - rng.random(n) ** (1.0 / 3.0)
    r = radius * (1.0 - h) * np.sqrt(rng.random(n))
    phi = rng.random(n) * 2 * np.pi
    return np.asarray(base_centre) + np.stack([r * np.sin(phi), r * np.cos(phi), h * height], 1)


def box(centre, size, yaw_deg: float = 0.0, bottom: bool = False):
    """Box mesh with outward normals: centre (x, y, z_bottom), size (sx, sy, sz). Returns (V [8,3], F [10|12,3])."""
    sx, sy, sz = (0.5 * size[0], 0.5 * size[1], size[2])
    corners = np.array([[-sx, -sy, 0], [sx, -sy, 0], [sx, sy, 0], [-sx, sy, 0],
                        [-sx, -sy, sz], [sx, -sy, sz], [sx, sy, sz], [-sx, sy, sz]], float)
    t = np.deg2rad(yaw_deg)
    R = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    v = corners @ R.T + np.asarray(centre, float)
    f = [[4, 5, 6], [4, 6, 7],          # top
         [0, 1, 5], [0, 5, 4],          # -y side
         [1, 2, 6], [1, 6, 5],          # +x
         [2, 3, 7], [2, 7, 6],          # +y
         [3, 0, 4], [3, 4, 7]]          # -x
    if bottom:
        f += [[0, 2, 1], [0, 3, 2]]
    return v, np.array(f)


def cylinder(base, radius, height, n_seg: int = 8):
    """Open vertical cylinder (side only), outward normals. Returns (V, F)."""
    phi = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    ring = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.zeros(n_seg)], 1)
    v = np.concatenate([ring, ring + [0, 0, height]]) + np.asarray(base, float)
    i = np.arange(n_seg)
    j = (i + 1) % n_seg
    f = np.concatenate([np.stack([i, j, j + n_seg], 1), np.stack([i, j + n_seg, i + n_seg], 1)])
    return v, f


def dome(rng, centre, radius, height, bump_m: float = 0.08, n_lat: int = 10, n_lon: int = 20):
    """Bumpy upper half-ellipsoid (haystack) on the ground at ``centre``; outward normals. Returns (V, F)."""
    th = np.linspace(0, np.pi / 2, n_lat + 1)[1:]  # from the top ring down to the equator
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    r = 1.0 + bump_m / radius * rng.standard_normal(T.shape)
    pts = np.stack([radius * r * np.sin(T) * np.cos(P), radius * r * np.sin(T) * np.sin(P),
                    height * np.cos(T) * r], -1).reshape(-1, 3)
    top = np.array([[0.0, 0.0, height]])
    v = np.concatenate([top, pts]) + np.asarray(centre, float)
    faces = []
    for k in range(n_lon):  # cap
        faces.append([0, 1 + k, 1 + (k + 1) % n_lon])
    for i in range(n_lat - 1):
        for k in range(n_lon):
            a = 1 + i * n_lon + k
            b = 1 + i * n_lon + (k + 1) % n_lon
            c = 1 + (i + 1) * n_lon + (k + 1) % n_lon
            d = 1 + (i + 1) * n_lon + k
            faces += [[a, d, c], [a, c, b]]
    f = np.array(faces)
    # make the winding outward (normals away from the dome's axis)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    out = tri.mean(1) - (np.asarray(centre, float) + [0, 0, 0.3 * height])
    flip = (n * out).sum(1) < 0
    f[flip] = f[flip][:, [0, 2, 1]]
    return v, f


def ellipse_disk(centre, a, b, yaw_deg=0.0, n_seg: int = 48):
    """Flat ellipse (fan) facing +z. Returns (V, F)."""
    phi = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    t = np.deg2rad(yaw_deg)
    x = a * np.cos(phi)
    y = b * np.sin(phi)
    ring = np.stack([x * np.cos(t) - y * np.sin(t), x * np.sin(t) + y * np.cos(t), np.zeros(n_seg)], 1)
    v = np.concatenate([[[0.0, 0.0, 0.0]], ring]) + np.asarray(centre, float)
    i = np.arange(n_seg)
    f = np.stack([np.zeros(n_seg, int), 1 + i, 1 + (i + 1) % n_seg], 1)
    return v, f


def merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (V, F) meshes into one."""
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(np.asarray(f) + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)
