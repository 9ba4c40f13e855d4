"""The trained-model file: a save/load round trip through the one model type, the one render
function, and a one-line UserError naming the file and the field for every damaged file."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from brfgs.brdf.head import HeadConfig, init_head_params
from brfgs.data.cameras import Intrinsics, pose_from_view_angles
from brfgs.errors import UserError
from brfgs.model import TrainedModel, camera_from_intrinsics, init_from_points, render
from brfgs.model.io import FORMAT, SCHEMA_VERSION
from brfgs.spectral.autoencoder import SpectralAutoencoder


def small_model(n: int = 60, bands: int = 8, d: int = 4, seed: int = 0) -> TrainedModel:
    """A random hybrid-head model over a 20 m square, seen by two cameras."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(-10, 10, (n, 2)), rng.uniform(0, 1, n)]
    gm = init_from_points(pts, rng.uniform(0, 1, (n, 3)), latent_dim=d, init_opacity=0.8)
    cfg = HeadConfig(kind="hybrid")
    head = init_head_params(cfg, n, d, z_init=torch.randn(n, d))
    head["z_vol"], head["z_geo"] = 0.3 * torch.randn(n, d), 0.3 * torch.randn(n, d)  # the sun matters
    gm.set_head(head, "brf")
    intr = Intrinsics.from_fov(40.0, 24, 16)
    frames = [{"name": f"v{k}", "split": "train" if k == 0 else "test", "c2w": pose_from_view_angles(z, a, 50.0).tolist(),
               "view_zenith_deg": z, "view_azimuth_deg": a} for k, (z, a) in enumerate([(0.0, 0.0), (30.0, 90.0)])]
    scene = {"name": "toy", "root": "/nonexistent", "wavelengths_nm": np.linspace(450, 900, bands).tolist(),
             "fwhm_nm": None, "sun_zenith_deg": 35.0, "sun_azimuth_deg": 150.0,
             "intrinsics": {"fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": intr.w, "h": intr.h},
             "downscale": 1, "roi": None, "split": {}, "frames": frames}
    return TrainedModel(gaussians=gm, head_cfg=cfg, decoder=SpectralAutoencoder(bands, d).eval(), scene=scene,
                        config={"variant": "brf"}, extra={"bg_latent": torch.zeros(d), "bg_colors": torch.zeros(3)},
                        meta={"cir_indices": [bands - 1, bands // 2, 0], "cir_scale": [1.0, 1.0, 1.0]})


def test_round_trip_and_render(tmp_path):
    tm = small_model()
    path = tm.save(tmp_path / "model.safetensors")
    back = TrainedModel.load(tmp_path)  # a run folder works as well as the file
    assert back.source == str(path.resolve())
    ta, tb = tm.tensors(), back.tensors()
    assert ta.keys() == tb.keys() and all(torch.equal(ta[k], tb[k]) for k in ta)
    meta = json.loads(load_file_meta(path)["brfgs"])
    assert meta["schema_version"] == SCHEMA_VERSION and meta["n_gaussians"] == 60
    for cam in back.cameras:
        a, b = render(tm, cam, backend="torch"), render(back, cam, backend="torch")
        assert np.array_equal(a.cube, b.cube) and a.cube.shape == (16, 24, 8)
        assert a.cir.shape == (16, 24, 3) and np.isfinite(a.cube).all()
    # culling only skips Gaussians that cannot touch the image
    cam = camera_from_intrinsics(np.asarray(back.frames[1]["c2w"]), back.intrinsics)
    full = render(back, cam, cull=False, normals=True, backend="torch")
    culled = render(back, cam, cull=True, normals=True, backend="torch")
    assert np.array_equal(full.cube, culled.cube) and np.array_equal(full.normal, culled.normal)
    # custom per-Gaussian features come back raw, and the sun changes the latent
    ones = render(back, cam, features=lambda idx, oo: torch.ones(idx.numel(), 1), backend="torch")
    assert np.allclose(ones.image[..., 0].numpy(), ones.alpha, atol=1e-6) and ones.cube is None
    other_sun = render(back, cam, sun_zenith_deg=60.0, backend="torch")
    assert np.isfinite(other_sun.latent).all() and np.isfinite(full.latent).all()
    assert np.abs(other_sun.latent - full.latent).max() > 1e-3


def load_file_meta(path):
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        return f.metadata()


def _rewrite(path, out, meta=None, tensors=None, fmt=FORMAT):
    t = load_file(str(path)) if tensors is None else tensors
    m = load_file_meta(path)["brfgs"] if meta is None else meta
    save_file(t, str(out), metadata={"format": fmt, "brfgs": m})
    return out


@pytest.mark.parametrize("meta, field", [
    ("{}", "scene"),
    ("not json", "brfgs"),
    ("[1, 2]", "brfgs"),
    ('{"schema_version": 99}', "schema_version"),
    ('{"schema_version": "2"}', "schema_version"),
])
def test_bad_metadata_is_a_user_error(tmp_path, meta, field):
    path = small_model().save(tmp_path / "good.safetensors")
    bad = _rewrite(path, tmp_path / "bad.safetensors", meta=meta)
    with pytest.raises(UserError) as err:
        TrainedModel.load(bad)
    assert err.value.file == str(bad) and err.value.field == field
    assert "\n" not in str(err.value)


def test_damaged_fields_and_tensors_are_named(tmp_path):
    path = small_model().save(tmp_path / "good.safetensors")
    meta = json.loads(load_file_meta(path)["brfgs"])
    cases = []
    for key, value, field in (("appearance", "rgb", "appearance"), ("latent_dim", -1, "latent_dim"),
                              ("cir_indices", [0, 1, 99], "cir_indices"), ("head", None, "head")):
        m = dict(meta, **{key: value})
        cases.append((json.dumps(m), None, field))
    m = json.loads(json.dumps(meta))
    m["scene"]["frames"][0]["c2w"] = [[1, 0], [0, 1]]
    cases.append((json.dumps(m), None, "scene.frames[0]"))
    m = json.loads(json.dumps(meta))
    m["scene"]["sun_zenith_deg"] = 120
    cases.append((json.dumps(m), None, "scene.sun_zenith_deg"))
    m = json.loads(json.dumps(meta))
    m["scene"]["frames"][1]["diffuse_fraction"] = [0.95] * len(m["scene"]["wavelengths_nm"])
    cases.append((json.dumps(m), None, "scene.frames[1].diffuse_fraction"))
    t = load_file(str(path))
    nan = dict(t)
    nan["param.means"] = t["param.means"].clone()
    nan["param.means"][3, 1] = float("nan")
    cases.append((None, nan, "param.means"))
    short = dict(t)
    short["param.quats"] = t["param.quats"][:10].clone()
    cases.append((None, short, "param.quats"))
    missing = {k: v for k, v in t.items() if k != "param.opacity_logits"}
    cases.append((None, missing, "param.opacity_logits"))
    nodec = {k: v for k, v in t.items() if not k.startswith("decoder.")}
    cases.append((None, nodec, "decoder."))
    for k, (m, tens, field) in enumerate(cases):
        bad = _rewrite(path, tmp_path / f"bad{k}.safetensors", meta=m, tensors=tens)
        with pytest.raises(UserError) as err:
            TrainedModel.load(bad)
        assert err.value.file == str(bad) and err.value.field == field, (field, str(err.value))


def test_not_a_model_file(tmp_path):
    (tmp_path / "x.safetensors").write_bytes(b"\x00" * 64)
    with pytest.raises(UserError, match="safetensors"):
        TrainedModel.load(tmp_path / "x.safetensors")
    path = small_model().save(tmp_path / "good.safetensors")
    other = _rewrite(path, tmp_path / "other.safetensors", fmt="something-else/1")
    with pytest.raises(UserError, match="not a brfgs model file"):
        TrainedModel.load(other)
    with pytest.raises(UserError, match="no model.safetensors"):
        TrainedModel.load(tmp_path / "..")


@pytest.mark.parametrize("meta", ["{}", "not json", "[1, 2]"])
def test_render_and_evaluate_refuse_a_bad_model_file_in_one_line(tmp_path, capsys, meta):
    from brfgs.cli import main

    path = small_model().save(tmp_path / "good.safetensors")
    run = tmp_path / "run"
    run.mkdir()
    bad = _rewrite(path, run / "model.safetensors", meta=meta)
    for args in (["render", str(bad), "--view-zenith", "0", "--view-azimuth", "0", "-o", str(tmp_path / "r"), "-q"],
                 ["evaluate", str(run), "--quiet"]):
        capsys.readouterr()
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(bad) in err, err
    assert not (tmp_path / "r").exists() and not (run / "metrics.json").exists()
