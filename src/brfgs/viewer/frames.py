"""One display frame of the viewer: a model, a camera, a sun and a display mode → RGB uint8.

Every mode goes through the one render path, :func:`brfgs.model.render`:

- ``cir`` — the model's CIR composite (the CIR of evaluation); ``truecolor`` — 640/550/470 nm
  divided by one common 99th percentile (colour balance kept);
- ``band:<nm>`` — the nearest band, grey, scaled by its 99th percentile;
- ``index:<formula>`` — a band formula (:mod:`brfgs.viewer.formula`, NDVI by default) on a
  red-yellow-green map over [−1, 1];
- ``depth`` (viridis, 2–98 % range), ``normals`` ((n + 1) / 2, world axes), ``alpha`` (grey);
- ``kernel:<iso|vol|geo|spec>`` — the term's contribution to the reflectance at the CIR's NIR band,
  decoded as ``brfgs products`` does it (D(Σ_{≤c}) − D(Σ_{<c})), on a blue-white-red map
  symmetric about 0.

The index, depth and kernel modes show only the surface: pixels whose accumulated opacity is
below :data:`SURFACE_MIN_ALPHA` (the learned background) are black, as are formula values
without a number (x/0). The geometry modes (depth, normals, alpha) rasterize no appearance.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from matplotlib import colormaps
from torch import Tensor

from brfgs.products.maps import COMPONENT_ORDER, component_latents, require_hybrid
from brfgs.data.cameras import Intrinsics
from brfgs.data.cir import cir_composite
from brfgs.errors import UserError
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from brfgs.model.rendering import composite_background
from brfgs.model.shadows import sun_sky_light
from brfgs.model.view import RenderedView
from brfgs.spectral.band_decode import decode_bands
from brfgs.viewer.formula import NDVI, IndexFormula, parse_formula

__all__ = ["DisplayMode", "parse_mode", "FrameResult", "render_frame", "frame_comparison", "MODE_NAMES",
           "TRUECOLOR_NM", "SURFACE_MIN_ALPHA"]

TRUECOLOR_NM = (640.0, 550.0, 470.0)
SURFACE_MIN_ALPHA = 0.1  # accumulated opacity from which a pixel shows the surface (index, depth, kernel, clicks)
MODE_NAMES = ("cir", "truecolor", "band", "index", "depth", "normals", "alpha",
              "kernel:iso", "kernel:vol", "kernel:geo", "kernel:spec")


@dataclass(frozen=True)
class DisplayMode:
    """What a frame shows: ``kind`` (cir, truecolor, band, index, depth, normals, alpha, kernel),
    the band wavelength (nm, for band), the formula (for index), the kernel term (for kernel)."""

    kind: str
    wavelength_nm: float | None = None
    formula: IndexFormula | None = None
    term: str | None = None

    @property
    def needs_cube(self) -> bool:
        return self.kind in ("cir", "truecolor", "band", "index")


def parse_mode(text: str) -> DisplayMode:
    """A mode from its text: cir, truecolor, band:<nm>, index[:<formula>], depth, normals, alpha,
    kernel:<iso|vol|geo|spec>; UserError naming the field ``mode`` otherwise."""
    t = str(text).strip()
    kind, _, arg = t.partition(":")
    kind = kind.strip().lower()
    if kind in ("cir", "truecolor", "depth", "normals", "alpha") and not arg:
        return DisplayMode(kind)
    if kind == "band":
        try:
            nm = float(arg)
        except ValueError:
            raise UserError(f"display mode {t!r}: band needs a wavelength in nm, e.g. band:860", field="mode") from None
        if not np.isfinite(nm):
            raise UserError(f"display mode {t!r}: the wavelength must be finite", field="mode")
        return DisplayMode("band", wavelength_nm=nm)
    if kind == "index":
        return DisplayMode("index", formula=parse_formula(arg or NDVI))
    if kind == "kernel" and arg.strip() in COMPONENT_ORDER:
        return DisplayMode("kernel", term=arg.strip())
    raise UserError(f"unknown display mode {t!r}; modes: cir, truecolor, band:<nm>, index:<formula>, depth, "
                    "normals, alpha, kernel:iso|vol|geo|spec", field="mode")


@dataclass
class FrameResult:
    """A displayed frame: ``rgb`` uint8 [H, W, 3], the render (depth, alpha, cube) for clicks, and
    the camera it was rendered from."""

    rgb: np.ndarray
    view: RenderedView
    c2w: np.ndarray  # [4, 4] OpenGL
    intr: Intrinsics
    seconds: float


def _to_u8(rgb01: np.ndarray) -> np.ndarray:  # [H, W, 3] uint8
    return (np.clip(np.nan_to_num(rgb01, nan=0.0), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _p99(x: np.ndarray) -> float:
    v = x[np.isfinite(x)]
    s = float(np.percentile(v, 99.0)) if v.size else 1.0
    return s if s > 1e-12 else 1.0


def _colormap(values: np.ndarray, lo: float, hi: float, name: str) -> np.ndarray:  # [H, W, 3] float in [0, 1]
    """``values`` [H, W] through matplotlib's colormap ``name`` over [lo, hi]; NaN → black."""
    t = (np.asarray(values, np.float64) - lo) / max(hi - lo, 1e-12)
    rgb = colormaps[name](np.clip(np.nan_to_num(t, nan=0.0), 0.0, 1.0))[..., :3]
    rgb[~np.isfinite(values)] = 0.0
    return rgb


