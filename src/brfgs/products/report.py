"""``brfgs products``: per-pixel kernel products from nadir, written as ENVI cubes, PNGs and JSON.

:func:`products_report` renders the products of :func:`brfgs.products.maps.render_products`
with a nadir camera over the scene (:func:`brfgs.products.maps.nadir_camera`) and writes one
ENVI cube and one PNG per product (CIR composites for reflectances, a colour-mapped band near
860 nm for the contributions and ANIX), alpha.npy and products.json (settings, camera, per-product
mean at that band, optionally the decoder check). With ``mcd43`` (the default) also the MODIS
MCD43-style parameters f_iso, f_vol, f_geo per pixel and band fitted to the model's BRF, the fit's
RMSE, and NBAR / black-sky / white-sky albedo computed from them as MCD43 does
(:mod:`brfgs.products.mcd43_maps`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brfgs.data.lock import releases_locks
from brfgs.analysis import plots
from brfgs.products import maps as P
from brfgs.analysis.brf import auto_roi_size
from brfgs.products.georaster import MapGrid, envi_map_info, map_camera, map_grid, write_geotiff
from brfgs.products.mcd43_maps import MCD43_NAMES, render_mcd43
from brfgs.analysis.options import check_size
from brfgs.products.options import ProductsOptions
from brfgs.analysis.output import Report, prepare_output_dir, run_folder
from brfgs.analysis.views import check_zenith_deg, intrinsics_json
from brfgs.data.cameras import Intrinsics
from brfgs.data.cir import cir_composite
from brfgs.data.cube_io import write_envi
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from brfgs.data import atomic

__all__ = ["ProductsOptions", "products_report", "PRODUCT_NAMES", "write_product_files"]

PRODUCT_NAMES = ("iso", "vol", "geo", "spec", "total", "nbar", "bsa", "wsa", "anix") + MCD43_NAMES + ("f_spec",)
_REFLECTANCES = ("iso", "total", "nbar", "bsa", "wsa", "f_iso", "nbar_mcd43", "bsa_mcd43", "wsa_mcd43")  # CIR
_NOT_SIGNED = ("anix", "fit_rmse")
_MAP_BAND_NM = 860.0


def _descriptions(nbar_sun_zenith_deg: float, albedo_sun_zenith_deg: float) -> dict[str, str]:
    return {"iso": "isotropic term", "vol": "Ross-Thick (volumetric) term", "geo": "Li-Sparse-R (geometric) term",
            "spec": "Cook-Torrance (specular) term", "total": "total BRF (sum of the four terms)",
            "nbar": f"NBAR (nadir view, sun zenith {nbar_sun_zenith_deg:g} deg)",
            "bsa": f"black-sky albedo (sun zenith {albedo_sun_zenith_deg:g} deg)",
            "wsa": "white-sky albedo", "anix": "anisotropy index max/min BRF over the principal plane",
            "f_iso": "MCD43 isotropic weight f_iso", "f_vol": "MCD43 RossThick weight f_vol",
            "f_geo": "MCD43 LiSparse-R weight f_geo", "fit_rmse": "RMSE of the MCD43 kernel fit to the model BRF",
            "f_spec": "Cook-Torrance (specular) weight f_spec",
            "nbar_mcd43": f"MCD43 NBAR from f (sun zenith {nbar_sun_zenith_deg:g} deg)",
            "bsa_mcd43": f"MCD43 black-sky albedo from f (sun zenith {albedo_sun_zenith_deg:g} deg)",
            "wsa_mcd43": "MCD43 white-sky albedo from f"}


def write_product_files(out: Path, tm: TrainedModel, products: dict, descriptions: dict[str, str],
                        grid: MapGrid | None = None) -> dict:
    """One ENVI cube NAME.hdr and one NAME.png per product of ``products`` (cubes [H, W, B]) and
    alpha.npy; with a map ``grid`` also NAME.tif (Cloud-Optimized GeoTIFF) and ENVI ``map info``.
    Returns {name: {cube, png, [geotiff,] description, mean_at_nm, finite_fraction}}."""
    wl = tm.wavelengths_nm
    i_map = int(np.argmin(np.abs(wl - _MAP_BAND_NM)))
    files = {}
    for name in PRODUCT_NAMES:
        if name not in products:
            continue
        cube = products[name]
        extra = {"description": f"brfgs {descriptions[name]}", **(envi_map_info(grid) if grid else {})}
        hdr = write_envi(out / f"{name}.hdr", cube, wl, tm.fwhm_nm, extra=extra, default_bands=tm.cir_indices,
                         ignore_value=float("nan"))
        if name in _REFLECTANCES:
            png = plots.save_rgb_png(out / f"{name}.png", cir_composite(cube, tm.cir_indices, tm.cir_scale))
        else:
            png = plots.save_map_png(out / f"{name}.png", cube[..., i_map], f"{descriptions[name]}, {wl[i_map]:.0f} nm",
                                     diverging=(name not in _NOT_SIGNED), label="max/min" if name == "anix" else "reflectance")
        band = cube[..., i_map]
        ok = np.isfinite(band)
        if grid is not None:
            write_geotiff(out / f"{name}.tif", cube, grid, wl, f"brfgs {descriptions[name]}")
        files[name] = {"cube": hdr.name, "png": png.name, "description": descriptions[name],
                       **({"geotiff": f"{name}.tif"} if grid is not None else {}),
                       "mean_at_nm": float(band[ok].mean()) if ok.any() else None,
                       "finite_fraction": float(ok.mean())}
    atomic.save_npy(out / "alpha.npy", products["alpha"].astype(np.float32))
    return files


def dsm_map(tm: TrainedModel, c2w: np.ndarray, intr: Intrinsics, backend: str, min_alpha: float) -> tuple[np.ndarray,
                                                                                                      str]:
    """(DSM [H, W] in metres, description): the rendered surface height under each pixel of the nadir
    map camera (camera height − depth along its vertical axis); ellipsoidal (WGS 84) when the scene
    has an origin, else relative to the ENU origin. NaN where the opacity is below ``min_alpha``."""
    rv = render(tm, camera_from_intrinsics(c2w, intr), decode=False, backend=backend)
    dsm = (float(c2w[2, 3]) - rv.depth).astype(np.float32)
    dsm[rv.alpha < min_alpha] = np.nan
    mf = tm.map_frame
    if mf is not None:
        return dsm + np.float32(mf.origin.altitude_m), "surface height (m above the WGS 84 ellipsoid) from depth"
    return dsm, "surface height (m above the scene's ENU origin) from depth"


def _write_dsm(out: Path, dsm: np.ndarray, description: str, grid: MapGrid | None) -> dict:
    """OUT/dsm.hdr (+ dsm.tif with a grid) and dsm.png."""
    extra = {"description": f"brfgs {description}", "band names": ["height_m"], **(envi_map_info(grid) if grid else {})}
    hdr = write_envi(out / "dsm.hdr", dsm[..., None], None, extra=extra, ignore_value=float("nan"))
    png = plots.save_map_png(out / "dsm.png", dsm, description, diverging=False, label="m")
    if grid is not None:
        write_geotiff(out / "dsm.tif", dsm[..., None], grid, None, f"brfgs {description}")
    ok = np.isfinite(dsm)
    return {"cube": hdr.name, "png": png.name, "description": description,
            **({"geotiff": "dsm.tif"} if grid is not None else {}),
            "median_m": float(np.median(dsm[ok])) if ok.any() else None, "finite_fraction": float(ok.mean())}


def _rmse_per_band(rmse: np.ndarray, wl: np.ndarray) -> dict:
    """Median and 95th percentile (over the map) of the MCD43 fit's RMSE per band."""
    flat = rmse.reshape(-1, rmse.shape[-1])
    ok = np.isfinite(flat).all(1)
    if not ok.any():
        return {"wavelengths_nm": wl.tolist(), "median": None, "p95": None}
    return {"wavelengths_nm": [float(w) for w in wl], "median": np.median(flat[ok], 0).round(6).tolist(),
            "p95": np.percentile(flat[ok], 95, 0).round(6).tolist()}


