"""Procedural geometry of the simulated scenes (pure numpy, deterministic from a seed).

A scene is a list of :class:`MeshPart` (triangles in ENU metres, z up, outward-facing
winding) tagged with a material name, plus per-material texture maps and a list of
objects (trees, building, vehicles, ...) for truth/scene.json. Nothing here imports
Mitsuba; :mod:`brfgs.sim.render` turns the parts into a Mitsuba scene.

Scenes
------
``testsite``
    Gently undulating terrain (0.5 m mesh with fBm displacement) of grass with bare-soil
    patches, a ploughed bare-soil field with furrows, a concrete yard and an asphalt road;
    a group of broadleaf trees whose crowns are thousands of small leaf facets (spherical
    leaf-angle distribution); isolated shrubs; a pond (rough dielectric water surface);
    a flat-roofed building; four cars with glossy clear-coat paint.
``forest``
    Hilly dry-grass terrain with soil patches, a stand of conifer-like trees (conical
    crowns of needle-cluster facets), shrubs and haystacks.
``flat``
    A flat, untextured Lambertian field of the prosail dry soil: a radiometric limit case
    (its apparent reflectance must equal the soil spectrum in every view).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

SCENES = ("testsite", "forest", "flat")

CORE_HALF_M = 60.0     # detailed terrain covers [-60, 60]² m
CORE_SPACING_M = 0.5   # terrain mesh spacing
OUTER_HALF_M = 2000.0  # flat surroundings out to ±2 km: every view ray and sky path ends on the ground
OUTER_TILE_M = 400.0   # period of the surroundings' (tileable) texture: no repeat within view


@dataclass
class MeshPart:
    """Triangles of one material: vertices [V, 3] (m), faces [F, 3] (int), optional uv [V, 2]."""

    name: str
    material: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    texture: str | None = None   # key into SceneGeometry.textures (None: uniform material)


@dataclass
class Texture:
    """Reflectance map ``brightness · (mix · end1 + (1 − mix) · end2)`` of a textured material.

    brightness, mix: [T, T] float32 maps (row = +v, col = +u); ``wrap``: repeat (tileable) or clamp.
    """

    brightness: np.ndarray
    mix: np.ndarray
    wrap: str = "clamp"


@dataclass
class SceneGeometry:
    """All geometry of a scene plus its texture maps and object list."""

    name: str
    parts: list[MeshPart] = field(default_factory=list)
    textures: dict[str, Texture] = field(default_factory=dict)
    objects: list[dict] = field(default_factory=list)

    def n_triangles(self) -> int:
        return int(sum(len(p.faces) for p in self.parts))


# ----------------------------------------------------------------------------------------
# noise and primitive builders


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


# ----------------------------------------------------------------------------------------
# terrain


class _Terrain:
    """Heightfield over the core square with a face-label map; builds per-material parts."""

    def __init__(self, rng, relief_m: float, hill_scale_px: float):
        n = int(round(2 * CORE_HALF_M / CORE_SPACING_M))
        self.n = n
        xy, self.faces = grid_mesh(-CORE_HALF_M, CORE_HALF_M, -CORE_HALF_M, CORE_HALF_M, n, n)
        self.xy = xy
        hills = fbm(rng, n + 1, (hill_scale_px, hill_scale_px / 3), (1.0, 0.3)).ravel()
        micro = rng.standard_normal(len(xy)) * 0.03  # 3 cm per-vertex roughness (mesh displacement)
        # fade to z = 0 at the core's border so the surroundings join without a step
        edge = np.clip((CORE_HALF_M - np.abs(xy).max(1)) / 10.0, 0.0, 1.0)
        self.z = relief_m * hills * edge + micro * edge
        cen = self.xy[self.faces].mean(1)
        self.face_xy = cen  # [F, 2]
        self.label = np.full(len(self.faces), "", dtype=object)

    def height_at(self, x: float, y: float) -> float:
        """Terrain height (m) at the nearest vertex."""
        i = int(round((y + CORE_HALF_M) / CORE_SPACING_M))
        j = int(round((x + CORE_HALF_M) / CORE_SPACING_M))
        i = min(max(i, 0), self.n)
        j = min(max(j, 0), self.n)
        return float(self.z[i * (self.n + 1) + j])

    def parts(self, texture_of: dict[str, str]) -> list[MeshPart]:
        verts = np.concatenate([self.xy, self.z[:, None]], 1)
        uv = (self.xy + CORE_HALF_M) / (2 * CORE_HALF_M)
        out = []
        for mat in sorted(set(self.label)):
            sel = self.faces[self.label == mat]
            used = np.unique(sel)
            remap = np.full(len(verts), -1)
            remap[used] = np.arange(len(used))
            out.append(MeshPart(f"terrain_{mat}", mat, verts[used], remap[sel], uv[used], texture_of.get(mat)))
        return out


def _surroundings(material: str, texture: str) -> MeshPart:
    """Flat ring of ground from the core's border out to ±OUTER_HALF_M (8 quads), tiled texture."""
    c, o = CORE_HALF_M, OUTER_HALF_M
    rects = [(-o, -c, -o, -c), (-c, c, -o, -c), (c, o, -o, -c), (-o, -c, -c, c), (c, o, -c, c),
             (-o, -c, c, o), (-c, c, c, o), (c, o, c, o)]
    parts = []
    for x0, x1, y0, y1 in rects:
        # subdivide near the core so the tiled texture's uv interpolation stays exact (it is linear anyway)
        xy, f = grid_mesh(x0, x1, y0, y1, 1, 1)
        parts.append((np.concatenate([xy, np.zeros((len(xy), 1))], 1), f))
    v, f = merge(parts)
    uv = v[:, :2] / OUTER_TILE_M
    return MeshPart("surroundings", material, v, f, uv, texture)


