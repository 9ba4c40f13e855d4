#!/usr/bin/env python3
"""Fuzz ``brfgs merge OUT A B ...`` with hostile flights and output paths: every case must end in exit 0
on valid input, or in exit 2 with one line naming a file (3 for a storage error, 130 for an interrupt),
never a traceback; no file outside OUT may change (content, inode, link count less OUT's own links, link
targets); a failed merge leaves no OUT (an empty OUT folder as it was) and no staging folder; a merged
scene reads, and each of its cubes and truth files holds the bytes of its own source.

Each case copies two tiny flights (3 views of 8x6 px, 4 bands, 2 dark frames, truth; a file outside the
flights hard-linked into each), applies one mutation whose expected outcome is known by construction,
runs ``brfgs merge`` in-process and checks the outcome. ``tests/test_fuzz_merge.py`` runs a few hundred
derandomized cases and every mutation once; the long run's counts are in docs/reliability.md.

    python3 scripts/fuzz_merge.py --cases 1500 --seed 0 [--work DIR] [--show-failures 20]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import os
import random
import shutil
import sys
import tempfile
import time
import traceback
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

W, H, BANDS = 8, 6, 4
FRAMES = ("v0", "v1", "v2")


def make_flight(root: Path, sun_deg: tuple[float, float], seed: int, frames=FRAMES, truth: bool = True) -> Path:
    """A valid tiny flight (docs/data-format.md layout): ENVI cubes, two listed dark frames, and a
    simulator-like truth/ (clean cubes, depth, materials, sun visibility, materials/sigma/scene JSON)."""
    from brfgs.data.cameras import Intrinsics, pose_from_view_angles
    from brfgs.data.cube_io import write_envi

    rng = np.random.default_rng(seed)
    wl = np.linspace(500.0, 850.0, BANDS)
    intr = Intrinsics.from_fov(35.0, W, H)
    fms = []
    for name, (zen, az) in zip(frames, [(0.0, 0.0), (30.0, 0.0), (30.0, 180.0)]):
        write_envi(root / f"images/{name}.hdr", (0.05 + 0.4 * rng.random((H, W, BANDS))).astype(np.float32), wl,
                   np.full(BANDS, 4.0))
        fms.append({"file_path": f"images/{name}.hdr", "transform_matrix": pose_from_view_angles(zen, az, 50.0).tolist(),
                    "view_zenith_deg": zen, "view_azimuth_deg": az})
        if truth:
            write_envi(root / f"truth/images/{name}.hdr", (0.05 + 0.4 * rng.random((H, W, BANDS))).astype(np.float32),
                       wl, np.full(BANDS, 4.0))
            for sub, arr in (("depth", rng.random((H, W)).astype(np.float32)),
                             ("materials", rng.integers(0, 2, (H, W)).astype(np.uint8)),
                             ("sun_visibility", rng.integers(0, 2, (H, W)).astype(np.uint8))):
                (root / "truth" / sub).mkdir(parents=True, exist_ok=True)
                np.save(root / "truth" / sub / f"{name}.npy", arr)
    for k in range(2):
        write_envi(root / f"calibration/dark_{k:02d}.hdr", rng.normal(0, 0.01, (H, W, BANDS)).astype(np.float32), wl)
    if truth:
        (root / "truth/materials.json").write_text(json.dumps({"0": {"name": "soil"}, "1": {"name": "grass"}}))
        (root / "truth/sigma.json").write_text(json.dumps({"sigma": [0.01] * BANDS, "seed": seed}))
        (root / "truth/scene.json").write_text(json.dumps({"scene": "tiny", "seed": seed}))
    meta = {"camera_model": "PINHOLE", "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": W,
            "h": H, "wavelengths_nm": wl.tolist(), "fwhm_nm": [4.0] * BANDS, "sun_zenith_deg": sun_deg[0],
            "sun_azimuth_deg": sun_deg[1], "frames": fms,
            "dark_frames": ["calibration/dark_00.hdr", "calibration/dark_01.hdr"]}
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))
    return root


def make_bases(folder: Path) -> tuple[Path, Path]:
    """Two flights of one tiny site under two suns."""
    return make_flight(folder / "A", (35.0, 150.0), 1), make_flight(folder / "B", (55.0, 220.0), 2)


# ------------------------------------------------------------------------------------------ the file tree
def snapshot(top: Path) -> dict[str, tuple]:
    """{path under ``top``: (kind, inode, link count, size, mtime, sha256 or link target)} of everything
    below ``top`` (links not followed, pipes not opened)."""
    snap = {}
    for dirpath, dirnames, filenames in os.walk(top):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st = p.lstat()
            kind = st.st_mode >> 12
            if p.is_symlink():
                what = os.readlink(p)
            elif p.is_file():
                what = hashlib.sha256(p.read_bytes()).hexdigest()
            else:
                what = None
            snap[str(p.relative_to(top))] = (kind, st.st_dev, st.st_ino, st.st_nlink,
                                             None if p.is_dir() else st.st_size,
                                             None if p.is_dir() else st.st_mtime_ns, what)
    return snap


def changes_outside(before: dict, after: dict, out_rel: str, succeeded: bool) -> list[str]:
    """Paths outside OUT (``out_rel`` under the case folder) that changed; a file's link count may grow by
    the links to it that OUT holds, and (only when the merge succeeded) OUT itself is new."""
    made = {k for k in after if k not in before and out_rel.startswith(k + "/")}   # OUT's new parents

    def outside(snap):
        return {k: v for k, v in snap.items() if not succeeded or (k != out_rel and not k.startswith(out_rel + "/")
                                                                   and k not in made)}

    in_out = Counter((v[1], v[2]) for k, v in after.items() if k.startswith(out_rel + "/")) if succeeded else Counter()
    b, a = outside(before), outside(after)
    bad = sorted(set(a) ^ set(b))
    for k in set(a) & set(b):
        va, vb = a[k], b[k]
        if va[:3] + va[4:] != vb[:3] + vb[4:] or va[3] - in_out[(va[1], va[2])] != vb[3]:
            bad.append(k)
    return bad


# ------------------------------------------------------------------------------------------ mutations
@dataclass
class Mutation:
    what: str
    expected: str                       # "valid" | "invalid" | a storage error or interrupt ("rc 3", "rc 130")
    args: list | None = None            # the flights given (default the case's A and B)
    out: Path | None = None             # the output path (default the case's out)
    interrupt: tuple | None = None      # (placement call at which to raise, exception)


def _meta(root: Path) -> dict:
    return json.loads((root / "transforms.json").read_text())


def _put(root: Path, meta: dict) -> None:
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))


def rename_frame(root: Path, k: int, new: str, folder: str = "images") -> None:
    """Frame ``k`` of a flight renamed ``new`` (its cube, data file and truth files moved along)."""
    meta = _meta(root)
    old = Path(meta["frames"][k]["file_path"]).stem
    (root / folder).mkdir(exist_ok=True)
    for sfx in (".hdr", ".img"):
        os.replace(root / "images" / f"{old}{sfx}", root / folder / f"{new}{sfx}")
        if (root / "truth/images" / f"{old}{sfx}").exists():
            os.replace(root / "truth/images" / f"{old}{sfx}", root / "truth/images" / f"{new}{sfx}")
    for sub in ("depth", "materials", "sun_visibility"):
        if (root / "truth" / sub / f"{old}.npy").exists():
            os.replace(root / "truth" / sub / f"{old}.npy", root / "truth" / sub / f"{new}.npy")
    meta["frames"][k]["file_path"] = f"{folder}/{new}.hdr"
    _put(root, meta)


def _rename_flight(case, which: str, new: str) -> Path:
    src = case[which]
    dst = src.parent / new
    os.rename(src, dst)
    case[which] = dst
    return dst


def mut_names(rng: random.Random, case: dict) -> Mutation:
    kind = rng.choice(["f_and_f_x", "same_folder_name", "same_label", "glob_frame", "long_folder", "long_frame",
                       "fitting_frame", "dark_clash", "dark_is_a_cube", "implicit_darks"])
    a, b = case["A"], case["B"]
    if kind == "f_and_f_x":
        rename_frame(a, 0, "x_v0")
        _rename_flight(case, "A", "f"), _rename_flight(case, "B", "f_x")
        rename_frame(case["B"], 1, "v0_b") if rng.random() < 0.5 else None
        return Mutation("flights f and f_x, frames x_v0 and v0", "valid")
    if kind in ("same_folder_name", "same_label"):
        other = b.parent / "x" / (a.name if kind == "same_folder_name" else a.name + "_")
        other.parent.mkdir()
        os.rename(b, other)
        case["B"] = other
        return Mutation(f"two flights with the {kind.replace('_', ' ')}", "valid")
    if kind == "glob_frame":
        new = rng.choice(["v?", "*", "v[01]", "v*", "[!x]", "v?.x"])
        rename_frame(rng.choice([a, b]), rng.randrange(3), new)
        return Mutation(f"a frame named {new!r}", "valid")
    if kind == "long_folder":
        _rename_flight(case, rng.choice("AB"), "L" * 240)
        return Mutation("a flight folder name of 240 characters", "valid")
    if kind in ("long_frame", "fitting_frame"):
        n = 251 if kind == "long_frame" else 200    # 251 + ".hdr": the longest name a flight can hold
        rename_frame(rng.choice([a, b]), rng.randrange(3), "n" * n)
        return Mutation(f"a frame name of {n} characters", "invalid" if kind == "long_frame" else "valid")
    if kind == "dark_clash":
        rename_frame(b, 0, "00", folder="calibration")
        _rename_flight(case, "B", "dark")
        return Mutation("a frame calibration/00.hdr of flight 'dark'", "valid")
    if kind == "dark_is_a_cube":
        meta = _meta(a)
        meta["dark_frames"] = ["images/v0.hdr", "calibration/dark_00.hdr"]
        _put(a, meta)
        return Mutation("a dark frame that is also a frame's cube", "valid")
    meta = _meta(a)
    del meta["dark_frames"]
    _put(a, meta)
    return Mutation("dark frames found in calibration/ (not listed)", "valid")


def mut_links(rng: random.Random, case: dict) -> Mutation:
    kind = rng.choice(["cube_inside", "cube_outside", "hard_outside", "flight_link", "truth_dir_outside",
                       "truth_dir_etc", "truth_file_outside", "truth_file_inside", "truth_fifo", "truth_subfolder",
                       "truth_loop", "transforms_fifo", "dark_outside", "cube_loop", "truth_file_loop"])
    f = rng.choice([case["A"], case["B"]])
    outside = case["outside"]
    if kind in ("cube_loop", "truth_file_loop"):
        p = f / ("images/v1.hdr" if kind == "cube_loop" else "truth/images/v2.img")
        p.unlink()
        p.symlink_to(p.name)
        return Mutation(f"{p.relative_to(f)} a loop of links", "invalid")
    if kind in ("cube_inside", "cube_outside", "truth_file_outside", "truth_file_inside", "dark_outside"):
        rel = {"truth_file_outside": "truth/depth/v1.npy", "truth_file_inside": "truth/depth/v1.npy",
               "dark_outside": "calibration/dark_01.img"}.get(kind, "images/v1.img")
        where = f / "store" if kind.endswith("inside") else outside / f"{f.name}_{kind}"
        where.mkdir(parents=True, exist_ok=True)
        os.replace(f / rel, where / Path(rel).name)
        (f / rel).symlink_to(where / Path(rel).name)
        return Mutation(f"{rel} a link {'inside' if kind.endswith('inside') else 'outside'} the flight",
                        "valid" if kind.endswith("inside") else "invalid")
    if kind == "hard_outside":
        os.link(f / "images/v2.img", outside / f"hard_{f.name}_v2.img")
        return Mutation("a cube hard-linked outside the flight", "valid")
    if kind == "flight_link":
        link = case["dir"] / "flight_link"
        link.symlink_to(case["B"], target_is_directory=True)
        return Mutation("a flight given as a link to its folder", "valid", args=[case["A"], link])
    sub = f / "truth/depth"
    if kind in ("truth_dir_outside", "truth_dir_etc", "truth_loop"):
        target = {"truth_dir_outside": outside / "depth", "truth_dir_etc": Path("/etc"),
                  "truth_loop": sub}[kind]
        if kind == "truth_dir_outside":
            shutil.move(str(sub), str(target))
        else:
            shutil.rmtree(sub)
        sub.symlink_to(target, target_is_directory=True)
        return Mutation(f"truth/depth a link to {kind}", "invalid")
    if kind == "truth_fifo":
        os.mkfifo(sub / "v9.npy")
        return Mutation("a pipe in truth/depth", "invalid")
    if kind == "truth_subfolder":
        (sub / "more").mkdir()
        return Mutation("a folder in truth/depth", "invalid")
    (f / "transforms.json").rename(f / "t.json")
    os.mkfifo(f / "transforms.json")
    return Mutation("transforms.json a pipe", "invalid")


def mut_flights(rng: random.Random, case: dict) -> Mutation:
    kind = rng.choice(["file", "loop", "missing", "twice", "one", "three", "wavelengths", "camera", "fwhm",
                       "no_truth", "other_materials"])
    d, a, b = case["dir"], case["A"], case["B"]
    if kind == "file":
        (d / "flight.txt").write_text("not a flight")
        return Mutation("a flight that is a file", "invalid", args=[a, d / "flight.txt"])
    if kind == "loop":
        (d / "loop").symlink_to(d / "loop")
        return Mutation("a flight that is a loop of links", "invalid", args=[a, d / "loop"])
    if kind in ("missing", "twice", "one"):
        args = {"missing": [a, d / "nowhere"], "twice": [a, a], "one": [a]}[kind]
        return Mutation(f"flights: {kind}", "invalid", args=args)
    if kind == "three":
        c = make_flight(d / "C", (20.0, 100.0), 3)
        return Mutation("three flights", "valid", args=[a, b, c])
    meta = _meta(b)
    if kind == "no_truth":
        shutil.rmtree(b / "truth")
        return Mutation("one flight without truth", "valid")
    if kind == "other_materials":
        (b / "truth/materials.json").write_text("{}")
        return Mutation("flights with other materials tables", "valid")
    if kind == "wavelengths":
        meta["wavelengths_nm"] = [w + 2.0 for w in meta["wavelengths_nm"]]
        for hdr in list((b / "images").glob("*.hdr")) + list((b / "calibration").glob("*.hdr")):
            hdr.write_text("\n".join(ln for ln in hdr.read_text().splitlines() if not ln.startswith("wavelength")))
    elif kind == "camera":
        meta["fl_x"] *= 1.1
    else:
        meta["fwhm_nm"] = [6.0] * BANDS
    _put(b, meta)
    return Mutation(f"flights with other {kind}", "invalid")


def mut_output(rng: random.Random, case: dict) -> Mutation:
    kind = rng.choice(["dangling", "link_to_empty", "file", "full", "empty", "inside", "new_parents", "long_name"])
    d, out = case["dir"], case["out"]
    if kind in ("inside", "new_parents", "long_name"):
        return {"inside": Mutation("OUT inside a flight", "invalid", out=case["A"] / "merged"),
                "new_parents": Mutation("OUT below new folders", "valid", out=d / "new" / "deeper" / "out"),
                "long_name": Mutation("OUT a name of 300 characters", "invalid", out=d / ("o" * 300))}[kind]
    if kind in ("full", "empty"):
        out.mkdir()
        if kind == "empty":
            return Mutation("OUT an empty folder", "valid")
        (out / "x.txt").write_text("mine")
    elif kind == "file":
        out.write_text("mine")
    else:
        (d / "empty").mkdir()
        out.symlink_to(d / ("nowhere" if kind == "dangling" else "empty"))
    return Mutation(f"OUT {kind}", "invalid")


def mut_interrupt(rng: random.Random, case: dict) -> Mutation:
    at = rng.randrange(0, 40)
    exc = rng.choice([KeyboardInterrupt(), OSError(28, "No space left on device"), OSError(5, "Input/output error")])
    rc = 130 if isinstance(exc, KeyboardInterrupt) else 3
    return Mutation(f"{type(exc).__name__} at file {at}", f"rc {rc}", interrupt=(at, exc))


def mut_none(rng: random.Random, case: dict) -> Mutation:
    return Mutation("two valid flights", "valid")


MUTATORS = (mut_names, mut_links, mut_flights, mut_output, mut_interrupt, mut_none)


# ------------------------------------------------------------------------------------------ one case
def merged_problems(out: Path, flights: list[Path]) -> list[str]:
    """What is wrong with a merged scene: it must read, and each frame's cube (header and data) and truth
    files must hold the bytes of its own flight's."""
    from brfgs.data import read_scene

    problems = []
    merged = read_scene(out)
    sources = [(f, Path(fm["file_path"]).stem) for f in flights for fm in _meta(f)["frames"]]
    if len(sources) != len(merged.frames):
        return [f"{len(merged.frames)} merged frames for {len(sources)}"]
    truth = all((f / "truth").is_dir() for f in flights) and (out / "truth").is_dir()
    for frame, (flight, name) in zip(merged.frames, sources):
        src = (flight / next(fm["file_path"] for fm in _meta(flight)["frames"]
                             if Path(fm["file_path"]).stem == name)).resolve()
        pairs = [(frame.path, src), (frame.path.with_suffix(".img"), src.with_suffix(".img"))]
        if truth:
            pairs += [(out / "truth/images" / f"{frame.name}.hdr", flight / "truth/images" / f"{name}.hdr")]
            pairs += [(out / "truth" / s / f"{frame.name}.npy", flight / "truth" / s / f"{name}.npy")
                      for s in ("depth", "materials", "sun_visibility")]
        for got, want in pairs:
            if not got.is_file() or got.read_bytes() != want.read_bytes():
                problems.append(f"{got.relative_to(out)} is not {want}")
    return problems


