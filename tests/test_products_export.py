"""PLY export (standard 3DGS names, round trip) and loading model files without the scene."""

from __future__ import annotations

import numpy as np
import torch

from brfgs.products.export import SH_C0, STANDARD_PROPERTIES, read_ply, write_ply
from brfgs.brdf.head import roughness_from_raw
from brfgs.model import TrainedModel, camera_from_intrinsics, render
from test_analysis_helpers import carpet_model, write_model_file


def test_ply_round_trip_with_standard_names(tmp_path):
    from plyfile import PlyData

    bm = carpet_model(half_m=3.0, n_bands=4, vol=0.2, geo=0.1, spec=0.3)
    g = torch.Generator().manual_seed(0)
    q = torch.randn(bm.n_gaussians, 4, generator=g)
    bm.gaussians.params["quats"] = q * 3.0                       # unnormalised on purpose
    colours = np.random.default_rng(1).random((bm.n_gaussians, 3)).astype(np.float32)
    path = write_ply(tmp_path / "g.ply", bm, colours=colours)
    ply = PlyData.read(str(path))
    names = [p.name for p in ply["vertex"].properties]
    assert names[: len(STANDARD_PROPERTIES)] == STANDARD_PROPERTIES
    assert all(ply["vertex"].data[n].dtype == np.float32 for n in names)
    v = read_ply(path)
    p = bm.gaussians.params
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
    bm.meta["cir_scale"] = [0.8, 0.5, 0.6]
    v = read_ply(write_ply(tmp_path / "g.ply", bm))
    z = bm.gaussians.params["z_iso"].numpy()
    want = np.clip(z[:, list(bm.cir_indices)] / bm.cir_scale, 0, 1)
    np.testing.assert_allclose(np.c_[v["f_dc_0"], v["f_dc_1"], v["f_dc_2"]] * SH_C0 + 0.5, want, atol=1e-6)


def test_model_file_loads_without_scene_and_renders_the_same(tmp_path):
    bm = carpet_model(half_m=6.0, n_bands=8, geo=0.2, spec=0.4)
    path = write_model_file(tmp_path / "run" / "model.safetensors", bm)
    lm = TrainedModel.load(tmp_path / "run")
    assert lm.n_gaussians == bm.n_gaussians and lm.head_cfg.components == bm.head_cfg.components
    c2w = np.asarray(bm.frames[2]["c2w"])
    a = render(bm, camera_from_intrinsics(c2w, bm.intrinsics), backend="cpu")
    b = render(lm, camera_from_intrinsics(c2w, lm.intrinsics), backend="cpu")
    np.testing.assert_allclose(b.cube, a.cube, atol=1e-6)
    np.testing.assert_allclose(b.depth, a.depth, atol=1e-5)
    assert path.stat().st_size > 0


def _viewer_colour(v, i, omega_o):
    """What a 3DGS viewer shows for vertex i seen along ω_o: clip(SH(−ω_o) + 0.5) (degree 3)."""
    from brfgs.brdf.sh import sh_basis

    y = sh_basis(3, torch.tensor(-np.asarray(omega_o, float)[None])).numpy()[0]        # [16]
    out = []
    for c in range(3):
        coef = np.r_[v[f"f_dc_{c}"][i], [v[f"f_rest_{15 * c + k}"][i] for k in range(15)]]
        out.append(float(y @ coef) + 0.5)
    return np.clip(out, 0, 1)


def test_ply_has_the_full_standard_3dgs_attribute_set(tmp_path):
    from plyfile import PlyData

    bm = carpet_model(half_m=2.0, n_bands=4, components=("iso",))
    ply = PlyData.read(str(write_ply(tmp_path / "g.ply", bm)))
    names = [p.name for p in ply["vertex"].properties]
    want = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(45)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    assert names[:62] == want == STANDARD_PROPERTIES
    v = read_ply(tmp_path / "g.ply")
    assert all((v[f"f_rest_{i}"] == 0).all() for i in range(45))      # no view dependence: rest is zero
    assert "z_iso_0" in names and ply.header.count("f_rest_") == 45


def test_ply_sh_fit_reproduces_the_view_dependent_cir_colour(tmp_path):
    """A Ross-Thick + Li-Sparse carpet: the viewer's degree-3 SH colour for a view direction is the
    model's CIR colour for that direction (to the fit's accuracy), hotspot brighter than forward."""
    from brfgs.products.export import _cir_of
    from brfgs.data.angles import direction_from_angles_deg

    bm = carpet_model(half_m=2.0, n_bands=4, z_left=[0.1, 0.2, 0.3, 0.4], z_right=[0.1, 0.2, 0.3, 0.4],
                      vol=0.3, geo=0.1, components=("iso", "vol", "geo"))
    bm.meta["cir_scale"] = [0.6, 0.5, 0.3]
    info = {}
    v = read_ply(write_ply(tmp_path / "g.ply", bm, info=info))
    assert info["rms_residual"] < 0.03 and info["n_directions"] == 48
    omega_i = bm.sun_direction()
    for zen, az in ((0.0, 0.0), (35.0, 150.0), (35.0, 330.0), (60.0, 60.0), (20.0, 250.0)):
        wo = direction_from_angles_deg(zen, az)
        want = np.clip(_cir_of(bm, torch.tensor([0]), torch.tensor(wo[None], dtype=torch.float32), omega_i), 0, 1)[0]
        # degree 3 rounds off the Li-Sparse hotspot: the peak comes out ~6 % low
        np.testing.assert_allclose(_viewer_colour(v, 0, wo), want, rtol=0.08)
    hot = _viewer_colour(v, 0, direction_from_angles_deg(35.0, 150.0))
    fwd = _viewer_colour(v, 0, direction_from_angles_deg(35.0, 330.0))
    assert (hot > fwd + 0.02).all()
    # --view-dependence none: nadir colour, zero rest
    v0 = read_ply(write_ply(tmp_path / "n.ply", bm, view_dependence="none"))
    assert all((v0[f"f_rest_{i}"] == 0).all() for i in range(45))