def _texture_maps(seed_key: list[int], n: int, wrap: bool, mix_mean: float, mix_contrast: float, bright_contrast: float,
                  furrow_period_px: float | None = None) -> Texture:
    """Brightness and mix maps for a textured ground material (fBm at 3 scales, optional furrows).

    Each texture draws from its own random stream ``seed_key``, so the texture resolution never
    changes the rest of the scene.
    """
    rng = np.random.default_rng(seed_key)
    b = fbm(rng, n, (n / 24, n / 64, 1.2), (1.0, 0.8, 0.5), wrap=wrap)
    m = fbm(rng, n, (n / 16, n / 48, 2.0), (1.0, 0.6, 0.3), wrap=wrap)
    bright = 1.0 + bright_contrast * b
    if furrow_period_px:
        rows = np.arange(n)[:, None]
        bright = bright * (1.0 + 0.25 * np.sin(2 * np.pi * rows / furrow_period_px))
    mix = np.clip(mix_mean + mix_contrast * m, 0.0, 1.0)
    return Texture(np.clip(bright, 0.3, 1.8).astype(np.float32), mix.astype(np.float32), "repeat" if wrap else "clamp")


# ----------------------------------------------------------------------------------------
# scenes


def _leaf_crowns(rng, crowns: list[dict], facet_m: float, lad_m2_m3: float, shape: str):
    """Leaf facets of all crowns merged. crowns: dicts with centre, radii (ellipsoid) or base/radius/height (cone)."""
    area = np.sqrt(3) / 4 * facet_m ** 2
    meshes = []
    for c in crowns:
        if shape == "ellipsoid":
            vol = 4.0 / 3.0 * np.pi * np.prod(c["radii"])
            n = int(lad_m2_m3 * vol / area)
            pts = points_in_ellipsoid(rng, n, c["centre"], c["radii"])
        else:
            vol = np.pi * c["radius"] ** 2 * c["height"] / 3.0
            n = int(lad_m2_m3 * vol / area)
            pts = points_in_cone(rng, n, c["base"], c["radius"], c["height"])
        c["n_facets"] = n
        meshes.append(facets(rng, pts, facet_m))
    return merge(meshes)