def _stage_left(case: Path) -> bool:
    from brfgs.workflows.merge_files import STAGE_PREFIX

    return any(n.startswith(STAGE_PREFIX) for _, dirs, files in os.walk(case) for n in dirs + files)


@dataclass
class Outcome:
    mutation: Mutation
    rc: int
    stderr: str
    traceback: str | None
    changed: list[str]
    leftovers: list[str]
    merged: list[str]

    def problems(self) -> list[str]:
        out = []
        if self.traceback is not None:
            out.append("traceback")
        elif self.rc not in (0, 2, 3, 130):
            out.append(f"exit {self.rc}")
        if self.rc in (2, 3):
            lines = self.stderr.strip().splitlines()
            if len(lines) != 1 or not lines[0].startswith("brfgs: error: ") or "Traceback" in self.stderr:
                out.append("error not one line")
        want = {"valid": 0, "invalid": 2}.get(self.mutation.expected)
        want = int(self.mutation.expected.split()[1]) if want is None else want
        if self.rc != want and self.traceback is None:
            out.append(f"exit {self.rc}, expected {want}")
        out += [f"changed outside OUT: {p}" for p in self.changed[:3]]
        out += [f"left after a failed merge: {p}" for p in self.leftovers]
        out += [f"merged scene: {p}" for p in self.merged[:3]]
        return out


