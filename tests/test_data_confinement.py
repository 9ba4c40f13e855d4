"""Confinement: files that links lead to outside the scene folder are refused (exit 2, the file
named) unless --allow-outside-links is given; the scene folder is never written to."""

from __future__ import annotations

import shutil

import pytest

from brfgs.cli import main
from brfgs.data import read_scene
from brfgs.errors import UserError
from scenes import make_scene, snapshot


def _link_out(scene, outside, rel):
    """Move ``scene/rel`` to ``outside`` and leave a link to it in its place."""
    src = scene / rel
    dst = outside / src.name
    shutil.move(str(src), str(dst))
    src.symlink_to(dst)
    return src


@pytest.mark.parametrize("rels", [["images/view_01.img"], ["images/view_02.hdr", "images/view_02.img"],
                                  ["calibration/dark_00.hdr", "calibration/dark_00.img"], ["calibration"],
                                  ["transforms.json"]], ids=["img", "cube", "dark", "calibration", "transforms"])
def test_links_out_of_the_scene_are_refused_unless_allowed(tmp_path, capsys, rels):
    scene = make_scene(tmp_path / "scene", n_dark=2)
    outside = tmp_path / "outside"
    outside.mkdir()
    for rel in rels:
        _link_out(scene, outside, rel)
    before = snapshot(scene)
    out = tmp_path / "inspect"
    assert main(["inspect", str(scene), "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "outside the scene folder" in err and "--allow-outside-links" in err
    assert str(scene) in err
    with pytest.raises(UserError):
        read_scene(scene)
    assert main(["inspect", str(scene), "--out", str(out), "-q", "--allow-outside-links"]) == 0
    sc = read_scene(scene, allow_outside_links=True)
    assert len(sc.frames) == 7
    assert snapshot(scene) == before


def test_dotdot_and_absolute_paths_stay_refused_with_the_opt_in(tmp_path):
    import json

    scene = make_scene(tmp_path / "scene")
    meta = json.loads((scene / "transforms.json").read_text())
    for bad in ("../elsewhere/view_00.hdr", "/etc/passwd", "images/../../x.hdr"):
        meta["frames"][0]["file_path"] = bad
        (scene / "transforms.json").write_text(json.dumps(meta))
        with pytest.raises(UserError, match="file_path"):
            read_scene(scene, allow_outside_links=True)


def test_the_scene_folder_itself_may_be_a_link(tmp_path):
    real = make_scene(tmp_path / "real")
    (tmp_path / "alias").symlink_to(real)
    assert len(read_scene(tmp_path / "alias").frames) == 7


@pytest.mark.parametrize("rel", ["images/view_03", "calibration/dark_01"])
def test_big_endian_cubes_read_the_same(tmp_path, rel):
    """``byte order = 1`` is honoured for image cubes and dark frames alike: the same values stored
    big-endian read (and give the same noise σ) exactly as the little-endian original."""
    import numpy as np

    scene = make_scene(tmp_path / "scene", n_dark=2)
    ref = read_scene(scene)
    hdr, img = scene / f"{rel}.hdr", scene / f"{rel}.img"
    img.write_bytes(np.frombuffer(img.read_bytes(), "<f4").astype(">f4").tobytes())
    hdr.write_text(hdr.read_text().replace("byte order = 0", "byte order = 1"))
    big = read_scene(scene)
    assert np.array_equal(big.dark_sigma, ref.dark_sigma)
    for i in range(len(ref.frames)):
        assert np.array_equal(big.load_image(i), ref.load_image(i))


def test_dark_frame_mislabelled_big_endian_or_empty_is_refused(tmp_path):
    """The issue's cases: a little-endian dark frame labelled ``byte order = 1`` (σ would be 1e37)
    and a dark frame with 0 lines were accepted; both are one-line errors naming the dark frame."""
    import re

    scene = make_scene(tmp_path / "a", n_dark=2)
    hdr = scene / "calibration" / "dark_00.hdr"
    hdr.write_text(hdr.read_text().replace("byte order = 0", "byte order = 1"))
    with pytest.raises(UserError, match="plausible reflectance range") as err:
        read_scene(scene)
    assert err.value.file == str(hdr)
    scene = make_scene(tmp_path / "b", n_dark=2)
    hdr = scene / "calibration" / "dark_01.hdr"
    hdr.write_text(re.sub(r"lines = \d+", "lines = 0", hdr.read_text()))
    (scene / "calibration" / "dark_01.img").write_bytes(b"")
    with pytest.raises(UserError) as err:
        read_scene(scene)
    assert err.value.file == str(hdr) and err.value.field == "lines"
