"""Fuzzing of `brfgs merge` (scripts/fuzz_merge.py): for flights with colliding names, glob characters,
links in and out of them, linked truth folders, dark-frame clashes, flights that are files, loops or
missing, long names, other cameras or bands, hostile output paths and failures mid-merge, the merge
exits 0 only on valid input, otherwise 2 with one line (3 for a storage error, 130 for an interrupt),
never a traceback; nothing outside OUT changes; a failed merge leaves no OUT and no staging folder; a
merged scene holds each source's own bytes. The long run is recorded in docs/reliability.md."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scripts_loader import load_script

fuzz = load_script("fuzz_merge")


@pytest.fixture(scope="module")
def bases(tmp_path_factory):
    return fuzz.make_bases(tmp_path_factory.mktemp("fuzz_merge"))


@settings(max_examples=24, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1))
def test_mutated_merges_give_exit_0_or_a_one_line_error(bases, tmp_path, seed):
    outcome = fuzz.run_case(seed, bases, tmp_path)
    assert outcome.problems() == [], (outcome.mutation, outcome.stderr, outcome.traceback)


@pytest.mark.parametrize("mutator", fuzz.MUTATORS, ids=lambda m: m.__name__)
def test_every_mutation_class(bases, tmp_path, mutator):
    """Each mutation class, a few draws, so that no class is left to chance."""
    for seed in range(4):
        outcome = fuzz.run_case(seed, bases, tmp_path, mutator)
        assert outcome.problems() == [], (outcome.mutation, outcome.stderr, outcome.traceback)


def test_the_checks_see_a_file_changed_outside_out(bases, tmp_path):
    """The harness's own check: a file written outside OUT, or a link added to it, is reported."""
    case = tmp_path / "c"
    (case / "a").mkdir(parents=True)
    (case / "a" / "x").write_text("1")
    before = fuzz.snapshot(case)
    (case / "a" / "x").write_text("2")
    assert fuzz.changes_outside(before, fuzz.snapshot(case), "out", True) == ["a/x"]
    before = fuzz.snapshot(case)
    (case / "out").mkdir()
    (case / "out" / "x").hardlink_to(case / "a" / "x")
    assert fuzz.changes_outside(before, fuzz.snapshot(case), "out", True) == []
    (case / "y").hardlink_to(case / "a" / "x")
    assert "a/x" in fuzz.changes_outside(before, fuzz.snapshot(case), "out", True)