def run_case(seed: int, bases: tuple[Path, Path], work: Path, mutator=None) -> Outcome:
    """Copy the two base flights, add decoys hard-linked into them, mutate (by ``seed``; with ``mutator``
    when given, else one drawn), run ``brfgs merge`` on them, report what happened."""
    from brfgs.cli import main
    from brfgs.workflows import merge_files

    rng = random.Random(seed)
    top = work / f"case{seed}"
    shutil.rmtree(top, ignore_errors=True)
    case = {"dir": top, "A": top / "flights" / "A", "B": top / "flights" / "B", "outside": top / "outside",
            "out": top / "out"}
    for k, base in zip("AB", bases):
        shutil.copytree(base, case[k])
    case["outside"].mkdir()
    os.link(case["A"] / "images/v0.img", case["outside"] / "decoy_v0.img")     # one inode, in and outside
    os.link(case["B"] / "truth/sigma.json", case["outside"] / "decoy_sigma.json")
    mutation = (mutator or rng.choice(MUTATORS))(rng, case)
    out = mutation.out or case["out"]
    flights = mutation.args or [case["A"], case["B"]]
    before = snapshot(top)
    try:
        was_empty_dir = out.is_dir() and not out.is_symlink() and not any(out.iterdir())
    except OSError:                     # a name too long for the file system
        was_empty_dir = False
    real_place, calls = merge_files.place_file, [0]

    def place(*a, **kw):
        if calls[0] == mutation.interrupt[0]:
            raise mutation.interrupt[1]
        calls[0] += 1
        return real_place(*a, **kw)

    if mutation.interrupt:
        merge_files.place_file = place
    err, tb = io.StringIO(), None
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(["merge", str(out), *map(str, flights)])
        except BaseException:  # a traceback is a failure of its own kind
            rc, tb = -1, traceback.format_exc()
        finally:
            merge_files.place_file = real_place
    ok = rc == 0
    out_rel = os.path.relpath(out, top)
    changed = changes_outside(before, snapshot(top), out_rel, ok)
    leftovers = (["staging folder"] if _stage_left(top) else [])
    if not ok and os.path.lexists(out) and not (was_empty_dir or out_rel in before):
        leftovers.append("OUT")
    merged = []
    if ok:
        try:
            merged = merged_problems(out, flights)
        except Exception as exc:  # noqa: BLE001 - any failure to read it back is a problem to report
            merged = [f"unreadable ({exc})"]
    shutil.rmtree(top, ignore_errors=True)
    return Outcome(mutation, rc, err.getvalue(), tb, changed, leftovers, merged)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--show-failures", type=int, default=20)
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="brfgs-fuzz-merge-"))
    bases = make_bases(work / "base")
    counts, problems, failures = Counter(), Counter(), []
    t0 = time.perf_counter()
    for k in range(args.cases):
        o = run_case(args.seed * 1_000_003 + k, bases, work)
        counts[f"exit {o.rc}" if o.rc in (0, 2, 3, 130) else "other"] += 1
        counts[f"expected {o.mutation.expected}"] += 1
        for p in o.problems():
            problems[p.split(":")[0]] += 1
            if len(failures) < args.show_failures:
                failures.append(f"{p}: {o.mutation.what}: {(o.traceback or o.stderr).strip().splitlines()[-1:]}")
    dt = time.perf_counter() - t0
    print(f"{args.cases} cases in {dt:.0f} s (seed {args.seed})")
    for k, v in sorted(counts.items()):
        print(f"  {k}: {v}")
    print("problems:", dict(problems) if problems else "none")
    for f in failures:
        print("  ", f)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