def _suns(tm: TrainedModel, opts: ProductsOptions) -> tuple[float, float, float]:
    """(sun, NBAR sun, albedo sun) zenith angles in degrees, validated."""
    sz = tm.sun_zenith_deg if opts.sun_zenith_deg is None else check_zenith_deg(opts.sun_zenith_deg, "--sun-zenith")
    nz = sz if opts.nbar_sun_zenith_deg is None else check_zenith_deg(opts.nbar_sun_zenith_deg, "--nbar-sun-zenith")
    az = sz if opts.albedo_sun_zenith_deg is None else check_zenith_deg(opts.albedo_sun_zenith_deg,
                                                                        "--albedo-sun-zenith")
    return sz, nz, az


def _camera(tm: TrainedModel, opts: ProductsOptions) -> tuple[np.ndarray, Intrinsics, MapGrid | None]:
    """The nadir camera (c2w [4, 4], intrinsics) of the maps: ``opts.size`` pixels, or the training
    images' pixel footprint on the ground (at most 2048 px); for a georeferenced scene turned to
    map north, with its map grid."""
    if opts.size is None:
        half = tm.scene_half_extent_m() if opts.half_extent_m is None else opts.half_extent_m
        wh = [auto_roi_size(tm, half, lo=16, hi=2048)]
    else:
        wh = list(opts.size)
    check_size(wh, "--size")
    c2w, intr = P.nadir_camera(tm, size=int(wh[0]), half_extent_m=opts.half_extent_m)
    if len(wh) == 2:
        intr = Intrinsics(intr.fl_x, intr.fl_x, wh[0] / 2, wh[1] / 2, int(wh[0]), int(wh[1]))
    mf = tm.map_frame
    if mf is None:
        return c2w, intr, None
    half = tm.scene_half_extent_m() if opts.half_extent_m is None else opts.half_extent_m
    c2w = map_camera(mf, c2w, half)
    target = np.r_[c2w[:2, 3], tm.scene_centre_m()[2]]
    return c2w, intr, map_grid(mf, c2w, intr, target)


