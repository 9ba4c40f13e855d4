"""Band-ratio and index formulas over band wavelengths, parsed without ``eval``.

A formula names bands by wavelength, ``b<nm>`` (e.g. ``b860``, ``b550.5``), and combines them
with numbers, ``+ - * /``, unary minus and parentheses: NDVI is ``(b860-b650)/(b860+b650)``.
The expression is parsed with :mod:`ast` and only those nodes are accepted; anything else
(names, calls, attributes, powers, ...) is a :class:`brfgs.errors.UserError`.
"""

from __future__ import annotations

import ast
import operator
import re
from dataclasses import dataclass

import numpy as np

from brfgs.errors import UserError

__all__ = ["NDVI", "IndexFormula", "parse_formula"]

NDVI = "(b860-b650)/(b860+b650)"
_BAND = re.compile(r"^b(\d+(?:_\d+)?)$")
_OPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}
MAX_FORMULA_CHARS = 200


@dataclass(frozen=True)
class IndexFormula:
    """A parsed formula: its text, the wavelengths it names (nm) and its syntax tree."""

    text: str
    wavelengths_nm: tuple[float, ...]
    tree: ast.Expression

    def evaluate(self, bands: dict[float, np.ndarray]) -> np.ndarray:
        """The formula over ``bands`` {wavelength nm: plane [H, W]}; x/0 (constants included) gives NaN."""
        with np.errstate(all="ignore"):
            out = _eval(self.tree.body, bands)
        out = np.asarray(out, np.float64)
        return np.where(np.isfinite(out), out, np.nan)


def _band_nm(name: str) -> float | None:
    m = _BAND.match(name)
    return float(m.group(1).replace("_", ".")) if m else None


def _check(node: ast.AST, text: str, found: list[float]) -> None:
    if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        _check(node.left, text, found)
        _check(node.right, text, found)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        _check(node.operand, text, found)
    elif isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        pass
    elif isinstance(node, ast.Name) and _band_nm(node.id) is not None:
        found.append(_band_nm(node.id))
    else:
        what = type(node).__name__ if not isinstance(node, ast.Name) else f"name {node.id!r}"
        raise UserError(f"formula {text!r}: {what} is not allowed (use b<nm> bands, numbers, + - * / and "
                        "parentheses, e.g. (b860-b650)/(b860+b650))", field="formula")


def parse_formula(text: str) -> IndexFormula:
    """Parse ``text`` (see the module docstring); UserError naming the formula when it is not one.

    Wavelengths with a decimal point are written ``b550_5`` or ``b550.5`` (the latter rewritten)."""
    t = str(text).strip()
    if not t or len(t) > MAX_FORMULA_CHARS:
        raise UserError(f"a formula must have 1..{MAX_FORMULA_CHARS} characters", field="formula")
    t_py = re.sub(r"\bb(\d+)\.(\d+)", r"b\1_\2", t)
    try:
        tree = ast.parse(t_py, mode="eval")
    except SyntaxError as exc:
        raise UserError(f"formula {t!r} is not an expression: {exc.msg}", field="formula") from None
    except (ValueError, RecursionError, MemoryError):  # e.g. a NUL character, absurd nesting
        raise UserError(f"formula {t!r} is not an expression", field="formula") from None
    found: list[float] = []
    _check(tree.body, t, found)
    if not found:
        raise UserError(f"formula {t!r} names no band (write bands as b<nm>, e.g. b860)", field="formula")
    return IndexFormula(t, tuple(dict.fromkeys(found)), tree)


def _eval(node: ast.AST, bands: dict[float, np.ndarray]):
    if isinstance(node, ast.BinOp):
        return _OPS[type(node.op)](_eval(node.left, bands), _eval(node.right, bands))
    if isinstance(node, ast.UnaryOp):
        v = _eval(node.operand, bands)
        return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.Constant):
        return np.float64(node.value)  # numpy scalars: 0/0 is NaN, 1/0 inf (then NaN), never an exception
    return np.asarray(bands[_band_nm(node.id)], np.float64)
