"""`brfgs merge OUT A B` writes only inside OUT, all at once: never through an existing link, only the
regular files that lie inside their own flight, under names that cannot collide; a failure leaves no OUT
and no staging folder; a flight or an OUT that cannot be used is one line, exit status 2, never a
traceback. Tiny flights (3 views of 8x6 px, scripts/fuzz_merge.py); a file outside the flights is
hard-linked into each, and every case checks that nothing outside OUT changed."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from brfgs.cli import main
from brfgs.data import read_scene
from brfgs.errors import UserError
from brfgs.workflows import merge_files
from brfgs.workflows.merge_flights import flight_labels
from scripts_loader import load_script

fz = load_script("fuzz_merge")


@pytest.fixture(scope="module")
def bases(tmp_path_factory):
    return fz.make_bases(tmp_path_factory.mktemp("merge_bases"))


@pytest.fixture
def case(bases, tmp_path):
    """Two flights A and B under tmp_path/flights, files outside them hard-linked into each, OUT = tmp_path/out."""
    c = {"dir": tmp_path, "A": tmp_path / "flights" / "A", "B": tmp_path / "flights" / "B",
         "outside": tmp_path / "outside", "out": tmp_path / "out"}
    for k, base in zip("AB", bases):
        shutil.copytree(base, c[k])
    c["outside"].mkdir()
    os.link(c["A"] / "images/v0.img", c["outside"] / "decoy_v0.img")
    os.link(c["B"] / "truth/sigma.json", c["outside"] / "decoy_sigma.json")
    return c


def run(capsys, out, *flights) -> tuple[int, list[str]]:
    capsys.readouterr()
    rc = main(["merge", str(out), *map(str, flights)])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, err.strip().splitlines()


def refused(capsys, out, *flights) -> str:
    """The one error line of a refused merge (exit status 2), after checking no OUT or staging is left."""
    rc, err = run(capsys, out, *flights)
    assert rc == 2 and len(err) == 1 and err[0].startswith("brfgs: error: "), (rc, err)
    assert not any(n.startswith(merge_files.STAGE_PREFIX) for n in os.listdir(Path(out).parent))
    return err[0]


def same_bytes(a: Path, b: Path) -> bool:
    return a.read_bytes() == b.read_bytes()


# ------------------------------------------------------------------------------------------ the cases
def test_a_file_is_never_written_through_an_existing_link(case, tmp_path, monkeypatch):
    """The old copy fallback wrote through a hard link into a file outside every flight: placing a file
    where a path exists is an error, with a hard link or a copy, and the linked file keeps its bytes."""
    decoy = case["outside"] / "decoy_v0.img"
    want = decoy.read_bytes()
    src = case["B"] / "images/v1.img"
    st = os.stat(src)
    with pytest.raises(UserError, match="two files"):
        merge_files.place_file(src, st, case["A"] / "images/v0.img", "images/v0.img")

    def no_link(*a, **kw):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(os, "link", no_link)
    with pytest.raises(UserError, match="two files"):
        merge_files.place_file(src, st, case["A"] / "images/v0.img", "images/v0.img")
    assert decoy.read_bytes() == want and os.stat(decoy).st_nlink == 2


def test_across_file_systems_the_files_are_fresh_copies(case, capsys, monkeypatch):
    def no_link(*a, **kw):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(os, "link", no_link)
    rc, _ = run(capsys, case["out"], case["A"], case["B"])
    assert rc == 0
    merged, a = case["out"] / "images/A_v0.img", case["A"] / "images/v0.img"
    assert same_bytes(merged, a) and os.stat(merged).st_ino != os.stat(a).st_ino
    assert os.stat(case["outside"] / "decoy_v0.img").st_nlink == 2


def test_flights_f_and_f_x_keep_their_own_frames(case, capsys):
    """Flight f's frame x_v0 and flight f_x's frame v0 were both f_x_v0: now two frames, each its own bytes."""
    fz.rename_frame(case["A"], 0, "x_v0")
    f, fx = case["dir"] / "flights" / "f", case["dir"] / "flights" / "f_x"
    os.rename(case["A"], f)
    os.rename(case["B"], fx)
    rc, _ = run(capsys, case["out"], f, fx)
    assert rc == 0
    m = read_scene(case["out"])
    assert [fr.name for fr in m.frames] == ["f_x_v0", "f_v1", "f_v2", "f-x_v0", "f-x_v1", "f-x_v2"]
    assert same_bytes(m.frames[0].path.with_suffix(".img"), f / "images/x_v0.img")
    assert same_bytes(m.frames[3].path.with_suffix(".img"), fx / "images/v0.img")
    assert same_bytes(case["out"] / "truth/depth/f_x_v0.npy", f / "truth/depth/x_v0.npy")
    assert same_bytes(case["out"] / "truth/depth/f-x_v0.npy", fx / "truth/depth/v0.npy")
    assert np.array_equal(m.load_truth(3), read_scene(fx).load_truth(0))
    assert fz.merged_problems(case["out"], [f, fx]) == []


def test_a_glob_character_in_a_frame_name_takes_only_its_own_cube(case, capsys):
    """A frame 'v?' once matched v0, v1 and v2 of its folder: now it takes its own cube only."""
    fz.rename_frame(case["B"], 2, "v?")
    own = {n: (case["B"] / "images" / f"{n}.img").read_bytes() for n in ("v0", "v1", "v?")}
    rc, _ = run(capsys, case["out"], case["A"], case["B"])
    assert rc == 0
    for n, data in own.items():
        assert (case["B"] / "images" / f"{n}.img").read_bytes() == data
        assert (case["out"] / "images" / f"B_{n}.img").read_bytes() == data
    assert sorted(p.name for p in (case["out"] / "images").iterdir() if p.name.startswith("B_")) == [
        "B_v0.hdr", "B_v0.img", "B_v1.hdr", "B_v1.img", "B_v?.hdr", "B_v?.img"]
    assert same_bytes(case["out"] / "images/B_v?.img", case["B"] / "images/v?.img")
    assert same_bytes(case["out"] / "images/B_v0.img", case["B"] / "images/v0.img")
    assert fz.merged_problems(case["out"], [case["A"], case["B"]]) == []


def test_a_frame_cannot_land_on_the_first_flights_dark_frames(case, capsys):
    """Flight 'dark' with a frame calibration/00.hdr once landed on flight 0's calibration/dark_00.hdr."""
    fz.rename_frame(case["B"], 0, "00", folder="calibration")
    dark = case["dir"] / "flights" / "dark"
    os.rename(case["B"], dark)
    rc, _ = run(capsys, case["out"], case["A"], dark)
    assert rc == 0
    assert same_bytes(case["out"] / "calibration/dark_00.img", case["A"] / "calibration/dark_00.img")
    assert same_bytes(case["out"] / "images/dark_00.img", dark / "calibration/00.img")
    m = read_scene(case["out"])
    assert m.dark_sigma_source == "dark_frames"
    np.testing.assert_allclose(m.dark_sigma, read_scene(case["A"]).dark_sigma)


