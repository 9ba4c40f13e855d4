#!/usr/bin/env python3
"""Fuzz brfgs's inputs: every case must end in exit 0 on valid input or in exit 2 with one line
naming the file (or the option), never a traceback, and the input must stay unchanged.

Surfaces (the mutations live in scripts/fuzz/):

- ``scene``: a tiny scene (3 views, 4 bands, 2 dark frames) with one mutation of transforms.json, an
  ENVI header, a data file, a link or a flight's fields, through ``brfgs inspect`` (fuzz/scene.py,
  fuzz/scene_fields.py);
- ``sidecar``: that scene as a COLMAP project with a mutated spectral.json, through ``brfgs import
  colmap`` and then ``brfgs inspect`` (fuzz/sidecar.py);
- ``roi``: mutated GeoJSON ROIs and ``polygon:`` text through ``brfgs brf`` on a tiny model (fuzz/roi.py,
  fuzz/model.py);
- ``sun``: mutated ``--sun-zenith`` / ``--sun-azimuth`` text for ``brfgs render`` and ``brfgs brf``
  (fuzz/sun.py).

Each mutation's expected outcome ("valid", "invalid" or "either") is known by construction.
``tests/test_fuzz_inputs.py`` draws the same cases; the long run's counts are in docs/reliability.md.

    python3 scripts/fuzz_inputs.py --cases 5000 --seed 0 [--surface scene|sidecar|roi|sun|all]
                                   [--work DIR] [--show-failures 20]
"""

from __future__ import annotations

import argparse
import random
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fuzz import roi, sidecar, sun  # noqa: E402
from fuzz.common import Mutation, Outcome, run_cli, snapshot  # noqa: E402,F401
from fuzz.model import make_run  # noqa: E402
from fuzz.scene import (BANDS, H, W, make_base_scene, mut_data, mut_header, mut_links,  # noqa: E402,F401
                        mut_transforms_number, mut_transforms_structure)
from fuzz.scene_fields import mut_cameras, mut_flight_fields  # noqa: E402

MUTATORS = (mut_transforms_number, mut_transforms_structure, mut_header, mut_data, mut_links, mut_flight_fields,
            mut_cameras)


def run_case(seed: int, base: Path, work: Path, mutator=None) -> Outcome:
    """Copy the scene ``base``, mutate it (by ``seed``; with ``mutator`` when given, else one drawn), run
    ``brfgs inspect`` on it, report what happened."""
    rng = random.Random(seed)
    case = work / f"case{seed}"
    shutil.rmtree(case, ignore_errors=True)
    scene = case / "scene"
    shutil.copytree(base, scene)
    mutation = (mutator or rng.choice(MUTATORS))(rng, scene)
    before = snapshot(scene)
    rc, err, tb = run_cli(["inspect", str(scene), "--out", str(case / "inspect"), "--quiet"])
    outcome = Outcome(mutation, rc, err, tb, snapshot(scene) != before)
    shutil.rmtree(case, ignore_errors=True)
    return outcome


# name: (make the base input in a folder, run one case, mutation classes, weight in --surface all)
SURFACES = {
    "scene": (make_base_scene, run_case, MUTATORS, 4),
    "sidecar": (sidecar.make_base_project, sidecar.run_case, sidecar.MUTATORS, 3),
    "roi": (make_run, roi.run_case, roi.MUTATORS, 2),
    "sun": (make_run, sun.run_case, sun.MUTATORS, 1),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--surface", choices=[*SURFACES, "all"], default="all")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--show-failures", type=int, default=20)
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="brfgs-fuzz-"))
    names = list(SURFACES) if args.surface == "all" else [args.surface]
    bases: dict = {}
    draw = random.Random(args.seed)
    counts, problems, failures = Counter(), Counter(), []
    t0 = time.perf_counter()
    for k in range(args.cases):
        name = draw.choices(names, weights=[SURFACES[n][3] for n in names])[0]
        make_base, case, _, _ = SURFACES[name]
        if make_base not in bases:
            bases[make_base] = make_base(work / f"base_{make_base.__name__}")
        o = case(args.seed * 1_000_003 + k, bases[make_base], work)
        counts[(name, "exit 0" if o.rc == 0 else "exit 2" if o.rc == 2 else "other")] += 1
        counts[(name, f"expected {o.mutation.expected}")] += 1
        for p in o.problems():
            problems[p] += 1
            if len(failures) < args.show_failures:
                failures.append(f"{name}: {p}: {o.mutation.what}: {o.last_line[:300]}")
                print("  ", failures[-1], flush=True)
        if (k + 1) % 250 == 0:
            print(f"{k + 1} cases, {time.perf_counter() - t0:.0f} s, problems: {dict(problems)}", flush=True)
    dt = time.perf_counter() - t0
    print(f"{args.cases} cases in {dt:.0f} s (seed {args.seed}, surface {args.surface})")
    for name in names:
        row = {k[1]: v for k, v in counts.items() if k[0] == name}
        print(f"  {name}: {sum(v for k, v in row.items() if k.startswith('exit') or k == 'other')} cases, "
              + ", ".join(f"{k}: {v}" for k, v in sorted(row.items())))
    print("problems:", dict(problems) if problems else "none")
    for f in failures:
        print("  ", f)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