def mode_bands(tm: TrainedModel, mode: DisplayMode) -> list[int]:
    """Band indices a spectral mode shows (CIR: the model's CIR bands)."""
    if mode.kind == "cir":
        return list(tm.cir_indices)
    if mode.kind == "truecolor":
        return tm.band_indices(TRUECOLOR_NM)
    if mode.kind == "band":
        return tm.band_indices([mode.wavelength_nm])
    return tm.band_indices(mode.formula.wavelengths_nm)


def _spectral_view(tm: TrainedModel, cam, sun: tuple[float, float], bands: list[int], backend: str
                   ) -> tuple[RenderedView, np.ndarray]:
    """(the render, reflectance planes [H, W, nb] in ``bands``): the latent rendered and only those
    bands decoded (:func:`brfgs.spectral.band_decode.decode_bands`, equal to the full decode; a model
    with shadows lit as :func:`brfgs.model.view.render` lights its cube); a
    model decoding per Gaussian (order "gaussian") decodes its whole cube."""
    if tm.render_settings.decode_order == "gaussian":
        view = render(tm, cam, sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1], backend=backend)
        return view, view.cube[..., bands]
    view = render(tm, cam, sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1], decode=False, backend=backend)
    planes = decode_bands(tm.decoder, torch.as_tensor(view.latent), bands)  # [H, W, nb]
    if view.sun_lit is not None:  # a model with shadows: the bands under the sun and sky light
        planes = planes * sun_sky_light(tm.diffuse_fraction(sun[0])[bands], torch.as_tensor(view.sun_lit))
    return view, planes.numpy()


def _planes_rgb(tm: TrainedModel, planes: np.ndarray, mode: DisplayMode, alpha: np.ndarray) -> np.ndarray:
    """[H, W, 3] in [0, 1] of a spectral mode from its planes [H, W, nb] (:func:`mode_bands`);
    an index only where the surface is (``alpha`` [H, W] ≥ :data:`SURFACE_MIN_ALPHA`)."""
    if mode.kind == "cir":
        return cir_composite(planes, (0, 1, 2), tm.cir_scale)
    if mode.kind == "truecolor":
        return planes / _p99(planes)
    if mode.kind == "band":
        return np.repeat((planes[..., 0] / _p99(planes[..., 0]))[..., None], 3, -1)
    f = mode.formula
    value = f.evaluate({w: planes[..., j] for j, w in enumerate(f.wavelengths_nm)})  # [H, W]
    return _colormap(np.where(alpha >= SURFACE_MIN_ALPHA, value, np.nan), -1.0, 1.0, "RdYlGn")


def _geometry_rgb(view: RenderedView, kind: str) -> np.ndarray:  # [H, W, 3] in [0, 1]
    if kind == "alpha":
        return np.repeat(view.alpha[..., None], 3, -1)
    if kind == "normals":
        return np.where(view.alpha[..., None] > 0, 0.5 * (view.normal + 1.0), 0.0)
    d = np.where((view.depth > 0) & (view.alpha >= SURFACE_MIN_ALPHA), view.depth, np.nan)
    v = d[np.isfinite(d)]
    lo, hi = (np.percentile(v, 2), np.percentile(v, 98)) if v.size else (0.0, 1.0)
    return _colormap(d, float(lo), float(hi), "viridis")


def _no_features(idx: Tensor, omega_o: Tensor) -> Tensor:  # [n, 1]: geometry only, no appearance head
    return torch.zeros(idx.shape[0], 1)


def kernel_contribution(tm: TrainedModel, view_image: Tensor, alpha: np.ndarray, term: str,
                        band: int) -> np.ndarray:  # [H, W]
    """Reflectance contribution of ``term`` in band ``band`` from rasterized component latents
    ``view_image`` [H, W, n_terms·d] (terms in :data:`COMPONENT_ORDER`): D(Σ_{≤term}) − D(Σ_{<term}),
    the background composited as in ``brfgs products``."""
    comps = [c for c in COMPONENT_ORDER if c in tm.head_cfg.components]
    d = tm.gaussians.latent_dim
    j = comps.index(term)
    a = torch.as_tensor(alpha)
    acc = view_image[..., :(j + 1) * d].reshape(*alpha.shape, j + 1, d).sum(-2)  # [H, W, d]
    cur = decode_bands(tm.decoder, composite_background(acc, a, tm.bg_latent), [band])[..., 0].numpy()
    if j == 0:
        return cur
    prev = view_image[..., :j * d].reshape(*alpha.shape, j, d).sum(-2)
    return cur - decode_bands(tm.decoder, composite_background(prev, a, tm.bg_latent), [band])[..., 0].numpy()