def test_a_truth_folder_linked_to_etc_is_refused(case, capsys):
    depth = case["A"] / "truth/depth"
    shutil.rmtree(depth)
    depth.symlink_to("/etc", target_is_directory=True)
    err = refused(capsys, case["out"], case["A"], case["B"])
    assert "truth/depth" in err and "outside" in err
    assert not os.path.lexists(case["out"])


def test_a_truth_file_linked_outside_its_flight_is_refused(case, capsys):
    p = case["B"] / "truth/materials/v1.npy"
    os.replace(p, case["outside"] / "v1.npy")
    p.symlink_to(case["outside"] / "v1.npy")
    err = refused(capsys, case["out"], case["A"], case["B"])
    assert "v1.npy" in err and "outside" in err
    assert not os.path.lexists(case["out"])


def test_a_cube_that_is_a_loop_of_links_is_one_line(case, capsys):
    cube = case["A"] / "images/v1.hdr"
    cube.unlink()
    cube.symlink_to("v1.hdr")
    assert "loop" in refused(capsys, case["out"], case["A"], case["B"])
    assert main(["inspect", str(case["A"]), "--out", str(case["dir"] / "insp"), "--quiet"]) == 2


def test_a_pipe_in_a_truth_folder_is_refused(case, capsys):
    os.mkfifo(case["A"] / "truth/sun_visibility/v9.npy")
    assert "not a regular file" in refused(capsys, case["out"], case["A"], case["B"])


