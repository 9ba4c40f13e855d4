"""``brfgs --version`` prints the package's version, which pyproject.toml takes from brfgs.__version__."""

from __future__ import annotations

import re
from pathlib import Path

import brfgs
from brfgs.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_version_option_prints_the_package_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"brfgs {brfgs.__version__}"
    assert re.fullmatch(r"\d+\.\d+\.\d+", brfgs.__version__)


def test_pyproject_takes_its_version_from_the_package():
    text = (ROOT / "pyproject.toml").read_text()
    assert 'dynamic = ["version"]' in text and 'attr = "brfgs.__version__"' in text
