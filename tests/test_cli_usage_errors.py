"""Option-parse errors of every command are one line `brfgs: error: --option: ...` with exit status 2 (not
the option parser's multi-line box), numbers are written with the digits 0-9, and --help still exits 0."""

import pytest

from brfgs.cli import main


def one_line(capsys) -> str:
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("brfgs: error: ") and "Traceback" not in err, err
    assert "╭" not in err and "Usage:" not in err + cap.out, err
    return err


@pytest.mark.parametrize("args, flag", [
    (["render", "RUN", "--view-zenith", "10", "--view-azimuth", "0", "--sun-zenith", "abc"], "--sun-zenith"),
    (["render", "RUN", "--view-zenith", "10", "--view-azimuth", "0", "--sun-azimuth", "x"], "--sun-azimuth"),
    (["brf", "RUN", "--roi", "polygon:0,0;1,0;1,1", "--sun-azimuth", "x"], "--sun-azimuth"),
    (["brf", "RUN", "--roi", "polygon:0,0;1,0;1,1", "--sun-zenith", ""], "--sun-zenith"),
    (["kernels", "--sun-zenith", "thirty"], "--sun-zenith"),
    (["train", "SCENE", "OUT", "--stage1-steps", "many"], "--stage1-steps"),
    (["inspect", "SCENE", "--downscale", "2.5"], "--downscale"),
])
def test_a_value_the_option_parser_refuses_is_one_line(tmp_path, capsys, args, flag):
    args = [str(tmp_path / a) if a in ("RUN", "SCENE", "OUT") else a for a in args]
    assert main(args) == 2
    err = one_line(capsys)
    assert err.startswith(f"brfgs: error: {flag}: "), err


@pytest.mark.parametrize("value", ["\u0661\u0666", "\uff13\uff10", "1_0", "nan", "inf", "1e400", " 30", "30\u00b0"])
def test_numbers_are_written_with_the_digits_0_to_9(tmp_path, capsys, value):
    assert main(["kernels", "--sun-zenith", value, "--out", str(tmp_path / "k")]) == 2
    assert one_line(capsys).startswith("brfgs: error: --sun-zenith: ")
    assert not (tmp_path / "k").exists()


@pytest.mark.parametrize("args, words", [
    (["inspect"], "missing argument"),
    (["inspect", "S", "--bogus", "1"], "no such option: --bogus"),
    (["bogus-command"], "no such command"),
    (["kernels", "--sun-zenith"], "--sun-zenith"),
    (["import", "colmap"], "missing argument"),
])
def test_usage_errors_are_one_line(capsys, args, words):
    assert main(args) == 2
    assert words in one_line(capsys).lower()


def test_help_and_version_still_exit_0(capsys):
    assert main(["render", "--help"]) == 0
    assert "--sun-zenith" in capsys.readouterr().out
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("brfgs ")


def test_comma_separated_numbers_are_written_with_the_digits_0_to_9(tmp_path, capsys):
    args = ["brf", str(tmp_path / "RUN"), "--roi", "polygon:0,0;\u0661,0;1,1"]
    assert main(args) == 2
    assert "--roi" in one_line(capsys)
    args = ["render", str(tmp_path / "RUN"), "--view-zenith", "10", "--view-azimuth", "0", "--target", "1_0,2,3"]
    assert main(args) == 2
    assert "--target" in one_line(capsys)