def build_testsite(seed: int, texture_px: int = 512) -> SceneGeometry:
    rng = np.random.default_rng([seed, 1])
    g = SceneGeometry("testsite")
    ter = _Terrain(rng, relief_m=0.35, hill_scale_px=40)
    x, y = ter.face_xy[:, 0], ter.face_xy[:, 1]

    # pond: ellipse, water level below the local ground
    pond_c = np.array([-16.0, -14.0])
    pond_a, pond_b, pond_yaw = 9.0, 6.0, 25.0
    t = np.deg2rad(pond_yaw)
    def ell(px, py):
        dx, dy = px - pond_c[0], py - pond_c[1]
        u = dx * np.cos(t) + dy * np.sin(t)
        w = -dx * np.sin(t) + dy * np.cos(t)
        return np.sqrt((u / pond_a) ** 2 + (w / pond_b) ** 2)
    water_z = ter.height_at(*pond_c) - 0.25
    dv = ell(ter.xy[:, 0], ter.xy[:, 1])
    ter.z = np.where(dv < 1.02, water_z - 0.6, np.where(dv < 1.5, np.maximum(ter.z, water_z + 0.08), ter.z))

    # building on a concrete yard, asphalt road to the south edge
    bld_c = np.array([14.0, 12.0])
    bld_yaw = 20.0
    yard_z = ter.height_at(*bld_c) + 0.05
    tb = np.deg2rad(bld_yaw)
    def local(px, py, c):
        dx, dy = px - c[0], py - c[1]
        return dx * np.cos(tb) + dy * np.sin(tb), -dx * np.sin(tb) + dy * np.cos(tb)
    lu, lw = local(ter.xy[:, 0], ter.xy[:, 1], bld_c)
    in_yard_v = (np.abs(lu) < 15.5) & (np.abs(lw) < 12.5)
    ter.z = np.where(in_yard_v, yard_z, ter.z)
    fu, fw = local(x, y, bld_c)
    yard = (np.abs(fu) < 15.0) & (np.abs(fw) < 12.0)
    road = (np.abs(x - 26.0) < 2.5) & (y < 2.0)
    road_v = (np.abs(ter.xy[:, 0] - 26.0) < 3.0) & (ter.xy[:, 1] < 2.5)
    ter.z = np.where(road_v & ~in_yard_v, ter.z * 0.3 + 0.02, ter.z)

    # ploughed field (bare soil) in the south-east, bare patches in the grass elsewhere
    n_soil = fbm(rng, ter.n + 1, (12.0,), (1.0,))
    patch = n_soil.ravel()[np.minimum(((y + CORE_HALF_M) / CORE_SPACING_M).astype(int), ter.n) * (ter.n + 1)
                           + np.minimum(((x + CORE_HALF_M) / CORE_SPACING_M).astype(int), ter.n)] > 1.1
    field = (x > 32.0) & (y < -6.0)
    ter.label[:] = "grass"
    ter.label[patch | field] = "soil"
    ter.label[yard] = "concrete"
    ter.label[road & ~yard] = "asphalt"
    ter.label[ell(x, y) < 1.25] = "soil"  # pond banks and bed

    tp = texture_px
    g.textures["grass"] = _texture_maps([seed, 1, 101], tp, False, 0.85, 0.15, 0.18)
    g.textures["soil"] = _texture_maps([seed, 1, 102], tp, False, 0.55, 0.25, 0.15,
                                       furrow_period_px=tp / (2 * CORE_HALF_M / 1.5))
    g.textures["concrete"] = _texture_maps([seed, 1, 103], tp, False, 1.0, 0.0, 0.10)
    g.textures["asphalt"] = _texture_maps([seed, 1, 104], tp, False, 1.0, 0.0, 0.12)
    g.textures["field"] = _texture_maps([seed, 1, 105], 512, True, 0.80, 0.20, 0.18)
    g.parts += ter.parts({m: m for m in ("grass", "soil", "concrete", "asphalt")})
    g.parts.append(_surroundings("grass", "field"))

    # pond water surface
    v, f = ellipse_disk([pond_c[0], pond_c[1], water_z], pond_a * 1.04, pond_b * 1.04, pond_yaw)
    g.parts.append(MeshPart("pond", "water", v, f))
    g.objects.append({"type": "pond", "centre_m": [*pond_c.tolist(), water_z], "semi_axes_m": [pond_a, pond_b],
                      "yaw_deg": pond_yaw})

    # building: walls of concrete, flat bitumen roof
    bsize = (14.0, 9.0, 6.0)
    v, f = box([bld_c[0], bld_c[1], yard_z], bsize, bld_yaw)
    g.parts.append(MeshPart("building_roof", "roof", v, f[:2]))
    g.parts.append(MeshPart("building_walls", "concrete_wall", v, f[2:]))
    g.objects.append({"type": "building", "centre_m": [*bld_c.tolist(), yard_z], "size_m": list(bsize),
                      "yaw_deg": bld_yaw})

    # cars parked in front of the building (glossy clear-coat paint)
    colours = ["red", "white", "blue", "silver"]
    for k, col in enumerate(colours):
        cu, cw = -8.0 + 4.2 * k, -9.0
        cx = bld_c[0] + cu * np.cos(tb) - cw * np.sin(tb)
        cy = bld_c[1] + cu * np.sin(tb) + cw * np.cos(tb)
        yaw = bld_yaw + 90.0
        body = box([cx, cy, yard_z + 0.25], (4.5, 1.8, 0.75), yaw)
        cab = box([cx, cy, yard_z + 1.0], (2.4, 1.6, 0.55), yaw)
        v, f = merge([body, cab])
        g.parts.append(MeshPart(f"car_{k}", f"paint_{col}", v, f))
        g.objects.append({"type": "vehicle", "paint": col, "centre_m": [float(cx), float(cy), yard_z],
                          "yaw_deg": yaw})

    # broadleaf trees: a group in the north-west plus two isolated ones
    crowns, trunks = [], []
    centres = [(-20.0 + 5.5 * i + rng.uniform(-1, 1), 14.0 + 5.0 * j + rng.uniform(-1, 1))
               for i in range(4) for j in range(3)] + [(5.0, -25.0), (-40.0, -30.0)]
    for cx, cy in centres:
        h = rng.uniform(8.0, 11.0)
        r = rng.uniform(2.4, 3.2)
        zg = ter.height_at(cx, cy)
        crowns.append({"centre": [cx, cy, zg + h - r * 1.1], "radii": [r, r, r * 1.1]})
        trunks.append(cylinder([cx, cy, zg - 0.2], 0.18, h - r * 1.1 + 0.2))
    v, f = _leaf_crowns(rng, crowns, facet_m=0.32, lad_m2_m3=1.1, shape="ellipsoid")
    g.parts.append(MeshPart("broadleaf_crowns", "broadleaf", v, f))
    v, f = merge(trunks)
    g.parts.append(MeshPart("trunks", "bark", v, f))
    for c in crowns:
        g.objects.append({"type": "tree", "crown": "ellipsoid", "centre_m": [float(q) for q in c["centre"]],
                          "radii_m": [float(q) for q in c["radii"]], "n_facets": c["n_facets"]})

    # shrubs scattered in the grass, away from the pond, yard and road
    shrubs = []
    while len(shrubs) < 30:
        sx, sy = rng.uniform(-55, 55, 2)
        fu_, fw_ = local(sx, sy, bld_c)
        if ell(sx, sy) < 1.6 or (abs(fu_) < 17 and abs(fw_) < 14) or abs(sx - 26) < 5 or (sx > 30 and sy < -4):
            continue
        if any((sx - cx) ** 2 + (sy - cy) ** 2 < 16 for cx, cy in centres):
            continue
        r = rng.uniform(0.6, 1.1)
        shrubs.append({"centre": [sx, sy, ter.height_at(sx, sy) + 0.7 * r], "radii": [r, r, 0.8 * r]})
    v, f = _leaf_crowns(rng, shrubs, facet_m=0.22, lad_m2_m3=1.5, shape="ellipsoid")
    g.parts.append(MeshPart("shrubs", "shrub", v, f))
    for c in shrubs:
        g.objects.append({"type": "shrub", "centre_m": [float(q) for q in c["centre"]],
                          "radii_m": [float(q) for q in c["radii"]], "n_facets": c["n_facets"]})
    return g


