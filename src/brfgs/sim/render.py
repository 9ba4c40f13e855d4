"""Mitsuba 3 rendering of the simulated scenes, three spectral bands per pass.

Why three bands per pass: Mitsuba's ``*_rgb`` variants carry three independent colour
channels along every path; nothing couples the channels except sampling decisions
(Russian roulette), which stay unbiased. Loading three *sensor bands* (not RGB colours)
into those channels — every material's band reflectances, the sun's and the sky's band
radiances — renders three bands with one set of paths, and a 164-band cube takes 55
passes. Measured on 2 cores (llvm_ad_rgb, 128², 16 spp, ~300k triangles): 0.18 s per pass;
a ``*_mono`` variant needs one pass per band at the same cost per pass (3× slower), and a
``*_spectral`` variant spreads its 4 wavelengths per path over the whole 350–1000 nm range
(≈40× fewer samples per 4 nm band). No colour conversion happens in rgb variants
(textures are loaded ``raw``), so each channel is exactly one band.

Illumination is normalised so that the downwelling irradiance on a horizontal plane is 1
in every band: the directional sun has irradiance ``(1 − f_d) / cos θ_s`` normal to its
beam, the uniform sky radiance ``f_d / π`` (``constant`` emitter; the ground extends to
±2 km so nothing below the horizon is ever seen). Apparent reflectance is then
``π · L``. The sky's emitter-sampling weight is 0.1 (sun 1.0): the sky is gathered mostly by
BSDF sampling (with MIS), and the path tracer's random choice between the two emitters then
adds little variance to the direct sun term.

Mitsuba's LLVM variants need LLVM ≥ 16: :func:`setup_mitsuba` points DRJIT_LIBLLVM_PATH
at the system's libLLVM 19 before importing Mitsuba.
"""

from __future__ import annotations

import glob
import math
import os

import numpy as np

from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.cameras import Intrinsics, pixel_rays
from brfgs.errors import UserError
from brfgs.sim import spectra as sp
from brfgs.sim.geometry import SceneGeometry
from brfgs.sim.materials import MATERIAL_IDS, Material, material

DEFAULT_VARIANT = "llvm_ad_rgb"
_LLVM_GLOBS = ["/usr/lib/llvm-19/lib/libLLVM*.so*", "/usr/lib/x86_64-linux-gnu/libLLVM-19*.so*",
               "/usr/lib/x86_64-linux-gnu/libLLVM.so.19*", "/usr/lib/llvm-1[6-9]/lib/libLLVM*.so*",
               "/usr/lib/llvm-2*/lib/libLLVM*.so*", "/usr/lib/*/libLLVM-1[6-9]*.so*", "/usr/lib/*/libLLVM-2*.so*"]
_REGISTERED: set[str] = set()


def setup_mitsuba(variant: str = DEFAULT_VARIANT):
    """Import Mitsuba with ``variant`` set (LLVM ≥ 16 located first); returns the ``mitsuba`` module."""
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        for pattern in _LLVM_GLOBS:
            found = sorted(glob.glob(pattern))
            if found:
                os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
                break
    try:
        import mitsuba as mi  # lazy: DRJIT_LIBLLVM_PATH must be set before the first import (above)
    except ImportError as exc:  # pragma: no cover - dependency declared in pyproject
        raise UserError(f"mitsuba is not installed ({exc}); pip install mitsuba") from None
    if mi.variant() != variant:
        if variant not in mi.variants():
            raise UserError(f"Mitsuba variant {variant!r} is not available (have {mi.variants()})", field="variant")
        mi.set_variant(variant)
    if variant not in _REGISTERED:
        _register_leaf_bsdf(mi)
        _REGISTERED.add(variant)
    return mi