@releases_locks
def products_report(run: str | Path, opts: ProductsOptions | None = None, out: str | Path | None = None) -> Report:
    """``brfgs products``: render the kernel products of the model of ``run`` from nadir and write
    them into ``out`` (default RUN/analysis/products)."""
    opts = (ProductsOptions() if opts is None else opts).validate()
    out = out if out is not None else opts.out
    tm = TrainedModel.load(run)
    P.require_hybrid(tm)
    sz, nz, az = _suns(tm, opts)
    c2w, intr, grid = _camera(tm, opts)
    out = Path(out) if out is not None else run_folder(Path(run)) / "analysis" / "products"
    prepare_output_dir(out, "products.json", opts.overwrite, tm.scene_root)
    t0 = time.perf_counter()
    res = P.render_products(tm, camera_from_intrinsics(c2w, intr), sun_zenith_deg=sz, nbar_sun_zenith_deg=nz,
                            albedo_sun_zenith_deg=az, backend=opts.backend, progress=opts.progress,
                            min_alpha=opts.min_alpha)
    t_render = time.perf_counter() - t0
    if opts.mcd43:
        t1 = time.perf_counter()
        fit = render_mcd43(tm, camera_from_intrinsics(c2w, intr), nbar_sun_zenith_deg=nz, albedo_sun_zenith_deg=az,
                           backend=opts.backend, min_alpha=opts.min_alpha, progress=opts.progress)
        res.update({k: fit[k] for k in MCD43_NAMES + ("f_spec",) if k in fit})
        res["settings"]["mcd43"] = fit["settings"]
        res["settings"]["mcd43"]["fit_seconds"] = time.perf_counter() - t1
    files = write_product_files(out, tm, res, _descriptions(nz, az), grid)
    files["dsm"] = _write_dsm(out, *dsm_map(tm, c2w, intr, opts.backend, opts.min_alpha), grid)
    wl = tm.wavelengths_nm
    info = {"model": tm.source, "scene": tm.scene_name, "settings": res["settings"],
            "camera": {"c2w": c2w.tolist(), "intrinsics": intrinsics_json(intr)},
            "files": files, "map": grid.describe(tm.map_frame) if grid is not None else None,
            "mean_band_nm": float(wl[int(np.argmin(np.abs(wl - _MAP_BAND_NM)))]),
            "timings_s": {"render_products_s": t_render},
            "notes": ["contributions are decoded sequentially (iso, +vol, +geo, +spec); they add up to 'total'",
                      "albedo integrals are applied in the latent space (brfgs.brdf.integrals); Cook-Torrance "
                      "integrals assume a horizontal facet", f"NaN where the accumulated opacity < {opts.min_alpha:g}"]}
    if opts.mcd43:
        info["mcd43_fit_rmse_per_band"] = _rmse_per_band(res["fit_rmse"], wl)
        info["notes"].append(("f_iso/f_vol/f_geo/f_spec: the model's own kernel weights per band (linear spectral basis), "
                              "rendered; fit_rmse: the specular lobe over settings.mcd43.grid"
                              if res["settings"]["mcd43"]["method"] == "exact" else
                              "f_iso/f_vol/f_geo: RossThick-LiSparse-R weights fitted per pixel and band to the model's "
                              "BRF over settings.mcd43.grid") + "; *_mcd43 products are computed from them as MCD43 does")
    if opts.check_decoder:
        info["decoder_check"] = P.decoder_nonlinearity(tm, az)
    atomic.write_json(out / "products.json", info)
    return Report(out, info, f"products ({intr.w}x{intr.h}, {len(wl)} bands) in {t_render:.1f} s -> {out}")
