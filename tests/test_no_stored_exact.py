"""No test compares a result with numbers stored from another run by exact equality (tests/stored_exact.py):
float results round differently on another CPU, so the suite passes on any x86-64 machine only if
bit-for-bit comparisons stay between two runs on the same machine."""

from __future__ import annotations

from pathlib import Path

import pytest

from stored_exact import StoredExact, check_file

TESTS = Path(__file__).resolve().parent

# The form tests/test_format1_runs.py had: a model trained here compared bit for bit with the one
# brfgs 0.1.0 stored (trained on another CPU).
OLD_FORMAT1 = '''
from pathlib import Path
import torch
from brfgs.cli import main
from brfgs.model.io import load

DATA = Path(__file__).parent / "data" / "format1"


def test_an_interrupted_run_resumes_to_the_uninterrupted_model(scene, tmp_path):
    run = _copy("interrupted", tmp_path)
    assert main(["train", str(scene), str(run), *OPTIONS, "--no-evaluate"]) == 0
    ta, tb = load(run / "model.safetensors")[0], load(DATA / "finished" / "model.safetensors")[0]
    assert ta.keys() == tb.keys()
    assert [k for k in ta if not torch.equal(ta[k], tb[k])] == []


def test_a_format_1_config_reruns(scene, tmp_path):
    out = tmp_path / "again"
    assert main(["train", str(scene), str(out), "--config", str(DATA / "finished" / "config.json")]) == 0
    ta, tb = load(out / "model.safetensors")[0], load(DATA / "finished" / "model.safetensors")[0]
    assert [k for k in ta if not torch.equal(ta[k], tb[k])] == []
'''


def lines(source: str) -> list[int]:
    return [int(f.split()[1].rstrip(":")) for f in StoredExact(source).findings]


@pytest.mark.parametrize("path", sorted(TESTS.glob("*.py")), ids=lambda p: p.name)
def test_no_test_compares_stored_numbers_exactly(path):
    assert check_file(path) == []


def test_the_old_format_1_test_is_caught(tmp_path):
    old = tmp_path / "test_format1_runs.py"
    old.write_text(OLD_FORMAT1)
    found = check_file(old)
    assert [f.split(":")[1].strip() for f in found] == ["line 15", "line 22"]
    assert all("equal() of data stored" in f for f in found)


def test_two_runs_of_this_machine_may_be_compared_bit_for_bit():
    src = '''
import torch
def test_resume(tmp_path):
    a = train(tmp_path / "a")
    b = train(tmp_path / "b")
    assert torch.equal(a, b) and a == b
'''
    assert lines(src) == []


def test_array_equal_with_a_committed_array_file():
    src = '''
from pathlib import Path
import numpy as np
REF = Path(__file__).parent / "data" / "ref.npy"
def test_it():
    ref = np.load(REF)
    out = compute()
    np.testing.assert_array_equal(out, ref)
    assert np.array_equal(ref, out)
    np.testing.assert_allclose(out, ref, rtol=0, atol=0)
    np.testing.assert_allclose(out, ref, rtol=1e-6, atol=0)
'''
    assert lines(src) == [8, 9, 10]


def test_equality_with_numbers_read_from_a_committed_file():
    src = '''
import json
from pathlib import Path
ROOT = Path(__file__).resolve().parents[1]
def test_it():
    want = json.loads((ROOT / "benchmarks" / "demo.json").read_text())
    got = run_demo()
    assert got["margin_db"] == want["margin_db"]
    assert want["mode"] == "adc" and want["steps"] == 12 and len(want) == 3
    assert want["margin_db"] != 0.19
'''
    assert lines(src) == [8, 10]


def test_code_read_through_file_is_not_stored_data():
    src = '''
from pathlib import Path
SRC = Path(__file__).resolve().parents[1] / "src" / "brfgs"
def test_it():
    names = sorted(p.stem for p in SRC.rglob("*.py"))
    assert names == other_names()
'''
    assert lines(src) == []


def test_a_digest_compared_with_a_hard_coded_one():
    src = '''
import hashlib
def test_it(tmp_path):
    out = render(tmp_path)
    assert hashlib.sha256(out.read_bytes()).hexdigest() == "9f86d081884c7d65"
    assert hashlib.sha256(out.read_bytes()).hexdigest() == hashlib.sha256(render(tmp_path).read_bytes()).hexdigest()
'''
    assert lines(src) == [5]


def test_stored_data_passed_through_a_fixture_or_a_helper():
    src = '''
from pathlib import Path
import pytest, torch
DATA = Path(__file__).parent / "data"
@pytest.fixture
def stored():
    return load(DATA / "model.safetensors")
def same(a, b):
    return torch.equal(a, b)
def test_fixture(stored):
    assert torch.equal(train(), stored)
def test_helper():
    assert same(train(), load(DATA / "model.safetensors"))
'''
    assert lines(src) == [9, 11]


def test_a_comparison_exact_on_every_cpu_says_why():
    src = '''
import json
from pathlib import Path
DATA = Path(__file__).parent / "data"
def test_it():
    split = json.loads((DATA / "split.json").read_text())
    assert result()["test"] == split["test"]  # exact across CPUs: frame names, no arithmetic
    assert result()["train"] == split["train"]  # exact across CPUs:
'''
    assert lines(src) == [8]
