"""Property-based fuzzing of brfgs's inputs (scripts/fuzz_inputs.py): for mutated scenes (through
`brfgs inspect`), COLMAP sidecars (`brfgs import colmap`, then `inspect`), GeoJSON ROIs (`brfgs brf`) and sun
options (`brfgs render` / `brf`), a command exits 0 only on valid input, otherwise 2 with one line naming
the file or the option, never a traceback, and the input stays unchanged. The long run is recorded in
docs/reliability.md."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scripts_loader import load_script

fuzz = load_script("fuzz_inputs")


@pytest.fixture(scope="module")
def bases(tmp_path_factory):
    """The base input of every surface, made once: {make_base: folder}."""
    root = tmp_path_factory.mktemp("fuzz")
    out = {}
    for make_base, *_ in fuzz.SURFACES.values():
        if make_base not in out:
            out[make_base] = make_base(root / f"base_{make_base.__name__}")
    return out


@settings(max_examples=100, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1))
def test_mutated_scenes_give_exit_0_or_a_one_line_error(bases, tmp_path, seed):
    outcome = fuzz.run_case(seed, bases[fuzz.make_base_scene], tmp_path)
    assert outcome.problems() == [], (outcome.mutation, outcome.stderr, outcome.traceback)


CLASSES = [(name, m) for name, (_, _, mutators, _) in fuzz.SURFACES.items() for m in mutators]


@pytest.mark.parametrize("surface, mutator", CLASSES, ids=[f"{s}-{m.__name__}" for s, m in CLASSES])
def test_every_mutation_class(bases, tmp_path, surface, mutator):
    """Each mutation class of every surface, a few draws, so that no class is left to chance."""
    make_base, run_case, _, _ = fuzz.SURFACES[surface]
    for seed in range(4 if surface == "scene" else 3):
        outcome = run_case(seed, bases[make_base], tmp_path, mutator)
        assert outcome.problems() == [], (outcome.mutation, outcome.stderr, outcome.traceback)
