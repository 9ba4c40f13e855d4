"""PLY export (standard 3DGS names, round trip) and loading model files without the scene."""

from __future__ import annotations

import numpy as np
import torch

from brfgs.analysis.export import SH_C0, STANDARD_PROPERTIES, read_ply, write_ply
from brfgs.analysis.renderer import load_model, render_view
from brfgs.brdf.head import roughness_from_raw
from test_analysis_helpers import carpet_model, write_model_file


def test_ply_round_trip_with_standard_names(tmp_path):
    from plyfile import PlyData

    bm = carpet_model(half_m=3.0, n_bands=4, vol=0.2, geo=0.1, spec=0.3)
    g = torch.Generator().manual_seed(0)
    q = torch.randn(bm.n_gaussians, 4, generator=g)
    bm.model.params["quats"] = q * 3.0                       # unnormalised on purpose
    colours = np.random.default_rng(1).random((bm.n_gaussians, 3)).astype(np.float32)
    path = write_ply(tmp_path / "g.ply", bm, colours=colours)
    ply = PlyData.read(str(path))
    names = [p.name for p in ply["vertex"].properties]
    assert names[: len(STANDARD_PROPERTIES)] == STANDARD_PROPERTIES
    assert all(ply["vertex"].data[n].dtype == np.float32 for n in names)
    v = read_ply(path)
    p = bm.model.params
    np.testing.assert_array_equal(np.c_[v["x"], v["y"], v["z"]], p["means"].numpy())
    np.testing.assert_array_equal(np.c_[v["scale_0"], v["scale_1"], v["scale_2"]], p["log_scales"].numpy())
    np.testing.assert_array_equal(v["opacity"], p["opacity_logits"].numpy())
    qn = (q / q.norm(dim=-1, keepdim=True)).numpy()
    np.testing.assert_allclose(np.c_[v["rot_0"], v["rot_1"], v["rot_2"], v["rot_3"]], qn, atol=1e-6)
    np.testing.assert_allclose(np.c_[v["f_dc_0"], v["f_dc_1"], v["f_dc_2"]] * SH_C0 + 0.5, colours, atol=1e-6)
    nrm = np.c_[v["nx"], v["ny"], v["nz"]]
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
    assert (nrm[:, 2] >= 0).all()
    for c in ("iso", "vol", "geo", "spec"):
        z = np.stack([v[f"z_{c}_{j}"] for j in range(4)], 1)
        np.testing.assert_array_equal(z, p[f"z_{c}"].numpy())
    np.testing.assert_allclose(v["roughness"], roughness_from_raw(p["rho_raw"]).numpy(), rtol=1e-6)


def test_default_ply_colours_are_the_cir_composite(tmp_path):
    bm = carpet_model(half_m=2.0, n_bands=4, components=("iso",))
    bm.cir_scale = np.array([0.8, 0.5, 0.6])
    v = read_ply(write_ply(tmp_path / "g.ply", bm))
    z = bm.model.params["z_iso"].numpy()
    want = np.clip(z[:, list(bm.cir_indices)] / bm.cir_scale, 0, 1)
    np.testing.assert_allclose(np.c_[v["f_dc_0"], v["f_dc_1"], v["f_dc_2"]] * SH_C0 + 0.5, want, atol=1e-6)


def test_model_file_loads_without_scene_and_renders_the_same(tmp_path):
    bm = carpet_model(half_m=6.0, n_bands=8, geo=0.2, spec=0.4)
    path = write_model_file(tmp_path / "run" / "model.safetensors", bm)
    lm = load_model(tmp_path / "run")
    assert lm.n_gaussians == bm.n_gaussians and lm.head_cfg.components == bm.head_cfg.components
    c2w = np.asarray(bm.frames[2]["c2w"])
    a = render_view(bm, c2w, bm.intrinsics, backend="cpu")
    b = render_view(lm, c2w, lm.intrinsics, backend="cpu")
    np.testing.assert_allclose(b.cube, a.cube, atol=1e-6)
    np.testing.assert_allclose(b.depth, a.depth, atol=1e-5)
    assert path.stat().st_size > 0
