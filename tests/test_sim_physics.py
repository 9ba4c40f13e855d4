"""Physics of the Mitsuba scene simulator (brfgs.sim) on small presets.

Each test checks a physical property rather than pixels: radiometric normalisation on a
flat Lambertian field, sun glint of the pond, the canopy hotspot, the vegetation red edge,
the camera geometry of depth maps and of the rendered images, the custom leaf BSDF.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.cameras import pixel_rays
from brfgs.sim import SimConfig, render_views
from brfgs.sim import spectra as sp
from brfgs.sim.geometry import build_geometry
from brfgs.sim.materials import MATERIAL_IDS, VEGETATION, material

SUN_Z, SUN_A = 38.0, 150.0


def _object(scene: str, kind: str, seed: int = 0) -> list[dict]:
    return [o for o in build_geometry(scene, seed, 64).objects if o["type"] == kind]


def _band_indices(cfg: SimConfig, wavelengths) -> list[int]:
    wl = cfg.wavelengths_nm()
    return [int(np.argmin(np.abs(wl - w))) for w in wavelengths]


def test_flat_field_reflectance_equals_lambertian_spectrum():
    """Limit case: a flat Lambertian field's apparent reflectance π·L/E_down is its reflectance,
    in every band and every view (checks the sun/sky normalisation and the band packing)."""
    cfg = SimConfig.tiny("flat", bands=7, spp=16)
    out = render_views(cfg, [(0.0, 0.0), (58.0, 90.0), (38.0, SUN_A + 180.0)], size=24)
    ref = sp.band_average(material("soil_plain").end1, cfg.wavelengths_nm(), cfg.fwhm_array_nm())  # [B]
    mean = out["reflectance"].mean(axis=(1, 2))  # [V, B]
    np.testing.assert_allclose(mean / ref, 1.0, atol=0.03)
    assert (out["material"] == MATERIAL_IDS["soil_plain"]).all()


def test_depth_maps_match_camera_geometry_for_ground_plane():
    """Depth (m along the optical axis) of a flat ground z = 0 equals the analytic ray-plane distance."""
    cfg = SimConfig.tiny("flat", bands=1, spp=1)
    views = [(0.0, 0.0), (23.0, 210.0), (58.0, 300.0)]
    out = render_views(cfg, views, size=20)
    for v, c2w in enumerate(out["c2w"]):
        o, d = pixel_rays(c2w, out["intrinsics"])  # [H, W, 3]
        t = -o[..., 2] / d[..., 2]
        expected = t * (d @ -c2w[:3, 2])
        np.testing.assert_allclose(out["depth"][v], expected, rtol=2e-4)
    # nadir: every pixel's depth is the flying height
    np.testing.assert_allclose(out["depth"][0], cfg.distance_m, rtol=1e-5)


def test_testsite_ground_depth_agrees_with_camera_geometry():
    """Terrain pixels lie within the terrain's relief (< 1.5 m) of the plane z = 0."""
    cfg = SimConfig.tiny("testsite", bands=1, spp=1)
    out = render_views(cfg, [(38.0, 0.0)], size=32)
    c2w = out["c2w"][0]
    o, d = pixel_rays(c2w, out["intrinsics"])
    forward = -c2w[:3, 2]
    t = out["depth"][0] / (d @ forward)  # ray distance
    z = o[..., 2] + t * d[..., 2]  # height of the hit point
    ground = np.isin(out["material"][0], [MATERIAL_IDS[m] for m in ("grass", "soil", "asphalt")])
    assert ground.mean() > 0.5
    assert np.abs(z[ground]).max() < 1.5


def test_rendered_image_is_aligned_with_camera_convention():
    """Mitsuba's image and the ray-cast material map (brfgs pixel_rays) agree pixel by pixel
    in an oblique view: the dark bitumen roof and the bright concrete yard fall where the
    cameras of docs/data-format.md put them (a flip or offset would mix them)."""
    cfg = SimConfig.tiny("testsite", bands=1, spp=16, wavelength_min_nm=650, wavelength_max_nm=651)
    bld = _object("testsite", "building")[0]
    out = render_views(cfg, [(38.0, 240.0)], size=48, target_m=np.array(bld["centre_m"]))
    img = out["reflectance"][0, ..., 0]
    mat = out["material"][0]
    from scipy import ndimage

    roof = ndimage.binary_erosion(mat == MATERIAL_IDS["roof"], iterations=1)
    yard = ndimage.binary_erosion(mat == MATERIAL_IDS["concrete"], iterations=1)
    assert roof.sum() >= 10 and yard.sum() >= 10
    ref_roof = sp.band_average(sp.bitumen_roof(), [650.0], [4.0])[0]
    assert np.median(img[roof]) < 1.6 * ref_roof
    assert np.median(img[yard]) > 2.5 * np.median(img[roof])