def _register_leaf_bsdf(mi) -> None:
    """Register the ``brfgs_leaf`` BSDF (diffuse reflection R + diffuse transmission T, two-sided)."""
    import drjit as dr  # lazy: like mitsuba, only after setup_mitsuba has set DRJIT_LIBLLVM_PATH

    class LeafBSDF(mi.BSDF):
        """Thin Lambertian leaf: f = R/π on the incident side, T/π on the other side.

        Sampling picks reflection or transmission with probability 1/2 (R ≈ T for leaves in
        the NIR and both are small in the visible) and a cosine-weighted direction.
        """

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.r = mi.Color3f(0.1)
            self.t = mi.Color3f(0.1)
            dr.make_opaque(self.r, self.t)
            both = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            self.m_components = [mi.BSDFFlags.DiffuseReflection | both, mi.BSDFFlags.DiffuseTransmission | both]
            self.m_flags = self.m_components[0] | self.m_components[1]

        def sample(self, ctx, si, sample1, sample2, active=True):
            cos_i = mi.Frame3f.cos_theta(si.wi)
            refl = sample1 < 0.5
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            up = dr.select(refl, cos_i > 0, cos_i < 0)
            wo.z = dr.select(up, wo.z, -wo.z)
            bs = mi.BSDFSample3f()
            bs.wo = wo
            bs.pdf = 0.5 * dr.abs(wo.z) * dr.inv_pi
            bs.eta = 1.0
            bs.sampled_type = dr.select(refl, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
                                        mi.UInt32(+mi.BSDFFlags.DiffuseTransmission))
            bs.sampled_component = dr.select(refl, mi.UInt32(0), mi.UInt32(1))
            value = dr.select(refl, self.r, self.t) * 2.0  # f·cos/pdf = (R/π)·cos / (0.5·cos/π)
            ok = active & (cos_i != 0) & (bs.pdf > 0)
            return bs, dr.select(ok, value, 0.0)

        def eval(self, ctx, si, wo, active=True):
            ci = mi.Frame3f.cos_theta(si.wi)
            co = mi.Frame3f.cos_theta(wo)
            v = dr.select(ci * co > 0, self.r, self.t) * dr.abs(co) * dr.inv_pi
            return dr.select(active & (ci != 0), v, 0.0)

        def pdf(self, ctx, si, wo, active=True):
            co = mi.Frame3f.cos_theta(wo)
            return dr.select(active, 0.5 * dr.abs(co) * dr.inv_pi, 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, cb):
            cb.put("reflectance", self.r, mi.ParamFlags.NonDifferentiable)
            cb.put("transmittance", self.t, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys):
            dr.make_opaque(self.r, self.t)

        def to_string(self):
            return "BrfgsLeafBSDF[]"

    mi.register_bsdf("brfgs_leaf", lambda props: LeafBSDF(props))


def sensor_to_world(c2w_gl: np.ndarray) -> np.ndarray:
    """Mitsuba sensor to_world [4, 4] from an OpenGL c2w (Mitsuba cameras: +X left, +Y up, +Z forward)."""
    return np.asarray(c2w_gl, float) @ np.diag([-1.0, 1.0, -1.0, 1.0])


