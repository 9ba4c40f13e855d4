"""Property-based fuzzing of scene input (scripts/fuzz_inputs.py): for mutated transforms.json,
ENVI headers, cube files and links, `brfgs inspect` exits 0 only on valid input, otherwise 2 with
one line naming a file, never a traceback, and the scene folder stays unchanged. The long run
(5,000 cases) is recorded in docs/reliability.md."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

_spec = importlib.util.spec_from_file_location("fuzz_inputs", Path(__file__).resolve().parents[1] / "scripts" / "fuzz_inputs.py")
fuzz = importlib.util.module_from_spec(_spec)
sys.modules["fuzz_inputs"] = fuzz  # dataclasses look their module up there
_spec.loader.exec_module(fuzz)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return fuzz.make_base_scene(tmp_path_factory.mktemp("fuzz") / "base")


@settings(max_examples=250, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1))
def test_mutated_scenes_give_exit_0_or_a_one_line_error(base, tmp_path, seed):
    outcome = fuzz.run_case(seed, base, tmp_path)
    assert outcome.problems() == [], (outcome.mutation, outcome.stderr, outcome.traceback)


@pytest.mark.parametrize("mutator", fuzz.MUTATORS, ids=lambda m: m.__name__)
def test_every_mutation_class(base, tmp_path, mutator):
    """Each mutation class, a dozen draws, so that no class is left to chance."""
    for seed in range(12):
        outcome = fuzz.run_case(seed, base, tmp_path, mutator)
        assert outcome.problems() == [], (outcome.mutation, outcome.stderr, outcome.traceback)
