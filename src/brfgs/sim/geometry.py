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

from brfgs.sim.meshes import (box, cylinder, dome, ellipse_disk, facets, fbm, grid_mesh, merge,  # noqa: F401
                              points_in_cone, points_in_ellipsoid, random_unit)

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


@dataclass
class _Site:
    """Layout of the testsite: pond (ellipse, water level) and building (yard level), with the two
    coordinate maps the terrain shaping, labelling and object placement use."""

    pond_c: np.ndarray
    pond_a: float
    pond_b: float
    pond_yaw: float
    bld_c: np.ndarray
    bld_yaw: float
    water_z: float = 0.0
    yard_z: float = 0.0

    def pond_radius(self, px, py):
        """Elliptic radius around the pond (1 on its shore)."""
        t = np.deg2rad(self.pond_yaw)
        dx, dy = px - self.pond_c[0], py - self.pond_c[1]
        u = dx * np.cos(t) + dy * np.sin(t)
        w = -dx * np.sin(t) + dy * np.cos(t)
        return np.sqrt((u / self.pond_a) ** 2 + (w / self.pond_b) ** 2)

    def building_frame(self, px, py):
        """(along, across) coordinates (m) in the building's frame."""
        tb = np.deg2rad(self.bld_yaw)
        dx, dy = px - self.bld_c[0], py - self.bld_c[1]
        return dx * np.cos(tb) + dy * np.sin(tb), -dx * np.sin(tb) + dy * np.cos(tb)


def _shape_testsite_terrain(ter: _Terrain) -> tuple[_Site, np.ndarray, np.ndarray]:
    """Sink the pond, level the yard and flatten the road in ``ter``; returns the site and the yard and
    road face masks."""
    site = _Site(np.array([-16.0, -14.0]), 9.0, 6.0, 25.0, np.array([14.0, 12.0]), 20.0)
    x, y = ter.face_xy[:, 0], ter.face_xy[:, 1]
    # pond: ellipse, water level below the local ground
    site.water_z = water_z = ter.height_at(*site.pond_c) - 0.25
    dv = site.pond_radius(ter.xy[:, 0], ter.xy[:, 1])
    ter.z = np.where(dv < 1.02, water_z - 0.6, np.where(dv < 1.5, np.maximum(ter.z, water_z + 0.08), ter.z))
    # building on a concrete yard, asphalt road to the south edge
    site.yard_z = ter.height_at(*site.bld_c) + 0.05
    lu, lw = site.building_frame(ter.xy[:, 0], ter.xy[:, 1])
    in_yard_v = (np.abs(lu) < 15.5) & (np.abs(lw) < 12.5)
    ter.z = np.where(in_yard_v, site.yard_z, ter.z)
    fu, fw = site.building_frame(x, y)
    yard = (np.abs(fu) < 15.0) & (np.abs(fw) < 12.0)
    road = (np.abs(x - 26.0) < 2.5) & (y < 2.0)
    road_v = (np.abs(ter.xy[:, 0] - 26.0) < 3.0) & (ter.xy[:, 1] < 2.5)
    ter.z = np.where(road_v & ~in_yard_v, ter.z * 0.3 + 0.02, ter.z)
    return site, yard, road


def _label_testsite(rng, ter: _Terrain, site: _Site, yard: np.ndarray, road: np.ndarray) -> None:
    """Face materials: grass; bare soil in patches, the ploughed field (south-east) and the pond banks;
    concrete yard; asphalt road."""
    x, y = ter.face_xy[:, 0], ter.face_xy[:, 1]
    n_soil = fbm(rng, ter.n + 1, (12.0,), (1.0,))
    patch = n_soil.ravel()[np.minimum(((y + CORE_HALF_M) / CORE_SPACING_M).astype(int), ter.n) * (ter.n + 1)
                           + np.minimum(((x + CORE_HALF_M) / CORE_SPACING_M).astype(int), ter.n)] > 1.1
    ploughed = (x > 32.0) & (y < -6.0)
    ter.label[:] = "grass"
    ter.label[patch | ploughed] = "soil"
    ter.label[yard] = "concrete"
    ter.label[road & ~yard] = "asphalt"
    ter.label[site.pond_radius(x, y) < 1.25] = "soil"  # pond banks and bed