def _kernel_view(tm: TrainedModel, cam, sun: tuple[float, float], term: str, backend: str) -> RenderedView:
    require_hybrid(tm)
    if term not in tm.head_cfg.components:
        raise UserError(f"this model has no {term!r} kernel term (terms: {', '.join(tm.head_cfg.components)})",
                        field="mode")
    omega_i = tm.sun_direction(*sun)
    comps = [c for c in COMPONENT_ORDER if c in tm.head_cfg.components]

    def fn(idx: Tensor, oo: Tensor) -> Tensor:
        cl = component_latents(tm, idx, omega_i, oo)
        return torch.cat([cl[c] for c in comps], -1)  # [n, n_terms·d]

    return render(tm, cam, features=fn, backend=backend)


def render_frame(tm: TrainedModel, c2w: np.ndarray, intr: Intrinsics, mode: DisplayMode, *,
                 sun_zenith_deg: float | None = None, sun_azimuth_deg: float | None = None,
                 backend: str = "auto") -> FrameResult:
    """Render ``tm`` from the OpenGL camera-to-world ``c2w`` [4, 4] with ``intr`` under the sun
    (degrees; default the acquisition's) and colour it for ``mode``: rgb uint8 [H, W, 3]."""
    t0 = time.perf_counter()
    cam = camera_from_intrinsics(np.asarray(c2w, float), intr)
    sun = (tm.sun_zenith_deg if sun_zenith_deg is None else float(sun_zenith_deg),
           tm.sun_azimuth_deg if sun_azimuth_deg is None else float(sun_azimuth_deg))
    if mode.kind == "kernel":
        view = _kernel_view(tm, cam, sun, mode.term, backend)
        nir = tm.cir_indices[0]
        contrib = kernel_contribution(tm, view.image, view.alpha, mode.term, nir)  # [H, W]
        contrib = np.where(view.alpha >= SURFACE_MIN_ALPHA, contrib, np.nan)
        s = _p99(np.abs(contrib))
        rgb = _colormap(contrib, -s, s, "RdBu_r")
    else:
        if mode.needs_cube and not tm.spectral:
            if mode.kind != "cir":
                raise UserError("this model renders CIR only (no spectral decoder)", field="mode")
            view = render(tm, cam, sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1], backend=backend)
            rgb = view.cir
        elif mode.needs_cube:
            view, planes = _spectral_view(tm, cam, sun, mode_bands(tm, mode), backend)
            rgb = _planes_rgb(tm, planes, mode, view.alpha)
            if mode.kind == "cir":
                view.cir = rgb
        else:
            view = render(tm, cam, features=_no_features, normals=mode.kind == "normals", backend=backend)
            rgb = _geometry_rgb(view, mode.kind)
    return FrameResult(_to_u8(rgb), view, np.asarray(c2w, float), intr, time.perf_counter() - t0)


def frame_comparison(tm: TrainedModel, i_frame: int, observed_cube: np.ndarray | None, backend: str = "auto"
                     ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(render, observation, error) of training/test frame ``i_frame`` as uint8 [H, W, 3] CIR images:
    the model rendered with the frame's camera and sun, the observed cube [H, W, B] (None when
    the scene cannot be read) in the same CIR composite, and |render − observation| (mean over the
    three CIR channels) on the magma map over [0, 0.25]."""
    fr = tm.frames[i_frame]
    sun = tm.frame_sun(i_frame)
    res = render_frame(tm, np.asarray(fr["c2w"], float), tm.intrinsics, DisplayMode("cir"),
                       sun_zenith_deg=sun[0], sun_azimuth_deg=sun[1], backend=backend)
    if observed_cube is None:
        return res.rgb, None, None
    obs = cir_composite(np.asarray(observed_cube, np.float32), tm.cir_indices, tm.cir_scale)  # [H, W, 3]
    if obs.shape != res.view.cir.shape:
        raise UserError(f"observation of frame {fr['name']!r} is {obs.shape[1]}x{obs.shape[0]} pixels, the model's "
                        f"camera {res.view.cir.shape[1]}x{res.view.cir.shape[0]}", field="frames")
    err = np.abs(np.clip(res.view.cir, 0, 1) - obs).mean(-1)  # [H, W]
    return res.rgb, _to_u8(obs), _to_u8(_colormap(err, 0.0, 0.25, "magma"))
