"""Accuracy by material (brfgs.evaluation.by_material): pooled statistics against a per-pixel loop,
pure-pixel blocks, the ray depth spread of a two-layer carpet against its closed form, and the
``materials`` block that ``brfgs evaluate`` writes for a scene with material maps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from brfgs.evaluation import by_material as BM
from brfgs.model import render
from test_analysis_helpers import carpet_model


def _toy_view(rng, h=6, w=8, f=1):
    mat = rng.integers(1, 4, size=(h * f, w * f))
    r_cir, t_cir = rng.random((h, w, 3)), rng.random((h, w, 3))
    r_cube, t_cube = rng.random((h, w, 5)) + 0.1, rng.random((h, w, 5)) + 0.1
    alpha = rng.random((h, w))
    depth = 50 + rng.random((h, w))
    spread = rng.random((h, w))
    true_depth = 50 + rng.random((h * f, w * f))
    valid = rng.random((h, w)) > 0.1
    return mat, r_cir, t_cir, valid, alpha, depth, spread, true_depth, r_cube, t_cube


def test_pooled_statistics_match_a_pixel_loop():
    rng = np.random.default_rng(0)
    views = [_toy_view(rng) for _ in range(3)]
    pix = [BM.view_pixels(*v) for v in views]
    got = BM.summarise(pix, {1: "grass", 2: "soil", 3: "water"})
    assert abs(sum(s["error_share"] for s in got.values()) - 1.0) < 1e-12
    shares = [s["error_share"] for s in got.values()]
    assert shares == sorted(shares, reverse=True)       # largest share first
    total = sum(((v[1] - v[2]) ** 2).mean(-1)[v[3]].sum() for v in views)
    for k, name in ((1, "grass"), (2, "soil"), (3, "water")):
        se, ang, al, sp, dz = [], [], [], [], []
        for mat, rc, tc, ok, a, d, s, td, rcu, tcu in views:
            for y in range(ok.shape[0]):
                for x in range(ok.shape[1]):
                    if ok[y, x] and mat[y, x] == k:
                        se.append(((rc[y, x] - tc[y, x]) ** 2).mean())
                        c = rcu[y, x] @ tcu[y, x] / np.linalg.norm(rcu[y, x]) / np.linalg.norm(tcu[y, x])
                        ang.append(np.arccos(min(1.0, c)))
                        al.append(a[y, x])
                        if a[y, x] >= BM.MIN_ALPHA:
                            sp.append(s[y, x])
                            dz.append(d[y, x] - td[y, x])
        s = got[name]
        assert s["n_pixels"] == len(se)
        assert s["psnr"] == pytest.approx(-10 * np.log10(np.mean(se)), rel=1e-12)
        assert s["sam"] == pytest.approx(np.mean(ang), rel=1e-9)
        assert s["error_share"] == pytest.approx(np.sum(se) / total, rel=1e-12)
        assert s["alpha"] == pytest.approx(np.median(al))
        assert s["depth_spread_m"] == pytest.approx(np.median(sp))
        assert s["depth_error_m"] == pytest.approx(np.median(dz))


def test_finer_maps_count_only_pure_blocks():
    mat = np.array([[1, 1, 2, 2],
                    [1, 1, 1, 2]])           # 2x4 map on a 1x2 image: left block pure (1), right mixed
    depth = np.array([[10.0, 12.0, 0, 0], [14.0, 16.0, 0, 0]])
    one = np.ones((1, 2))
    pix = BM.view_pixels(mat, np.zeros((1, 2, 3)), np.full((1, 2, 3), 0.1), one > 0, one, np.full((1, 2), 14.0),
                         np.zeros((1, 2)), depth)
    assert set(pix) == {1} and pix[1]["se"].size == 1
    assert pix[1]["dz"][0] == pytest.approx(14.0 - 13.0)   # block mean of the true depth
    with pytest.raises(ValueError):
        BM.view_pixels(np.ones((3, 4), int), np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), np.ones((2, 2), bool),
                       np.ones((2, 2)), np.ones((2, 2)), np.zeros((2, 2)))


def _rot(axis: str, deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])}[axis]


def test_normal_error_of_a_tilted_plane_against_its_true_depth():
    """A plane 20 m in front of a camera, its normal tilted 25° (facing the camera): the normal map
    of the plane itself scores 0°, one turned by 15° scores 15°, in any camera rotation; pixels
    next to another material, or with no rendered normal, are left out (NaN)."""
    w, h = 12, 10
    K = np.array([[30.0, 0, w / 2], [0, 30.0, h / 2], [0, 0, 1]])
    n_cam = _rot("x", 25.0) @ np.array([0.0, 0.0, -1.0])            # camera axes, facing the camera
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    depth = -20.0 / (rays @ n_cam)                                   # the plane n_cam . P = -20
    viewmat = np.eye(4)
    viewmat[:3, :3] = _rot("y", 40.0) @ _rot("x", -70.0)             # world -> camera
    n_world = viewmat[:3, :3].T @ n_cam
    ids = np.ones((h, w), int)
    ids[:, 9:] = 2
    err = BM.normal_error_deg(np.broadcast_to(n_world, (h, w, 3)), viewmat, K, depth, ids)
    inner = (slice(1, -1), slice(1, 8))
    np.testing.assert_allclose(err[inner], 0.0, atol=1e-5)
    assert np.isnan(err[:, 8:10]).all() and np.isnan(err[0]).all()  # material edge and border
    turned = viewmat[:3, :3].T @ (_rot("x", 15.0) @ n_cam)             # about an axis in the plane
    normals = np.broadcast_to(turned, (h, w, 3)).copy()
    normals[5, 4] = 0.0                                              # nothing rendered there
    err = BM.normal_error_deg(normals, viewmat, K, depth, ids)
    assert np.isnan(err[5, 4])
    err[5, 4] = 15.0
    np.testing.assert_allclose(err[inner], 15.0, atol=1e-5)


def test_view_pixels_pools_the_normal_error_where_the_model_is_opaque():
    rng = np.random.default_rng(3)
    mat, rc, tc, ok, a, d, s, td, rcu, tcu = _toy_view(rng, h=8, w=10)
    mat[:] = 1
    mat[:, 6:] = 2
    K = np.array([[20.0, 0, 5], [0, 20.0, 4], [0, 0, 1]])
    normals = rng.normal(size=(8, 10, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    pix = BM.view_pixels(mat, rc, tc, ok, a, d, s, td, rcu, tcu, (normals, np.eye(4), K))
    ref = BM.normal_error_deg(normals, np.eye(4), K, td, mat)
    for k in (1, 2):
        sel = ok & (mat == k)
        want = np.where(a >= BM.MIN_ALPHA, ref, np.nan)[sel]
        np.testing.assert_array_equal(pix[k]["dn"], want)
        got = BM.summarise([pix], {1: "grass", 2: "soil"})["grass" if k == 1 else "soil"]["normal_error_deg"]
        assert got == pytest.approx(np.nanmedian(want))
    assert BM.summarise([BM.view_pixels(mat, rc, tc, ok, a, d, s, td)], {})["1"]["normal_error_deg"] is None


def _two_layers(h_top: float, logit_top: float, logit_low: float):
    """A carpet at z = 0 and a copy lifted to ``h_top`` (the top layer's opacity logit given)."""
    low = carpet_model()
    top = carpet_model()
    p_low, p_top = low.gaussians.params, top.gaussians.params
    p_low["opacity_logits"].fill_(logit_low)
    p_top["means"][:, 2] += h_top
    p_top["opacity_logits"].fill_(logit_top)
    both = carpet_model()
    both.gaussians.replace({k: torch.cat([p_low[k], p_top[k]]) for k in p_low})
    return low, top, both


def test_depth_spread_of_two_layers_matches_the_closed_form():
    torch.manual_seed(0)
    low, top, both = _two_layers(1.5, -2.0, -1.0)
    cam = both.cameras[0]                                   # nadir, 60 m above the carpet
    a_low = render(low, cam, decode=False).alpha.astype(np.float64)
    a_top = render(top, cam, decode=False).alpha.astype(np.float64)
    alpha, depth, spread, normal = BM.ray_depth_moments(both, cam)
    centre = (slice(10, 22), slice(10, 22))        # well inside the 40 m carpet
    t_top, t_low = 60.0 - 1.5, 60.0
    w_top, w_low = a_top, (1 - a_top) * a_low                # the top layer composites first
    p = w_top / (w_top + w_low)
    np.testing.assert_allclose(alpha[centre], (w_top + w_low)[centre], atol=1e-4)
    np.testing.assert_allclose(depth[centre], (p * t_top + (1 - p) * t_low)[centre], atol=2e-3)
    np.testing.assert_allclose(spread[centre], (np.sqrt(p * (1 - p)) * 1.5)[centre], atol=2e-2)
    # one opaque layer: no spread; a finer layer stack (lower top layer) spreads less
    # the carpets are level: the normal map points up (world), toward the nadir camera
    np.testing.assert_allclose(normal[centre], np.broadcast_to([0.0, 0.0, 1.0], normal[centre].shape), atol=1e-4)
    s_one = BM.ray_depth_moments(low, cam)[2]
    assert np.nanmax(s_one[centre]) < 1e-3
    assert np.nanmedian(BM.ray_depth_moments(_two_layers(0.5, -2.0, -1.0)[2], cam)[2][centre]) < np.nanmedian(
        spread[centre])


def test_evaluate_writes_materials_for_scenes_with_material_maps(tmp_path, capsys):
    from brfgs.cli import main
    from test_train_cli import TINY
    from test_train_scene import make_plane_scene
    torch.set_num_threads(1)
    scene = make_plane_scene(tmp_path / "scene", w=64, h=48, n_bands=12)
    out = tmp_path / "run"
    assert main(["train", str(scene), str(out), *TINY, "--no-evaluate"]) == 0
    truth = scene / "truth"
    (truth / "materials").mkdir()
    for p in (scene / "images").glob("*.hdr"):
        m = np.ones((48, 64), np.int16)
        m[:, 32:] = 2
        np.save(truth / "materials" / f"{p.stem}.npy", m)
    (truth / "materials.json").write_text(json.dumps({"materials": {"1": {"name": "soil"}, "2": {"name": "grass"}}}))
    assert main(["evaluate", str(out), "--quiet", "--no-images", "--backend", "torch"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    mats = m["against"]["truth"]["materials"]
    assert set(mats["mean"]) == {"soil", "grass"} and mats["definitions"]
    assert set(mats["rings"]) == set(m["against"]["truth"]["rings"])
    for s in mats["mean"].values():
        assert s["n_pixels"] > 0 and s["psnr"] > 0 and 0 <= s["alpha"] <= 1 and s["sam"] is not None
        assert s["depth_error_m"] is None and s["normal_error_deg"] is None  # no truth/depth in this scene
    assert "materials" not in m["against"]["observed"]
    # with the true depth of the plane z = 0: depth and normal-map errors are reported (a short run's
    # discs are not yet levelled; normal_error_deg itself is checked on a plane above)
    from brfgs.data.cameras import Intrinsics, pixel_rays
    meta = json.loads((scene / "transforms.json").read_text())
    intr = Intrinsics(meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"], meta["w"], meta["h"])
    (truth / "depth").mkdir()
    for fr in meta["frames"]:
        c2w = np.asarray(fr["transform_matrix"])
        o, d = pixel_rays(c2w, intr)
        t = -o[..., 2] / d[..., 2]
        depth = t * (d @ -c2w[:3, 2])                      # along the optical axis (OpenGL c2w: it looks down -z)
        np.save(truth / "depth" / f"{Path(fr['file_path']).stem}.npy", depth.astype(np.float32))
    assert main(["evaluate", str(out), "--quiet", "--no-images", "--backend", "torch"]) == 0
    mats_d = json.loads((out / "metrics.json").read_text())["against"]["truth"]["materials"]
    for s in mats_d["mean"].values():
        assert abs(s["depth_error_m"]) < 5.0 and 0.0 <= s["normal_error_deg"] <= 180.0
    # maps on another pixel grid are left out; a corrupt map is an input error naming the file
    name = m["split"]["test"][0]
    np.save(truth / "materials" / f"{name}.npy", np.ones((10, 10), np.int16))
    assert main(["evaluate", str(out), "--quiet", "--no-images", "--backend", "torch"]) == 0
    m2 = json.loads((out / "metrics.json").read_text())["against"]["truth"]["materials"]
    assert sum(s["n_pixels"] for s in m2["mean"].values()) < sum(s["n_pixels"] for s in mats["mean"].values())
    (truth / "materials" / f"{name}.npy").write_bytes(b"not a numpy file")
    assert main(["evaluate", str(out), "--quiet", "--no-images", "--backend", "torch"]) == 2
    assert f"{name}.npy" in capsys.readouterr().err
