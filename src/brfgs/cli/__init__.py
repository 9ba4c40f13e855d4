"""The ``brfgs`` command line: thin commands over the library.

One module per pipeline step lives beside this file (``inspect.py``, ``simulate.py``,
``kernels.py``, ...). Each defines ``register(app)`` that adds its commands to the
Typer app. Command modules import heavy libraries (torch, mitsuba, pycolmap) inside
the command functions so that ``brfgs --help`` stays fast and pycolmap is never
imported before zlib (see brfgs.init).

User errors (:class:`brfgs.errors.UserError`) are printed without traceback and the
process exits with status 2.
"""

from __future__ import annotations

import errno
import importlib
import importlib.util
import os
import sys

# Idle OpenMP threads of numba/torch (GNU libgomp) spin 300 000 times by default before they sleep: on a
# 2-core machine shared with other work that made frames 2-3x slower, while sleeping at once
# (OMP_WAIT_POLICY=PASSIVE) made a quiet machine's 128-px view 25 % slower (the next parallel op waits for
# the threads to wake). A short spin keeps both (BENCHMARKS.md "OpenMP threads"). A user's own
# OMP_WAIT_POLICY or GOMP_SPINCOUNT is left as it is. Must be set before torch loads.
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ.setdefault("GOMP_SPINCOUNT", "1000")

import typer
from typer._click.exceptions import BadParameter, ClickException, MissingParameter  # typer's own click

from brfgs.errors import STORAGE_ERRNOS, UserError

# OSErrors of a path the user gave (a name too long for the file system): exit status 2, one line.
PATH_ERRNOS = {errno.ENAMETOOLONG}

app = typer.Typer(
    name="brfgs",
    help="Hyperspectral BRF modelling with 3D Gaussian splatting (BRF-GS).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

# Command modules in pipeline order; each defines register(app).
COMMAND_MODULES = [
    "brfgs.cli.demo",        # demo: the whole pipeline on a simulated scene
    "brfgs.cli.import_",     # import colmap: COLMAP model + cubes + sidecar -> transforms.json
    "brfgs.cli.inspect",     # inspect: read + validate a scene, summary and polar plot
    "brfgs.cli.simulate",    # simulate: Mitsuba scenes with truth
    "brfgs.cli.bands",       # select-bands: EFC band selection
    "brfgs.cli.init",        # init: SfM / known poses -> sparse points
    "brfgs.cli.kernels",     # kernels: BRDF kernel plots and CSV
    "brfgs.cli.train",       # train / evaluate / ablate
    "brfgs.cli.compare",     # compare: two evaluated models, margins with bootstrap intervals
    "brfgs.cli.analysis",    # render / brf / products / export
    "brfgs.cli.batch",       # batch: train -> evaluate -> products for a manifest of scenes (Ray)
    "brfgs.cli.bench",       # bench: speed and memory benchmarks
    "brfgs.cli.view",        # view: the live web viewer (viser)
]



def _print_version(value: bool) -> None:
    if value:
        from brfgs import __version__

        typer.echo(f"brfgs {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: bool = typer.Option(False, "--version", is_eager=True, callback=_print_version,
                                       help="Print the version and exit.")) -> None:
    """Hyperspectral BRF modelling with 3D Gaussian splatting (BRF-GS)."""


for _name in COMMAND_MODULES:
    # A pipeline step whose module is not part of this build is simply not offered.
    if importlib.util.find_spec(_name) is not None:
        importlib.import_module(_name).register(app)


def usage_error_line(exc: ClickException) -> str:
    """One line for an option-parse error of click: ``--sun-zenith: 'abc' is not a number``, ``no such
    option: --bogus``, ``missing argument 'SCENE'`` (click's own messages, without its usage box)."""
    if isinstance(exc, BadParameter) and not isinstance(exc, MissingParameter):
        hint = exc.param_hint
        if hint is None and exc.param is not None:
            opts = getattr(exc.param, "opts", None) or [exc.param.human_readable_name or ""]
            hint = max(opts, key=len) if opts[0].startswith("-") else opts[0]
        hint = " / ".join(hint) if isinstance(hint, (list, tuple)) else str(hint or "").strip("'\"")
        msg = " ".join(exc.message.split())
        return f"{hint}: {msg}" if hint else msg
    msg = " ".join(exc.format_message().split())
    return msg[:1].lower() + msg[1:] if msg[:2] in ("No", "Mi", "Go") else msg


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``brfgs`` console script; returns the exit status.

    Exit status: 0 success; 2 usage errors (click's option parsing: one line
    ``brfgs: error: --option: message``) and user errors (:class:`UserError`: one line naming the file
    and the field; a path too long for the file system, one line naming it); 3 a file could not be written or read for a storage reason
    (no space left, read-only file system, permission denied, I/O error: one line naming the path;
    results are written under temporary names and renamed into place, so no half file is left);
    130 Ctrl-C (long commands checkpoint before that).
    """
    try:
        rv = app(args=argv, prog_name="brfgs", standalone_mode=False)  # click's errors come here, not its box
    except ClickException as exc:
        if type(exc).__name__ != "NoArgsIsHelpError":  # that one is the help, already shown
            print(f"brfgs: error: {usage_error_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except typer.Abort:
        print("brfgs: interrupted", file=sys.stderr)
        return 130
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except UserError as exc:
        print(f"brfgs: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("brfgs: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        if exc.errno not in STORAGE_ERRNOS | PATH_ERRNOS:
            raise
        where = str(exc.filename or "(unknown path)")
        if len(where) > 300:                                 # the path itself may be what is too long
            where = f"{where[:150]}...{where[-100:]} ({len(where)} characters)"
        print(f"brfgs: error: {where}: {exc.strerror or os.strerror(exc.errno)}", file=sys.stderr)
        return 2 if exc.errno in PATH_ERRNOS else 3
    return rv if isinstance(rv, int) and not isinstance(rv, bool) else 0