def test_ply_frames_for_splat_viewers(tmp_path):
    """--up y / -y: positions, rotations, normals and SH colours are the ENU export's, rotated (and
    centred, scaled); SuperSplat's load rotation (180° about z) then puts the scene's up at +y."""
    from brfgs.products.export import PlyFrame, ply_frame
    from brfgs.data.angles import direction_from_angles_deg
    from brfgs.render.geometry import quat_to_rotmat

    bm = carpet_model(half_m=2.0, n_bands=4, z_left=[0.1, 0.2, 0.3, 0.4], z_right=[0.2, 0.1, 0.3, 0.2],
                      vol=0.3, geo=0.1, components=("iso", "vol", "geo"), height_fn=lambda x, y: 0.3 * x)
    ref = read_ply(write_ply(tmp_path / "z.ply", bm))
    p_ref = np.stack([ref["x"], ref["y"], ref["z"]], 1).astype(float)
    up_enu = np.array([0.0, 0.0, 1.0])
    for up, viewer_up in (("y", [0, 1, 0]), ("-y", [0, -1, 0])):
        fr = ply_frame(bm, up, scale=2.0)
        assert fr.centre_m == tuple(bm.scene_centre_m())
        r = fr.rotation
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)   # a proper rotation
        np.testing.assert_allclose(r @ up_enu, viewer_up, atol=1e-12)
        v = read_ply(write_ply(tmp_path / f"{up}.ply", bm, frame=fr))
        p = np.stack([v["x"], v["y"], v["z"]], 1)
        np.testing.assert_allclose(p, 2.0 * (p_ref - fr.centre_m) @ r.T, atol=1e-4)
        n = np.stack([v["nx"], v["ny"], v["nz"]], 1)
        np.testing.assert_allclose(n, np.stack([ref["nx"], ref["ny"], ref["nz"]], 1) @ r.T, atol=1e-5)
        np.testing.assert_allclose(v["scale_0"], ref["scale_0"] + np.log(2.0), atol=1e-6)
        q = torch.tensor(np.stack([v[f"rot_{i}"] for i in range(4)], 1))
        q0 = torch.tensor(np.stack([ref[f"rot_{i}"] for i in range(4)], 1))
        np.testing.assert_allclose(quat_to_rotmat(q).numpy(), r @ quat_to_rotmat(q0).numpy(), atol=1e-5)
        for zen, az in ((0.0, 0.0), (35.0, 150.0), (60.0, 60.0)):          # the viewer sees the same colours
            wo = direction_from_angles_deg(zen, az)
            np.testing.assert_allclose(_viewer_colour(v, 3, r @ wo), _viewer_colour(ref, 3, wo), atol=1e-4)
    # SuperSplat / PlayCanvas rotate a PLY by 180° about z on load (splat-transform's viewer: setLocalEulerAngles(0, 0, 180))
    load = np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(load @ PlyFrame(up="-y").rotation @ up_enu, [0, 1, 0], atol=1e-12)


def test_export_cli_for_supersplat(tmp_path):
    import json

    from brfgs.cli import main

    bm = carpet_model(half_m=2.0, n_bands=4, components=("iso",))
    write_model_file(tmp_path / "run" / "model.safetensors", bm)
    assert main(["export", str(tmp_path / "run"), str(tmp_path / "e"), "--for", "supersplat"]) == 0
    info = json.loads((tmp_path / "e" / "export.json").read_text())
    assert info["ply_frame"]["up"] == "-y" and info["ply_frame"]["rotation_enu_to_ply"][1] == [0.0, 0.0, -1.0]
    v = read_ply(tmp_path / "e" / "gaussians.ply")
    assert abs(float(np.median(v["x"]))) < 0.6 and np.allclose(v["y"], 0.0, atol=1e-6)   # centred; ground at y = 0
    assert main(["export", str(tmp_path / "run"), str(tmp_path / "f"), "--for", "supersplat", "--up", "y"]) == 2
    assert main(["export", str(tmp_path / "run"), str(tmp_path / "g"), "--up", "x"]) == 2
    assert not (tmp_path / "g").exists()