def _add_testsite_ground(g: SceneGeometry, ter: _Terrain, seed: int, tp: int) -> None:
    """Ground textures, terrain parts and the surroundings of the testsite."""
    g.textures["grass"] = _texture_maps([seed, 1, 101], tp, False, 0.85, 0.15, 0.18)
    g.textures["soil"] = _texture_maps([seed, 1, 102], tp, False, 0.55, 0.25, 0.15,
                                       furrow_period_px=tp / (2 * CORE_HALF_M / 1.5))
    g.textures["concrete"] = _texture_maps([seed, 1, 103], tp, False, 1.0, 0.0, 0.10)
    g.textures["asphalt"] = _texture_maps([seed, 1, 104], tp, False, 1.0, 0.0, 0.12)
    g.textures["field"] = _texture_maps([seed, 1, 105], 512, True, 0.80, 0.20, 0.18)
    g.parts += ter.parts({m: m for m in ("grass", "soil", "concrete", "asphalt")})
    g.parts.append(_surroundings("grass", "field"))


def _add_pond_and_building(g: SceneGeometry, site: _Site) -> None:
    """Pond water surface; building (concrete walls, flat bitumen roof); four cars with glossy
    clear-coat paint parked in front of it."""
    pond_c, pond_yaw, water_z = site.pond_c, site.pond_yaw, site.water_z
    v, f = ellipse_disk([pond_c[0], pond_c[1], water_z], site.pond_a * 1.04, site.pond_b * 1.04, pond_yaw)
    g.parts.append(MeshPart("pond", "water", v, f))
    g.objects.append({"type": "pond", "centre_m": [*pond_c.tolist(), water_z],
                      "semi_axes_m": [site.pond_a, site.pond_b], "yaw_deg": pond_yaw})
    bld_c, bld_yaw, yard_z = site.bld_c, site.bld_yaw, site.yard_z
    bsize = (14.0, 9.0, 6.0)
    v, f = box([bld_c[0], bld_c[1], yard_z], bsize, bld_yaw)
    g.parts.append(MeshPart("building_roof", "roof", v, f[:2]))
    g.parts.append(MeshPart("building_walls", "concrete_wall", v, f[2:]))
    g.objects.append({"type": "building", "centre_m": [*bld_c.tolist(), yard_z], "size_m": list(bsize),
                      "yaw_deg": bld_yaw})
    tb = np.deg2rad(bld_yaw)
    for k, col in enumerate(["red", "white", "blue", "silver"]):
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


def _add_trees(g: SceneGeometry, rng, crowns: list[dict], trunks: list, crown_part: tuple[str, str],
               facet_m: float, lad_m2_m3: float, shape: str) -> None:
    """Leaf-facet crowns (part ``crown_part`` = (name, material)), bark trunks and one object per tree."""
    v, f = _leaf_crowns(rng, crowns, facet_m=facet_m, lad_m2_m3=lad_m2_m3, shape=shape)
    g.parts.append(MeshPart(crown_part[0], crown_part[1], v, f))
    v, f = merge(trunks)
    g.parts.append(MeshPart("trunks", "bark", v, f))
    for c in crowns:
        if shape == "ellipsoid":
            g.objects.append({"type": "tree", "crown": "ellipsoid", "centre_m": [float(q) for q in c["centre"]],
                              "radii_m": [float(q) for q in c["radii"]], "n_facets": c["n_facets"]})
        else:
            g.objects.append({"type": "tree", "crown": "cone", "base_m": [float(q) for q in c["base"]],
                              "radius_m": float(c["radius"]), "height_m": float(c["height"]),
                              "n_facets": c["n_facets"]})


