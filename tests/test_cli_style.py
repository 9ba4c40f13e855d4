"""One command-line style: every command's options come from its options dataclass (defaults and help in
one place), every help text is in product terms, and a bad value is one line with exit status 2."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import typer.main

from brfgs.cli import app, main

CLI = Path(__file__).resolve().parents[1] / "src" / "brfgs" / "cli"
HISTORY = re.compile(r"Session \d|Sessions \d|\bS\d\d\b|issue \d|issue #\d|#\d\d")


def _commands() -> dict:
    """{'train': ..., 'bench view': ..., 'import colmap': ...}: every leaf command."""
    out = {}

    def walk(cmd, prefix):
        if hasattr(cmd, "commands"):
            for name, sub in cmd.commands.items():
                walk(sub, prefix + [name])
        else:
            out[" ".join(prefix)] = cmd

    walk(typer.main.get_command(app), [])
    return out


def test_no_command_declares_an_option_by_hand():
    """Options are generated from dataclasses by brfgs.cli._config; only the root's --version is not."""
    for path in CLI.glob("*.py"):
        if path.name in ("_config.py", "__init__.py"):
            continue
        assert "typer.Option(" not in path.read_text(), path.name


def test_every_option_default_is_its_dataclass_default():
    """A generated option's click default is None ("not given"): the command fills in the dataclass's
    default, so no default is repeated in the command line."""
    for name, cmd in _commands().items():
        for p in cmd.params:
            if getattr(p, "param_type_name", "") == "option" and not p.is_eager and p.name not in ("help",):
                assert p.default is None or p.required, (name, p.name, p.default)


@pytest.mark.parametrize("name", sorted(_commands()))
def test_help_is_in_product_terms(name, capsys):
    args = name.split() + ["--help"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "Usage:" in text and not HISTORY.search(text), HISTORY.search(text)
    cmd = _commands()[name]
    if any(getattr(p, "hidden", False) for p in cmd.params):
        assert main(name.split() + ["--help-all"]) == 0
        assert not HISTORY.search(capsys.readouterr().out)


@pytest.mark.parametrize("args, flag", [
    (["render", "RUN", "--view-zenith", "10", "--view-azimuth", "0", "--frames", "1"], "--frames"),
    (["kernels", "--sun-zenith", "95"], "--sun-zenith"),
    (["brf", "RUN", "--roi", "polygon:0,0;1,0;1,1", "--max-zenith", "90"], "--max-zenith"),
    (["products", "RUN", "--min-alpha", "2"], "--min-alpha"),
    (["export", "RUN", "OUT", "--up", "x"], "--up"),
    (["init", "SCENE", "OUT", "--max-features", "1"], "max_features"),
    (["select-bands", "SCENE", "--top", "0"], "--top"),
    (["simulate", "OUT", "--layout", "nowhere"], "--layout"),
    (["view", "RUN", "--height", "5"], "--height"),
    (["bench", "view", "--repeats", "0"], "--repeats"),
    (["compare", "A", "B", "--split", "nowhere"], "--split"),
    (["evaluate", "RUN", "--split", "nowhere"], "--split"),
    (["ablate", "SCENE", "OUT", "--study", "nowhere"], "--study"),
    (["render", "RUN", "--view-zenith", "10", "--view-azimuth", "0", "--target", "1,2"], "--target"),
])
def test_a_bad_value_is_one_line_and_exit_2(tmp_path, capsys, args, flag):
    args = [str(tmp_path / a) if a in ("RUN", "SCENE", "OUT", "A", "B") else a for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and flag in err, err
