"""The sun options: mutated text for ``--sun-zenith`` / ``--sun-azimuth`` of ``brfgs render`` and
``brfgs brf`` on the tiny model of model.py. Valid: a number written with the digits 0-9 (sign, point,
exponent), the zenith in [0, 89], the azimuth any finite number for render and in [-360, 360] for brf;
anything else is one line naming the option."""

from __future__ import annotations

import os
import random
import shutil
from pathlib import Path

from fuzz.common import Mutation, Outcome, run_cli, snapshot
from fuzz.model import brf_args, render_args

ZENITH_VALID = ("0", "35", "89", "45.5", "+10", ".5", "1e1", "8.9E1", "-0", "0089", "30.")
ZENITH_OUT = ("89.5", "90", "-1", "-0.001", "1e2", "360", "1e308")
AZIMUTH_VALID = ("-360", "360", "150", "-45.5", "0", "1e2", "+90")
AZIMUTH_WRAPS = ("720", "-1000", "1e5")          # render wraps them; brf refuses beyond ±360
GARBAGE = ("abc", "", " ", "nan", "NaN", "inf", "-inf", "Infinity", "1e400", "-1e999", "\u0661\u0666", "1_0", " 30",
           "30 ", "0x1e", "30\u00b0", "3,0", "1e", ".", "+", "e5", "\u0663\u0660", "\uff13\uff10", "\u00b2",
           "30\u0000", "30\n", "\u202e30", "1" * 40, "--", "--help", "true", "[30]", "30deg", "½")


def mut_sun_value(rng: random.Random, folder: Path) -> tuple[Mutation, str, str, str]:
    """(mutation, command, flag, value text)."""
    command = rng.choice(["render", "brf"])
    flag = rng.choice(["--sun-zenith", "--sun-azimuth"])
    group = rng.choice(["valid", "valid", "out", "garbage", "garbage"])
    if flag == "--sun-zenith":
        value = rng.choice({"valid": ZENITH_VALID, "out": ZENITH_OUT, "garbage": GARBAGE}[group])
        ok = group == "valid"
    else:
        value = rng.choice({"valid": AZIMUTH_VALID, "out": AZIMUTH_WRAPS, "garbage": GARBAGE}[group])
        ok = group == "valid" or (group == "out" and command == "render")
    if value == "--help":
        return Mutation(f"{command} {flag} {value!r}", "invalid", names=flag), command, flag, value
    return Mutation(f"{command} {flag} {value!r}", "valid" if ok else "invalid", names=flag), command, flag, value


def mut_sun_shape(rng: random.Random, folder: Path) -> tuple[Mutation, str, str, str | None]:
    """The option without a value, given twice, or with a value that looks like another option."""
    command, flag = rng.choice(["render", "brf"]), rng.choice(["--sun-zenith", "--sun-azimuth"])
    kind = rng.choice(["missing", "twice", "equals", "equals_empty"])
    if kind == "missing":
        return Mutation(f"{command} {flag} without a value", "invalid", names=flag), command, flag, None
    if kind == "twice":
        return Mutation(f"{command} {flag} twice", "valid"), command, flag, "30|40"
    value = "30" if kind == "equals" else ""
    return Mutation(f"{command} {flag}={value!r}", "valid" if value else "invalid", names=flag), command, \
        f"{flag}={value}", ""


MUTATORS = (mut_sun_value, mut_sun_shape)


def _argv(command: str, run: Path, out: Path, flag: str, value: str | None) -> list[str]:
    base = render_args(run, out) if command == "render" else brf_args(run, "polygon:-4,-4;4,-4;4,4;-4,4", out)
    if value is None:                      # the option last, without its value
        return base + [flag]
    if "|" in value:
        a, b = value.split("|")
        return base + [flag, a, flag, b]
    return base + ([flag] if not value and "=" in flag else [flag, value])


def run_case(seed: int, base: Path, work: Path, mutator=None) -> Outcome:
    """Run ``brfgs render`` or ``brfgs brf`` with a mutated sun option on a run folder holding (a hard
    link to) the model of ``base``; the model must stay unchanged."""
    rng = random.Random(seed)
    case = work / f"case{seed}"
    shutil.rmtree(case, ignore_errors=True)
    (case / "run").mkdir(parents=True)
    os.link(base / "model.safetensors", case / "run" / "model.safetensors")
    mutation, command, flag, value = (mutator or rng.choice(MUTATORS))(rng, case)
    before = snapshot(base)
    rc, err, tb = run_cli(_argv(command, case / "run", case / "out", flag, value))
    outcome = Outcome(mutation, rc, err, tb, snapshot(base) != before)
    shutil.rmtree(case, ignore_errors=True)
    return outcome