def _add_broadleaf_trees(g: SceneGeometry, rng, ter: _Terrain) -> list[tuple[float, float]]:
    """Broadleaf trees, a group in the north-west plus two isolated ones; returns their (x, y)."""
    crowns, trunks = [], []
    centres = [(-20.0 + 5.5 * i + rng.uniform(-1, 1), 14.0 + 5.0 * j + rng.uniform(-1, 1))
               for i in range(4) for j in range(3)] + [(5.0, -25.0), (-40.0, -30.0)]
    for cx, cy in centres:
        h = rng.uniform(8.0, 11.0)
        r = rng.uniform(2.4, 3.2)
        zg = ter.height_at(cx, cy)
        crowns.append({"centre": [cx, cy, zg + h - r * 1.1], "radii": [r, r, r * 1.1]})
        trunks.append(cylinder([cx, cy, zg - 0.2], 0.18, h - r * 1.1 + 0.2))
    _add_trees(g, rng, crowns, trunks, ("broadleaf_crowns", "broadleaf"), 0.32, 1.1, "ellipsoid")
    return centres


def _add_shrubs(g: SceneGeometry, rng, ter: _Terrain, n: int, allowed, r_range: tuple[float, float],
                z_frac: float, flat: float) -> None:
    """``n`` shrubs (ellipsoids of radius r in ``r_range``, centre z_frac·r above the ground, height
    flat·r) at uniform random places in the core where ``allowed(x, y)`` holds."""
    shrubs = []
    while len(shrubs) < n:
        sx, sy = rng.uniform(-55, 55, 2)
        if not allowed(sx, sy):
            continue
        r = rng.uniform(*r_range)
        shrubs.append({"centre": [sx, sy, ter.height_at(sx, sy) + z_frac * r], "radii": [r, r, flat * r]})
    v, f = _leaf_crowns(rng, shrubs, facet_m=0.22, lad_m2_m3=1.5, shape="ellipsoid")
    g.parts.append(MeshPart("shrubs", "shrub", v, f))
    for c in shrubs:
        g.objects.append({"type": "shrub", "centre_m": [float(q) for q in c["centre"]],
                          "radii_m": [float(q) for q in c["radii"]], "n_facets": c["n_facets"]})


def build_testsite(seed: int, texture_px: int = 512) -> SceneGeometry:
    """The ``testsite`` scene (module docstring), deterministic from ``seed``."""
    rng = np.random.default_rng([seed, 1])
    g = SceneGeometry("testsite")
    ter = _Terrain(rng, relief_m=0.35, hill_scale_px=40)
    site, yard, road = _shape_testsite_terrain(ter)
    _label_testsite(rng, ter, site, yard, road)
    _add_testsite_ground(g, ter, seed, texture_px)
    _add_pond_and_building(g, site)
    centres = _add_broadleaf_trees(g, rng, ter)

    def allowed(sx, sy):  # in the grass, away from the pond, yard, road, field and trees
        fu_, fw_ = site.building_frame(sx, sy)
        if site.pond_radius(sx, sy) < 1.6 or (abs(fu_) < 17 and abs(fw_) < 14) or abs(sx - 26) < 5 or \
                (sx > 30 and sy < -4):
            return False
        return not any((sx - cx) ** 2 + (sy - cy) ** 2 < 16 for cx, cy in centres)

    _add_shrubs(g, rng, ter, 30, allowed, (0.6, 1.1), 0.7, 0.8)
    return g


def build_forest(seed: int, texture_px: int = 512) -> SceneGeometry:
    """The ``forest`` scene (module docstring), deterministic from ``seed``."""
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
    _add_trees(g, rng, crowns, trunks, ("conifer_crowns", "needles"), 0.30, 1.3, "cone")
    _add_shrubs(g, rng, ter, 40, lambda sx, sy: not any((sx - cx) ** 2 + (sy - cy) ** 2 < 9 for cx, cy in pos),
                (0.5, 1.2), 0.6, 0.7)

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