@pytest.mark.parametrize("boom", [OSError(errno.EIO, "Input/output error"), KeyboardInterrupt()],
                         ids=["io-error", "interrupt"])
@pytest.mark.parametrize("out_exists", [False, True], ids=["new-out", "empty-out"])
def test_a_failure_mid_merge_leaves_no_out_and_the_rerun_works(case, capsys, monkeypatch, boom, out_exists):
    out = case["out"]
    if out_exists:
        out.mkdir()
        ino = os.stat(out).st_ino
    real, calls = merge_files.place_file, []

    def place(*a, **kw):
        calls.append(a)
        if len(calls) == 5:
            raise boom
        return real(*a, **kw)

    monkeypatch.setattr(merge_files, "place_file", place)
    rc, err = run(capsys, out, case["A"], case["B"])
    assert rc == (130 if isinstance(boom, KeyboardInterrupt) else 3) and len(err) <= 1
    if out_exists:
        assert os.stat(out).st_ino == ino and not any(out.iterdir())
    else:
        assert not os.path.lexists(out)
    assert sorted(os.listdir(case["dir"])) == sorted(["flights", "outside"] + (["out"] if out_exists else []))
    assert os.stat(case["outside"] / "decoy_v0.img").st_nlink == 2
    monkeypatch.setattr(merge_files, "place_file", real)
    assert run(capsys, out, case["A"], case["B"])[0] == 0


def test_a_flight_that_is_a_loop_of_links_is_one_line(case, capsys):
    loop = case["dir"] / "loop"
    loop.symlink_to(loop)
    assert "loop" in refused(capsys, case["out"], case["A"], loop)


def test_a_flight_that_is_a_file_is_one_line(case, capsys):
    (case["dir"] / "flight.txt").write_text("x")
    assert "not a folder" in refused(capsys, case["out"], case["A"], case["dir"] / "flight.txt")


def test_a_missing_flight_is_one_line(case, capsys):
    assert "not found" in refused(capsys, case["out"], case["A"], case["dir"] / "nowhere")


def test_out_as_a_dangling_link_is_one_line(case, capsys):
    case["out"].symlink_to(case["dir"] / "nowhere")
    assert "link" in refused(capsys, case["out"], case["A"], case["B"])
    assert case["out"].is_symlink() and not (case["dir"] / "nowhere").exists()


def test_out_as_a_file_is_one_line(case, capsys):
    case["out"].write_text("mine")
    assert "not a folder" in refused(capsys, case["out"], case["A"], case["B"])
    assert case["out"].read_text() == "mine"


def test_a_flight_folder_name_of_240_characters_gets_a_short_label(case, capsys):
    long = case["dir"] / "flights" / ("L" * 240)
    os.rename(case["B"], long)
    rc, _ = run(capsys, case["out"], case["A"], long)
    assert rc == 0
    names = [f.name for f in read_scene(case["out"]).frames]
    assert names[3] == "L" * 40 + "_v0" and all(len(os.fsencode(p.name)) <= 255 for p in case["out"].rglob("*"))


def test_a_merged_name_longer_than_a_file_system_takes_is_one_line(case, capsys):
    fz.rename_frame(case["B"], 1, "n" * 251)
    assert "255" in refused(capsys, case["out"], case["A"], case["B"])


def test_flight_labels_never_collide():
    assert flight_labels(["f", "f_x"]) == ["f", "f-x"]
    assert flight_labels(["a b", "a_b"]) == ["f0-a-b", "f1-a-b"]
    assert flight_labels(["", "..", "x" * 300]) == ["f0-flight", "f1-flight", "f2-" + "x" * 40]
    assert all("_" not in s for s in flight_labels(["a_", "_a", "ü_ß"]))