def build_forest(seed: int, texture_px: int = 512) -> SceneGeometry:
    rng = np.random.default_rng([seed, 2])
    g = SceneGeometry("forest")
    ter = _Terrain(rng, relief_m=1.2, hill_scale_px=60)
    x, y = ter.face_xy[:, 0], ter.face_xy[:, 1]
    ter.label[:] = "dry_grass"
    n_soil = fbm(rng, ter.n + 1, (8.0,), (1.0,)).ravel()
    iy = np.minimum(((y + CORE_HALF_M) / CORE_SPACING_M).astype(int), ter.n)
    ix = np.minimum(((x + CORE_HALF_M) / CORE_SPACING_M).astype(int), ter.n)
    ter.label[n_soil[iy * (ter.n + 1) + ix] > 1.3] = "soil"
    tp = texture_px
    g.textures["dry_grass"] = _texture_maps([seed, 2, 101], tp, False, 0.8, 0.2, 0.18)
    g.textures["soil"] = _texture_maps([seed, 2, 102], tp, False, 0.6, 0.2, 0.15)
    g.textures["field"] = _texture_maps([seed, 2, 105], 512, True, 0.75, 0.2, 0.18)
    g.parts += ter.parts({"dry_grass": "dry_grass", "soil": "soil"})
    g.parts.append(_surroundings("dry_grass", "field"))

    # conifer stand: jittered grid over the west and north, plus scattered trees
    crowns, trunks, pos = [], [], []
    for gx in np.arange(-52.0, 12.0, 6.5):
        for gy in np.arange(-50.0, 54.0, 6.5):
            if rng.random() < 0.25:
                continue
            pos.append((gx + rng.uniform(-1.8, 1.8), gy + rng.uniform(-1.8, 1.8)))
    for _ in range(10):
        pos.append((rng.uniform(15, 55), rng.uniform(-55, 55)))
    for cx, cy in pos:
        h = rng.uniform(9.0, 15.0)
        base_h = rng.uniform(0.2, 0.35) * h
        r = rng.uniform(0.18, 0.24) * h
        zg = ter.height_at(cx, cy)
        crowns.append({"base": [cx, cy, zg + base_h], "radius": r, "height": h - base_h})
        trunks.append(cylinder([cx, cy, zg - 0.2], 0.15, base_h + 0.5, 6))
    v, f = _leaf_crowns(rng, crowns, facet_m=0.30, lad_m2_m3=1.3, shape="cone")
    g.parts.append(MeshPart("conifer_crowns", "needles", v, f))
    v, f = merge(trunks)
    g.parts.append(MeshPart("trunks", "bark", v, f))
    for c in crowns:
        g.objects.append({"type": "tree", "crown": "cone", "base_m": [float(q) for q in c["base"]],
                          "radius_m": float(c["radius"]), "height_m": float(c["height"]), "n_facets": c["n_facets"]})

    shrubs = []
    while len(shrubs) < 40:
        sx, sy = rng.uniform(-55, 55, 2)
        if any((sx - cx) ** 2 + (sy - cy) ** 2 < 9 for cx, cy in pos):
            continue
        r = rng.uniform(0.5, 1.2)
        shrubs.append({"centre": [sx, sy, ter.height_at(sx, sy) + 0.6 * r], "radii": [r, r, 0.7 * r]})
    v, f = _leaf_crowns(rng, shrubs, facet_m=0.22, lad_m2_m3=1.5, shape="ellipsoid")
    g.parts.append(MeshPart("shrubs", "shrub", v, f))
    for c in shrubs:
        g.objects.append({"type": "shrub", "centre_m": [float(q) for q in c["centre"]],
                          "radii_m": [float(q) for q in c["radii"]], "n_facets": c["n_facets"]})

    stacks = []
    for hx, hy in [(30.0, 10.0), (36.0, 4.0), (28.0, -20.0)]:
        zg = ter.height_at(hx, hy)
        stacks.append(dome(rng, [hx, hy, zg - 0.1], 2.2, 2.8))
        g.objects.append({"type": "haystack", "centre_m": [hx, hy, zg], "radius_m": 2.2, "height_m": 2.8})
    v, f = merge(stacks)
    g.parts.append(MeshPart("haystacks", "straw", v, f))
    return g


def build_flat(seed: int, texture_px: int = 512) -> SceneGeometry:
    g = SceneGeometry("flat")
    xy, f = grid_mesh(-OUTER_HALF_M, OUTER_HALF_M, -OUTER_HALF_M, OUTER_HALF_M, 1, 1)
    v = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    g.parts.append(MeshPart("ground", "soil_plain", v, f))
    g.objects.append({"type": "plane", "z_m": 0.0})
    return g


def build_geometry(scene: str, seed: int, texture_px: int = 512) -> SceneGeometry:
    """Geometry of scene ``scene`` (one of SCENES), deterministic from ``seed``."""
    return {"testsite": build_testsite, "forest": build_forest, "flat": build_flat}[scene](seed, texture_px)