def test_pond_sun_glint_specular_vs_backscatter():
    """The rough water surface reflects the sun: near the specular direction the pond is several
    times brighter than in the backscatter direction (NIR, where the water body is black)."""
    cfg = SimConfig.tiny("testsite", bands=2, spp=16, wavelength_min_nm=550, wavelength_max_nm=850)
    pond = _object("testsite", "pond")[0]
    out = render_views(cfg, [(SUN_Z, SUN_A + 180.0), (SUN_Z, SUN_A)], size=32,
                       target_m=np.array(pond["centre_m"]))
    water = out["material"] == MATERIAL_IDS["water"]  # [2, H, W]
    assert water[0].sum() > 30 and water[1].sum() > 30
    spec = out["reflectance"][0][water[0]].mean(0)  # [2 bands]
    back = out["reflectance"][1][water[1]].mean(0)
    assert spec[1] > 4.0 * back[1], (spec, back)
    assert spec[0] > 2.0 * back[0], (spec, back)


@pytest.mark.parametrize("scene,kind,leaf", [("testsite", "tree", "broadleaf"), ("forest", "tree", "needles")])
def test_canopy_hotspot(scene, kind, leaf):
    """Shadow hiding: crowns of leaf facets are brighter looking along the sun (hotspot, φ = 0)
    than at the same zenith on the forward-scatter side (φ = 180°)."""
    cfg = SimConfig.tiny(scene, bands=2, spp=16, wavelength_min_nm=650, wavelength_max_nm=850)
    trees = _object(scene, kind)
    centre = np.mean([t.get("centre_m", t.get("base_m")) for t in trees], axis=0)
    centre[2] = 0.0
    out = render_views(cfg, [(SUN_Z, SUN_A), (SUN_Z, SUN_A + 180.0)], size=32, target_m=centre)
    canopy = out["material"] == MATERIAL_IDS[leaf]
    assert canopy[0].sum() > 40 and canopy[1].sum() > 40
    hot = out["reflectance"][0][canopy[0]].mean(0)
    fwd = out["reflectance"][1][canopy[1]].mean(0)
    assert (hot > 1.15 * fwd).all(), (hot, fwd)


def test_vegetation_red_edge():
    """Vegetation: NIR (850 nm) reflectance is many times the red (650 nm); soil and concrete are not."""
    cfg = SimConfig.tiny("testsite", spp=16, bands=2, wavelength_min_nm=650, wavelength_max_nm=850)
    out = render_views(cfg, [(0.0, 0.0)], size=48)
    refl, mat = out["reflectance"][0], out["material"][0]
    for name in ("grass", "broadleaf", "shrub"):
        sel = mat == MATERIAL_IDS[name]
        if sel.sum() < 5:
            continue
        red, nir = refl[sel].mean(0)
        assert nir > 5.0 * red, (name, red, nir)
    for name in ("soil", "concrete"):
        sel = mat == MATERIAL_IDS[name]
        red, nir = refl[sel].mean(0)
        assert nir < 2.0 * red, (name, red, nir)
    assert set(VEGETATION) >= {"grass", "broadleaf"}


def test_leaf_bsdf_matches_lambertian_reflection_transmission():
    """The Python leaf BSDF: eval = R/π·|cos θo| (same side) or T/π·|cos θo| (other side),
    sample weights = eval / pdf, and its albedo (mean weight) = R + T."""
    from brfgs.sim.render import setup_mitsuba

    mi = setup_mitsuba()
    import drjit as dr

    bsdf = mi.load_dict({"type": "brfgs_leaf"})
    p = mi.traverse(bsdf)
    R = np.array([0.05, 0.45, 0.30])
    T = np.array([0.02, 0.40, 0.10])
    p["reflectance"] = mi.Color3f(*[float(v) for v in R])
    p["transmittance"] = mi.Color3f(*[float(v) for v in T])
    p.update()
    rng = np.random.default_rng(0)
    n = 20000
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    wi = rng.standard_normal((n, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    si.wi = mi.Vector3f(*[mi.Float(wi[:, k].astype(np.float32)) for k in range(3)])
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n).astype(np.float32)),
                             mi.Point2f(*[mi.Float(rng.random(n).astype(np.float32)) for _ in range(2)]))
    w = np.stack([np.asarray(weight[k]) for k in range(3)], 1)  # [n, 3]
    # albedo: E[weight] = R + T for every incident direction
    np.testing.assert_allclose(w.mean(0), R + T, rtol=0.03)
    # eval/pdf consistency at the sampled directions
    val = bsdf.eval(ctx, si, bs.wo)
    pdf = np.asarray(bsdf.pdf(ctx, si, bs.wo))
    ev = np.stack([np.asarray(val[k]) for k in range(3)], 1)
    np.testing.assert_allclose(ev / pdf[:, None], w, rtol=1e-4, atol=1e-6)
    # analytic value
    wo = np.stack([np.asarray(bs.wo[k]) for k in range(3)], 1)
    same = wi[:, 2] * wo[:, 2] > 0
    expected = np.where(same[:, None], R, T) / math.pi * np.abs(wo[:, 2:3])
    np.testing.assert_allclose(ev, expected, rtol=1e-4, atol=1e-7)