# ------------------------------------------------------------------------------------------ the sweep
def _scenario(name: str, c: dict) -> tuple[list, Path, int]:
    """(flights, OUT, expected exit status) of one merge case, the flights mutated as it says."""
    a, b, d, out = c["A"], c["B"], c["dir"], c["out"]
    if name == "f_and_f_x":
        fz.rename_frame(a, 0, "x_v0")
        os.rename(a, d / "flights/f"), os.rename(b, d / "flights/f_x")
        return [d / "flights/f", d / "flights/f_x"], out, 0
    if name == "glob":
        fz.rename_frame(b, 2, "v?")
    elif name == "dark_clash":
        fz.rename_frame(b, 0, "00", folder="calibration")
        os.rename(b, d / "flights/dark")
        return [a, d / "flights/dark"], out, 0
    elif name == "truth_etc":
        shutil.rmtree(a / "truth/depth")
        (a / "truth/depth").symlink_to("/etc", target_is_directory=True)
    elif name == "truth_outside":
        shutil.move(str(b / "truth/images"), str(c["outside"] / "images"))
        (b / "truth/images").symlink_to(c["outside"] / "images", target_is_directory=True)
    elif name == "cube_hard_linked_outside":
        os.link(b / "images/v2.img", c["outside"] / "v2.img")
    elif name in ("loop", "file", "missing"):
        (d / "loop").symlink_to(d / "loop")
        (d / "file").write_text("x")
        return [a, d / name], out, 2
    elif name == "out_dangling":
        out.symlink_to(d / "nowhere")
    elif name == "out_file":
        out.write_text("mine")
    elif name == "out_full":
        out.mkdir()
        (out / "x").write_text("mine")
    elif name == "out_empty":
        out.mkdir()
    elif name == "long_folder":
        os.rename(b, d / "flights" / ("L" * 240))
        return [a, d / "flights" / ("L" * 240)], out, 0
    elif name == "long_frame":
        fz.rename_frame(b, 1, "n" * 251)
    elif name == "wavelengths":
        meta = fz._meta(b)
        meta["fl_x"] *= 1.1
        fz._put(b, meta)
    return [a, b], out, {"truth_etc": 2, "truth_outside": 2, "out_dangling": 2, "out_file": 2, "out_full": 2,
                         "long_frame": 2, "wavelengths": 2}.get(name, 0)


SCENARIOS = ("valid", "f_and_f_x", "glob", "dark_clash", "truth_etc", "truth_outside", "cube_hard_linked_outside",
             "loop", "file", "missing", "out_dangling", "out_file", "out_full", "out_empty", "long_folder",
             "long_frame", "wavelengths", "interrupted")


@pytest.mark.parametrize("name", SCENARIOS)
def test_no_file_outside_out_changes_in_any_merge(case, capsys, monkeypatch, name):
    """Every file outside OUT (flights, the files hard-linked into them, link targets) keeps its bytes,
    inode, link count (less OUT's own links) and link target; a failed merge leaves no OUT, no staging."""
    flights, out, want = _scenario(name, case)
    if name == "interrupted":
        real = merge_files.place_file
        monkeypatch.setattr(merge_files, "place_file",
                            lambda *a: real(*a) if a[3].startswith("images/A") else (_ for _ in ()).throw(OSError(
                                errno.ENOENT, "No such file or directory", a[0])))
        want = 2
    before = fz.snapshot(case["dir"])
    existed = os.path.lexists(out)
    rc, err = run(capsys, out, *flights)
    assert rc == want, err
    assert fz.changes_outside(before, fz.snapshot(case["dir"]), "out", rc == 0) == []
    assert not any(n.startswith(merge_files.STAGE_PREFIX) for n in os.listdir(case["dir"]))
    if rc == 0:
        assert fz.merged_problems(out, flights) == []
    else:
        assert len(err) == 1 and os.path.lexists(out) == existed