class BandTripletRenderer:
    """A Mitsuba scene of ``geometry`` that renders apparent-reflectance cubes three bands at a time.

    Args:
        geometry: the scene's meshes, textures and objects.
        wavelengths_nm, fwhm_nm: [B] sensor bands.
        sun_zenith_deg, sun_azimuth_deg: sun position (conventions: azimuth clockwise from north).
        spp: samples per pixel (power of two for byte-identical renders; a power of 4 for ldsampler).
        sampler: Mitsuba sampler, "ldsampler" (low discrepancy) or "independent".
        max_depth: longest path (Mitsuba ``path`` integrator; Russian roulette from depth 5).
    """

    def __init__(self, geometry: SceneGeometry, wavelengths_nm, fwhm_nm, sun_zenith_deg: float,
                 sun_azimuth_deg: float, spp: int = 64, max_depth: int = 10, variant: str = DEFAULT_VARIANT,
                 sampler: str = "ldsampler"):
        mi = setup_mitsuba(variant)
        self.mi = mi
        self.geometry = geometry
        self.wavelengths_nm = np.asarray(wavelengths_nm, float)
        self.fwhm_nm = np.asarray(fwhm_nm, float)
        self.spp = int(spp)
        self.sampler = str(sampler)
        B = len(self.wavelengths_nm)
        self.n_bands = B
        # illumination per band (downwelling irradiance on a horizontal plane = 1)
        self.sky_fraction = sp.sky_fraction(self.wavelengths_nm)  # [B]
        cos_s = math.cos(math.radians(sun_zenith_deg))
        self.sun_irradiance_normal = (1.0 - self.sky_fraction) / cos_s  # [B]
        self.sky_radiance = self.sky_fraction / math.pi  # [B]
        omega_i = direction_from_angles_deg(sun_zenith_deg, sun_azimuth_deg)  # toward the sun
        self.sun_deg = (float(sun_zenith_deg), float(sun_azimuth_deg))

        # materials used by the scene, with band-averaged spectra
        names = sorted({p.material for p in geometry.parts}, key=lambda n: MATERIAL_IDS[n])
        self.materials: dict[str, Material] = {n: material(n) for n in names}
        ba = lambda s: sp.band_average(s, self.wavelengths_nm, self.fwhm_nm)  # noqa: E731
        self.band_spectra = {n: {"end1": ba(m.end1), "end2": ba(m.end2),
                                 "transmittance": None if m.transmittance is None else ba(m.transmittance)}
                             for n, m in self.materials.items()}

        # one BSDF per (material, texture): textured ground materials get their own bitmap
        self._bsdfs: list[dict] = []
        bsdf_of: dict[tuple, object] = {}
        scene_dict = {"type": "scene",
                      "integrator": {"type": "path", "max_depth": int(max_depth), "rr_depth": 5},
                      "sun": {"type": "directional", "direction": (-omega_i).tolist(),
                              "irradiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
                      "sky": {"type": "constant", "sampling_weight": 0.1,
                              "radiance": {"type": "rgb", "value": [0.1, 0.1, 0.1]}}}
        self._shape_material: list[int] = []
        for part in geometry.parts:
            key = (part.material, part.texture)
            if key not in bsdf_of:
                bsdf_of[key] = self._make_bsdf(part.material, part.texture)
            props = mi.Properties()
            props["bsdf"] = bsdf_of[key]
            mesh = mi.Mesh(part.name, len(part.vertices), len(part.faces), props=props,
                           has_vertex_normals=False, has_vertex_texcoords=part.uv is not None)
            mp = mi.traverse(mesh)
            mp["vertex_positions"] = mi.Float(np.ascontiguousarray(part.vertices, np.float32).ravel())
            mp["faces"] = mi.UInt32(np.ascontiguousarray(part.faces, np.uint32).ravel())
            if part.uv is not None:
                mp["vertex_texcoords"] = mi.Float(np.ascontiguousarray(part.uv, np.float32).ravel())
            mp.update()
            scene_dict[part.name] = mesh
        self.scene = mi.load_dict(scene_dict, optimize=False)
        self._scene_params = mi.traverse(self.scene)
        # shape registry id -> material id, for ray-cast material maps
        import drjit as dr  # lazy: like mitsuba, only after setup_mitsuba has set DRJIT_LIBLLVM_PATH

        reg = {}
        for shape in self.scene.shapes():
            rid = int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])
            part = next(p for p in geometry.parts if p.name == shape.id())
            reg[rid] = MATERIAL_IDS[part.material]
        self._reg_to_material = np.zeros(max(reg) + 1, np.int16)
        for rid, mid in reg.items():
            self._reg_to_material[rid] = mid
        self._current = None

    # ---- materials
    def _make_bsdf(self, name: str, texture_key: str | None):
        mi = self.mi
        m = self.materials[name]
        entry = {"material": name, "kind": m.kind, "texture": None}
        if m.kind == "diffuse":
            if texture_key is not None:
                tex = self.geometry.textures[texture_key]
                b = tex.brightness.astype(np.float32)
                entry["texture"] = (np.ascontiguousarray((b * tex.mix)[..., None], np.float32),
                                    np.ascontiguousarray((b * (1.0 - tex.mix))[..., None], np.float32))
                init = np.zeros(tex.brightness.shape + (3,), np.float32)
                bsdf = mi.load_dict({"type": "diffuse", "reflectance": {
                    "type": "bitmap", "bitmap": mi.Bitmap(init), "raw": True, "filter_type": "bilinear",
                    "wrap_mode": tex.wrap}})
            else:
                bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}})
        elif m.kind == "plastic":
            bsdf = mi.load_dict({"type": "roughplastic", "distribution": "ggx", "alpha": float(m.alpha),
                                 "int_ior": float(m.ior), "ext_ior": 1.000277,
                                 "diffuse_reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}})
        elif m.kind == "leaf":
            bsdf = mi.load_dict({"type": "brfgs_leaf"})
        else:  # pragma: no cover
            raise ValueError(m.kind)
        entry["params"] = mi.traverse(bsdf)
        entry["bsdf"] = bsdf
        self._bsdfs.append(entry)
        return bsdf

    def set_sun(self, sun_zenith_deg: float, sun_azimuth_deg: float) -> None:
        """Move the sun (a flight's later frame): its direction, and its beam irradiance so that the
        horizontal downwelling irradiance stays 1 in every band."""
        if (float(sun_zenith_deg), float(sun_azimuth_deg)) == self.sun_deg:
            return
        mi = self.mi
        self.sun_deg = (float(sun_zenith_deg), float(sun_azimuth_deg))
        self.sun_irradiance_normal = (1.0 - self.sky_fraction) / math.cos(math.radians(sun_zenith_deg))
        travel = -direction_from_angles_deg(sun_zenith_deg, sun_azimuth_deg)          # light travels away from the sun
        up = [0.0, 1.0, 0.0] if abs(travel[2]) > 0.99 else [0.0, 0.0, 1.0]
        self._scene_params["sun.to_world"] = mi.Transform4f().look_at(origin=[0.0, 0.0, 0.0],
                                                                     target=travel.tolist(), up=up)
        self._scene_params.update()
        self._current = None                                        # set_bands reloads the irradiance

    def set_bands(self, idx: tuple[int, int, int]) -> None:
        """Load bands ``idx`` (three band indices) into the R, G, B channels of all materials and lights."""
        mi = self.mi
        idx = list(idx)
        if self._current == idx:
            return
        for e in self._bsdfs:
            s = self.band_spectra[e["material"]]
            p = e["params"]
            if e["kind"] == "diffuse":
                if e["texture"] is not None:
                    bm, bn = e["texture"]
                    tex = bm * s["end1"][idx].astype(np.float32) + bn * s["end2"][idx].astype(np.float32)  # [T, T, 3]
                    p["reflectance.data"] = mi.TensorXf(tex)
                else:
                    p["reflectance.value"] = mi.Color3f(*[float(v) for v in s["end1"][idx]])
            elif e["kind"] == "plastic":
                p["diffuse_reflectance.value"] = mi.Color3f(*[float(v) for v in s["end1"][idx]])
            else:
                p["reflectance"] = mi.Color3f(*[float(v) for v in s["end1"][idx]])
                p["transmittance"] = mi.Color3f(*[float(v) for v in s["transmittance"][idx]])
            p.update()
        sp_ = self._scene_params
        sp_["sun.irradiance.value"] = mi.Color3f(*[float(v) for v in self.sun_irradiance_normal[idx]])
        sp_["sky.radiance.value"] = mi.Color3f(*[float(v) for v in self.sky_radiance[idx]])
        sp_.update()
        self._current = idx

    # ---- cameras
    def make_sensor(self, c2w_gl: np.ndarray, intr: Intrinsics):
        """Mitsuba perspective sensor matching ``intr`` (square pixels, centred principal point) and c2w."""
        mi = self.mi
        fov_x = math.degrees(2 * math.atan(0.5 * intr.w / intr.fl_x))
        if abs(intr.fl_x - intr.fl_y) > 1e-6 * intr.fl_x or abs(intr.cx - intr.w / 2) > 1e-6 or \
                abs(intr.cy - intr.h / 2) > 1e-6:
            raise ValueError("the simulator renders square pixels with a centred principal point")
        return mi.load_dict({
            "type": "perspective", "fov": fov_x, "fov_axis": "x", "near_clip": 0.1, "far_clip": 1.0e5,
            "to_world": mi.ScalarTransform4f(sensor_to_world(c2w_gl).tolist()),
            "film": {"type": "hdrfilm", "width": int(intr.w), "height": int(intr.h), "pixel_format": "rgb",
                     "rfilter": {"type": "box"}, "sample_border": False},
            "sampler": {"type": self.sampler, "sample_count": self.spp}})

    def render_triplet(self, sensor, seed: int) -> np.ndarray:
        """Apparent reflectance [H, W, 3] (π·L) of the three loaded bands."""
        img = self.mi.render(self.scene, sensor=sensor, seed=int(seed) & 0xFFFFFFFF, spp=self.spp)
        return np.asarray(img, dtype=np.float64)[..., :3] * math.pi

    def render_cube(self, c2w_gl: np.ndarray, intr: Intrinsics, seed: int, bands=None) -> np.ndarray:
        """Apparent reflectance cube [H, W, B] (float32) for the camera ``c2w_gl`` (all bands or ``bands``)."""
        bands = list(range(self.n_bands)) if bands is None else list(bands)
        sensor = self.make_sensor(c2w_gl, intr)
        out = np.empty((intr.h, intr.w, len(bands)), np.float32)
        for k in range(0, len(bands), 3):
            chunk = bands[k:k + 3]
            idx = chunk + [chunk[-1]] * (3 - len(chunk))
            self.set_bands(tuple(idx))
            img = self.render_triplet(sensor, seed)
            out[..., k:k + len(chunk)] = img[..., :len(chunk)]
        return out

    def _pixel_hits(self, c2w_gl: np.ndarray, intr: Intrinsics):
        """(Mitsuba surface interactions, ray directions [H·W, 3]) of the rays through the pixel centres."""
        mi = self.mi
        o, d = pixel_rays(c2w_gl, intr)  # [H, W, 3] each
        o = o.reshape(-1, 3)
        d = d.reshape(-1, 3)
        ray = mi.Ray3f(mi.Point3f(*[mi.Float(np.ascontiguousarray(o[:, k], np.float32)) for k in range(3)]),
                       mi.Vector3f(*[mi.Float(np.ascontiguousarray(d[:, k], np.float32)) for k in range(3)]))
        return self.scene.ray_intersect(ray), d

    def sun_visibility(self, c2w_gl: np.ndarray, intr: Intrinsics) -> np.ndarray:
        """Direct-sun visibility [H, W] (uint8) of the surface through each pixel centre, for the current
        sun: 1 lit, 0 in the shadow of the scene's geometry (a ray toward the sun is blocked), 255 where the
        pixel's ray hits nothing. Leaves block the sun entirely here (their transmission is not counted)."""
        mi = self.mi
        si, _ = self._pixel_hits(c2w_gl, intr)
        to_sun = direction_from_angles_deg(*self.sun_deg)  # [3] unit, toward the sun
        blocked = np.asarray(self.scene.ray_test(si.spawn_ray(mi.Vector3f(*[float(v) for v in to_sun]))), bool)
        valid = np.asarray(si.is_valid(), bool)
        return np.where(valid, np.where(blocked, 0, 1), 255).astype(np.uint8).reshape(intr.h, intr.w)

    def raycast(self, c2w_gl: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
        """Depth [H, W] (m along the optical axis, NaN where nothing is hit) and material id [H, W] (int16)
        of the surfaces through the pixel centres."""
        mi = self.mi
        import drjit as dr  # lazy: like mitsuba, only after setup_mitsuba has set DRJIT_LIBLLVM_PATH

        si, d = self._pixel_hits(c2w_gl, intr)
        t = np.asarray(si.t, np.float64)
        valid = np.asarray(si.is_valid(), bool)
        rid = np.asarray(dr.reinterpret_array(mi.UInt32, si.shape), np.int64)
        forward = -np.asarray(c2w_gl, float)[:3, 2]
        depth = np.where(valid, t * (d @ forward), np.nan).astype(np.float32).reshape(intr.h, intr.w)
        mat = np.where(valid & (rid < len(self._reg_to_material)),
                       self._reg_to_material[np.clip(rid, 0, len(self._reg_to_material) - 1)], 0)
        return depth, mat.astype(np.int16).reshape(intr.h, intr.w)