def test_sigma_b_shape_of_a_snapshot_imager():
    """σ_b is high below ~420 nm and above ~920 nm and low in 500–850 nm."""
    wl = np.arange(350.0, 1001.0, 2.0)
    s = sp.dark_sigma(wl)
    mid = s[(wl >= 500) & (wl <= 850)]
    assert mid.max() < 0.005
    assert s[wl <= 400].min() > 3 * mid.max()
    assert s[wl >= 980].min() > 3 * mid.max()
    assert s[np.argmin(np.abs(wl - 420))] > 1.5 * mid.min()
    assert s[np.argmin(np.abs(wl - 920))] > 1.5 * mid.min()


def test_building_shadow_falls_away_from_the_sun():
    """The directional sun comes from (θ_s, φ_s) of docs/data-format.md: the yard just beyond the
    building on the anti-sun side is in shadow, the yard on the sun side is lit."""
    from brfgs.data.cameras import project_points

    cfg = SimConfig.tiny("testsite", bands=1, spp=16, wavelength_min_nm=650, wavelength_max_nm=651)
    bld = _object("testsite", "building")[0]
    centre = np.array(bld["centre_m"])
    out = render_views(cfg, [(0.0, 0.0)], size=64, target_m=centre)
    horiz = direction_from_angles_deg(90.0, SUN_A)  # horizontal unit vector toward the sun
    pts = np.stack([centre + 6.5 * horiz, centre - 6.5 * horiz]) + [0, 0, 0.05]
    uv, _ = project_points(pts, out["c2w"][0], out["intrinsics"])
    cols, rows = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    mat = out["material"][0][rows, cols]
    assert (mat == MATERIAL_IDS["concrete"]).all(), mat
    lit, shade = out["reflectance"][0, rows, cols, 0]
    assert shade < 0.5 * lit, (lit, shade)
    assert out["sun_visibility"][0][rows, cols].tolist() == [1, 0]  # the shadow truth agrees


@pytest.mark.parametrize("sun", [(38.0, 150.0), (55.0, 220.0)])
def test_sun_visibility_truth_agrees_with_the_rendered_light(sun):
    """The direct-sun visibility truth (a geometric ray test toward the sun) against the path-traced
    image, an independent computation: on each ground material, the pixels it calls shadowed are far
    darker than those it calls lit; the flat field has no shadow at all."""
    cfg = SimConfig.tiny("testsite", bands=1, spp=16, wavelength_min_nm=650, wavelength_max_nm=651,
                         sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1])
    out = render_views(cfg, [(0.0, 0.0), (38.0, 60.0)], size=64)
    vis, mat, refl = out["sun_visibility"], out["material"], out["reflectance"][..., 0]
    assert set(np.unique(vis)) <= {0, 1, 255} and ((vis == 255) == (mat == 0)).all()
    checked = 0
    for name in ("grass", "soil", "concrete", "asphalt"):
        on = mat == MATERIAL_IDS[name]
        lit, shade = refl[on & (vis == 1)], refl[on & (vis == 0)]
        if min(lit.size, shade.size) >= 15:
            assert np.median(shade) < 0.6 * np.median(lit), (name, np.median(shade), np.median(lit))
            checked += 1
    assert checked >= 2
    flat = render_views(SimConfig.tiny("flat", bands=1, spp=1, sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1]),
                        [(0.0, 0.0), (58.0, 300.0)], size=20)
    assert (flat["sun_visibility"] == 1).all()
