"""brfgs batch's manifest checks: every field's range and type named in one line, the path checks
against a pairwise reference on random layouts (links included), the dry run's exit status and its
lines, link loops and unreadable paths, and the manifest benchmark."""

from __future__ import annotations

import json
import os
import random
from pathlib import Path

import pytest

from brfgs.cli import main
from brfgs.data.paths import inside
from brfgs.errors import UserError
from brfgs.train import config as config_mod
from brfgs.train.config import TrainConfig
from brfgs.train.presets import preset
from brfgs.render import BACKENDS
from brfgs.workflows import manifest_paths
from brfgs.workflows.batch_plan import local_gpus
from brfgs.workflows.bench_manifest import write_manifest
from brfgs.workflows.manifest import MAX_STEPS, check_manifest, read_manifest


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _scene(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    (path / "transforms.json").write_text('{"frames": []}\n')
    return path


# ------------------------------------------------------------------------------------------ fields
@pytest.mark.parametrize("text, field", [
    ("backend = 'quantum'\n", "scene[1].backend"),
    ("poses = 'quantum'\n", "scene[1].poses"),
    ("band_strategy = 'best'\n", "scene[1].band_strategy"),
    ("cache_gib = -1\n", "scene[1].cache_gib"),
    ("init_opacity = 1.5\n", "scene[1].init_opacity"),
    ("value_range = [10, -0.5]\n", "scene[1].value_range"),
    ("stage1_steps = 9223372036854775807\n", "scene[1].stage1_steps"),
    (f"ae_steps = {MAX_STEPS + 1}\n", "scene[1].ae_steps"),
    ("seed = -1\n", "scene[1].seed"),
    ("max_gaussians = 4294967296\n", "scene[1].max_gaussians"),
    ("[scene.densify]\nrefine_every = 100000000\n", "scene[1].densify.refine_every"),
    ("num_cpus = 10000000\n", "scene[1].num_cpus"),
    ("num_gpus = -1\n", "scene[1].num_gpus"),
    ("num_gpus = nan\n", "scene[1].num_gpus"),
    ("[scene.products]\nsun_zenith_deg = 200\n", "scene[1].products.sun_zenith_deg"),
    ("[scene.products]\nnbar_sun_zenith_deg = -5\n", "scene[1].products.nbar_sun_zenith_deg"),
    ("[scene.products]\nhalf_extent_m = -3\n", "scene[1].products.half_extent_m"),
    ("[scene.products]\nsize = [64, 100000]\n", "scene[1].products.size"),
    ("lr_spec = inf\n", "scene[1].lr_spec"),
    ("preset = ['fast']\n", "scene[1].preset"),
    ("densify = 5\n", "scene[1].densify"),
    ("[scene.mcmc]\nrefine_stop = 'late'\n", "scene[1].mcmc.refine_stop"),
])
def test_every_field_is_checked_and_named(tmp_path, text, field):
    _scene(tmp_path / "a")
    m = _write(tmp_path / "m.toml", "[[scene]]\nscene = 'a'\n" + text)
    with pytest.raises(UserError) as err:
        read_manifest(m)
    assert err.value.file == str(m) and err.value.field == field, str(err.value)
    assert "\n" not in str(err.value)


def test_out_must_be_a_folder(tmp_path):
    _scene(tmp_path / "a")
    _write(tmp_path / "file", "x")
    for text, field in (("out = 'file'\n[[scene]]\nscene = 'a'\n", "out"),
                        ("[[scene]]\nscene = 'a'\nout = 'file'\n", "scene[1].out"),
                        ("[[scene]]\nscene = 'a'\nout = 'file/below'\n", "scene[1].out")):
        with pytest.raises(UserError, match="is a file, not a folder") as err:
            read_manifest(_write(tmp_path / "m.toml", text))
        assert err.value.field == field


def test_a_value_that_only_validate_refuses_is_caught_after_a_valid_scene_of_the_same_shape(tmp_path):
    """Scenes whose options have the same keys and types share one type check; validate() still
    runs for each, and a new type is checked again."""
    _scene(tmp_path / "a")
    scenes = "".join(f"[[scene]]\nscene = 'a'\nname = 's{i}'\nlatent_dim = {v}\n" for i, v in enumerate((8, 16, 99)))
    with pytest.raises(UserError) as err:
        read_manifest(_write(tmp_path / "m.toml", scenes))
    assert err.value.field == "scene[3].latent_dim"
    scenes = "".join(f"[[scene]]\nscene = 'a'\nname = 's{i}'\nseed = {v}\n" for i, v in enumerate((1, 2.5)))
    with pytest.raises(UserError) as err:
        read_manifest(_write(tmp_path / "m.toml", scenes))
    assert err.value.field == "scene[2].seed"


def test_scene_options_equal_from_dict_of_the_merged_options(tmp_path):
    """Each scene's config.json dict is TrainConfig.from_dict(preset < defaults < scene).validate()'s."""
    _scene(tmp_path / "a")
    rng = random.Random(3)
    parts = ["[defaults]\npreset = 'tiny'\nlambda_flat = 0.02\n[defaults.densify]\nreset_every = 700\n"]
    raw = []
    for i in range(40):
        opts = {"seed": rng.randrange(1000)}
        if rng.random() < 0.3:
            opts["preset"] = rng.choice(["fast", "fine", "paper-fast"])
        if rng.random() < 0.3:
            opts["lr_spec"] = rng.choice([0.1, 1, 0.25])
        if rng.random() < 0.3:
            opts["components"] = rng.choice([["iso", "vol"], ["iso", "vol", "geo", "spec"]])
        if rng.random() < 0.3:
            opts["value_range"] = [-1, rng.choice([5, 7.5])]
        text = "".join(f"{k} = {json.dumps(v)}\n" for k, v in opts.items())
        densify = {"refine_every": rng.randrange(50, 150)} if rng.random() < 0.3 else {}
        if densify:
            text += "[scene.densify]\n" + "".join(f"{k} = {v}\n" for k, v in densify.items())
        parts.append(f"[[scene]]\nscene = 'a'\nname = 's{i}'\nproducts = false\n" + text)
        raw.append((opts, densify))
    man = read_manifest(_write(tmp_path / "m.toml", "".join(parts)))
    for s, (opts, densify) in zip(man.scenes, raw):
        base = preset(opts.get("preset", "tiny")).to_dict()
        merged = {**base, "lambda_flat": 0.02, **{k: v for k, v in opts.items() if k != "preset"}}
        merged["densify"] = {**base["densify"], "reset_every": 700, **densify}
        want = TrainConfig.from_dict(merged).validate().to_dict()
        assert s.config == want
        assert TrainConfig.from_dict(s.config).to_dict() == want


# ------------------------------------------------------------------------------------------ paths
def _reference(root: Path, scenes: list[tuple[str, Path, Path]]) -> set[str]:
    """The fields a pairwise check flags (each pair compared with brfgs.data.paths.inside)."""
    fields = set()
    if any(inside(root, sc) for _, sc, _ in scenes) or _under_file(root):
        fields.add("out")
    for i, (name, sc, out) in enumerate(scenes, 1):
        if any(inside(out, b) or inside(b, out) for _, b, _ in scenes) or _under_file(out):
            fields.add(f"scene[{i}].out")
        for j, (name_j, _, out_j) in enumerate(scenes[:i - 1], 1):
            if name.casefold() == name_j.casefold():
                fields.add(f"scene[{i}].name")
            if inside(out, out_j) or inside(out_j, out):
                fields.add(f"scene[{i}].out")
    return fields


def _under_file(path: Path) -> bool:
    p = path.resolve()
    return any(q.exists() and not q.is_dir() for q in (p, *p.parents))


def _layout(tmp_path: Path, rng: random.Random) -> tuple[str, list]:
    """A random manifest: scenes and outputs among a few nested folders, links and a file."""
    folders = ["d/a", "d/b", "d/a/x", "e", "e/f/g", "d", "h/A"]
    for f in folders[:5]:
        _scene(tmp_path / f)
    _write(tmp_path / "plain_file", "x")
    for link, target in (("ln_a", "d/a"), ("ln_e", "e")):
        if not (tmp_path / link).is_symlink():
            (tmp_path / link).symlink_to(tmp_path / target)
    places = folders + ["ln_a", "ln_a/out", "ln_e/f", "runs", "runs/x", "o/1", "o/2", "plain_file/x"]
    lines, scenes = ["out = 'runs'\n" if rng.random() < 0.8 else "out = 'ln_e/r'\n"], []
    for i in range(rng.randrange(2, 7)):
        scene = rng.choice(folders[:5] + ["ln_a", "ln_e/f/g"])
        name = rng.choice(["a", "b", "c", "A", "x", "g", "f"])
        text = f"[[scene]]\nscene = '{scene}'\nname = '{name}'\n"
        out = rng.choice(places) if rng.random() < 0.5 else None
        if out:
            text += f"out = '{out}'\n"
        lines.append(text)
        scenes.append((name, tmp_path / scene, tmp_path / out if out else None))
    root = tmp_path / ("runs" if lines[0] == "out = 'runs'\n" else "ln_e/r")
    return "".join(lines), [(n, sc, o or root / n) for n, sc, o in scenes], root


def test_path_checks_equal_a_pairwise_reference_on_random_layouts(tmp_path):
    rng = random.Random(0)
    flagged = 0
    for trial in range(150):
        text, scenes, root = _layout(tmp_path, rng)
        check = check_manifest(_write(tmp_path / "m.toml", text))
        got = {exc.field for _, exc in check.problems}
        assert got == _reference(root, scenes), (trial, text, [str(e) for _, e in check.problems])
        assert {s.index for s in check.manifest.scenes}.isdisjoint(i for i, _ in check.problems)
        flagged += bool(got)
    assert 30 < flagged < 150                                                      # both kinds of layout occur


def test_links_are_followed(tmp_path):
    _scene(tmp_path / "data" / "a")
    (tmp_path / "alias").symlink_to(tmp_path / "data")
    m = _write(tmp_path / "m.toml", "[[scene]]\nscene = 'alias/a'\nout = 'data/a/out'\n")
    with pytest.raises(UserError, match="lies inside the scene folder") as err:
        read_manifest(m)
    assert err.value.field == "scene[1].out"


def test_many_scenes_with_one_conflict(tmp_path):
    path = write_manifest(tmp_path, 3000)
    text = path.read_text() + "\n[[scene]]\nscene = 'scenes/s000010'\nname = 'late'\nout = 'runs/s002999/deeper'\n"
    check = check_manifest(_write(path, text))
    assert check.total == 3001 and len(check.manifest.scenes) == 3000
    assert [(i, e.field) for i, e in check.problems] == [(3001, "scene[3001].out")]
    assert "nested folders" in str(check.problems[0][1])


# ------------------------------------------------------------------------------------------ the dry run
def test_dry_run_lists_each_failing_scene_and_exits_2(tmp_path, capsys):
    for name in ("a", "b"):
        _scene(tmp_path / name)
    (tmp_path / "loop1").symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(tmp_path / "loop1")
    m = _write(tmp_path / "m.toml", "[defaults]\npreset = 'tiny'\n"
               "[[scene]]\nscene = 'a'\n"
               "[[scene]]\nscene = 'b'\nbackend = 'quantum'\n"
               "[[scene]]\nscene = 'loop1'\n"
               "[[scene]]\nscene = 'missing'\n"
               "[[scene]]\nscene = 'b'\nname = 'b2'\n[scene.products]\nsun_zenith_deg = 200\n")
    assert main(["batch", str(m), "--dry-run"]) == 2
    cap = capsys.readouterr()
    out, err = cap.out.splitlines(), cap.err.splitlines()
    assert len(out) == 6 and out[1].startswith("  a: run train")
    assert "scene[2]: FAIL:" in out[2] and "scene[3]: FAIL:" in out[3] and "missing: FAIL:" in out[4]
    assert len(err) == 5 and all(line.startswith("brfgs: error: ") for line in err)
    assert "field 'scene[2].backend': backend must be one of auto, torch, cpu, cuda, got 'quantum'" in err[0]
    assert "field 'scene[3].scene': cannot follow the links of" in err[1] and "loop1" in err[1]
    assert "field 'scene[5].products.sun_zenith_deg'" in err[2]
    assert err[3].startswith("brfgs: error: scene 'missing' would fail:")
    assert err[4] == "brfgs: error: 4 of 5 scenes would fail"
    # the run itself refuses the manifest in one line, counting the other problems
    assert main(["batch", str(m)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "scene[2].backend" in err[0] and "(and 2 more: brfgs batch --dry-run" in err[0]
    assert not (tmp_path / "m_batch").exists()


def test_an_output_root_that_cannot_be_written_fails_every_scene(tmp_path, capsys):
    _scene(tmp_path / "a")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    _write(tmp_path / "file", "x")
    for out, message in (("file", "is a file, not a folder"), ("loop/x", "cannot follow the links")):
        m = _write(tmp_path / "m.toml", f"out = '{out}'\n[[scene]]\nscene = 'a'\n[[scene]]\nscene = 'a'\nname = 'b'\n")
        assert main(["batch", str(m), "--dry-run"]) == 2
        err = capsys.readouterr().err
        assert message in err and "field 'out'" in err and "Traceback" not in err


def test_unreadable_paths_are_one_line(tmp_path, capsys, monkeypatch):
    _scene(tmp_path / "a")
    _scene(tmp_path / "b")
    (tmp_path / "link").symlink_to(tmp_path / "b")
    m = _write(tmp_path / "m.toml", "[[scene]]\nscene = 'a'\n[[scene]]\nscene = 'link'\n")
    real_is_file, real_realpath = Path.is_file, os.path.realpath

    def is_file(self):
        if self.name == "transforms.json" and self.parent.name == "a":
            raise PermissionError(13, "Permission denied", str(self))
        return real_is_file(self)

    def realpath(path, strict=False):
        if str(path).endswith("link"):
            raise PermissionError(13, "Permission denied", str(path))
        return real_realpath(path, strict=strict)

    monkeypatch.setattr(Path, "is_file", is_file)
    monkeypatch.setattr(manifest_paths.os.path, "realpath", realpath)
    assert main(["batch", str(m), "--dry-run"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "field 'scene[2].scene': cannot follow the links of" in err[0] and "Permission denied" in err[0]
    assert err[1].startswith("brfgs: error: scene 'a' would fail: ") and "transforms.json" in err[1]
    assert "cannot read (Permission denied)" in err[1] and err[2] == "brfgs: error: 2 of 2 scenes would fail"


def test_more_cpus_than_the_machine_has_is_a_warning(tmp_path, capsys):
    _scene(tmp_path / "a")
    m = _write(tmp_path / "m.toml", "[[scene]]\nscene = 'a'\nnum_cpus = 100000\n")
    assert main(["batch", str(m), "--dry-run"]) == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("brfgs: warning: 1 scene(s) ask for more CPUs than this machine has") and "a (100000)" in err
    assert main(["batch", str(m), "--dry-run", "--address", "127.0.0.1:1"]) == 0     # a cluster may have them
    assert capsys.readouterr().err == ""


def test_more_gpus_than_the_machine_has_is_a_warning(tmp_path, capsys, monkeypatch):
    _scene(tmp_path / "a")
    m = _write(tmp_path / "m.toml", "[[scene]]\nscene = 'a'\nnum_gpus = 0.5\n[[scene]]\nscene = 'a'\nname = 'b'\n"
               "num_gpus = 3\n")
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,1")
    assert local_gpus() == 2
    assert main(["batch", str(m), "--dry-run"]) == 0
    err = capsys.readouterr().err.strip()
    assert err == ("brfgs: warning: 1 scene(s) ask for more GPUs than this machine has (2): b (3); a local batch "
                   "fails them at once, a Ray cluster (--address) may have them")
    for visible, n in (("", 0), ("-1", 0), ("0,-1,1", 1), ("GPU-5e1f,GPU-77aa,GPU-0b3c", 3)):
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", visible)
        assert local_gpus() == n


def test_backend_names_are_the_rasterizers():
    assert config_mod.BACKENDS == BACKENDS


# ------------------------------------------------------------------------------------------ the benchmark
def test_bench_manifest(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert main(["bench", "manifest", "--scenes", "120", "--repeats", "2", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["scenes"] == 120 and len(res["rounds_s"]) == 2 and res["median_s"] > 0
    assert "120 scenes" in capsys.readouterr().out
    assert main(["bench", "manifest", "--scenes", "0"]) == 2
