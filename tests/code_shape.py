#!/usr/bin/env python3
"""List code-shape violations in src/brfgs: files over 500 lines, functions over 80 lines or
over 12 parameters. Numba kernels (decorated with ``njit``/``jit``) are exempt; command-line
functions (Typer commands in ``cli/``) are exempt from the parameter count only (each option is a
parameter). Exit 1 when anything is listed.

    python3 tests/code_shape.py [SRC_DIR]
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 80
MAX_PARAMETERS = 12


def _decorator_names(node: ast.FunctionDef) -> set[str]:
    names = set()
    for d in node.decorator_list:
        d = d.func if isinstance(d, ast.Call) else d
        names.add(d.attr if isinstance(d, ast.Attribute) else getattr(d, "id", ""))
    return names


def _n_params(node: ast.FunctionDef) -> int:
    a = node.args
    n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    if a.args and a.args[0].arg in ("self", "cls"):
        n -= 1
    return n


def _is_cli_command(path: Path, node: ast.FunctionDef) -> bool:
    """A Typer command: a function in cli/ whose parameters default to typer.Argument/Option."""
    if "cli" not in path.parts:
        return False
    defaults = node.args.defaults + [d for d in node.args.kw_defaults if d is not None]
    return any(isinstance(d, ast.Call) and getattr(d.func, "attr", "") in ("Argument", "Option") for d in defaults)


def violations(src: Path) -> list[str]:
    """One line per violation under ``src``."""
    out = []
    for path in sorted(src.rglob("*.py")):
        text = path.read_text()
        n_lines = text.count("\n")
        rel = path.relative_to(src.parent)
        if n_lines > MAX_FILE_LINES:
            out.append(f"{rel}: {n_lines} lines (max {MAX_FILE_LINES})")
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if _decorator_names(node) & {"njit", "jit"}:
                continue
            length = node.end_lineno - node.lineno + 1
            if length > MAX_FUNCTION_LINES and node.name != "register":
                out.append(f"{rel}:{node.lineno} {node.name}: {length} lines (max {MAX_FUNCTION_LINES})")
            if _n_params(node) > MAX_PARAMETERS and not _is_cli_command(path, node):
                out.append(f"{rel}:{node.lineno} {node.name}: {_n_params(node)} parameters (max {MAX_PARAMETERS})")
    return out


def main(argv: list[str]) -> int:
    src = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parents[1] / "src" / "brfgs"
    found = violations(src)
    for line in found:
        print(line)
    print(f"{len(found)} code-shape violation(s) in {src}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
