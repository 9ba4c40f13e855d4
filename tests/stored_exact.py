"""AST check of the test files: no test compares a result with numbers stored from another run
(files under tests/data/ or any other committed file a test reads) by exact equality, and no test
compares a digest with a hard-coded one. Float results round differently on another CPU (vector
width, FMA, BLAS kernels), so only two runs on the same machine may be compared bit for bit;
against stored numbers a test uses a tolerance it justifies, or a reference it computes itself.

What counts as stored: a path built from ``__file__`` to a data folder (data/, benchmarks/, docs/)
or a file of numbers (.json, .npy, .safetensors, .csv, .md, ...), a string naming tests/data/ or
benchmarks/, and everything computed from one (assignments, loops,
``with ... as``, calls of helpers and fixtures that return one, helper parameters that receive one).
What counts as exact: ``==`` / ``!=`` between a stored value and anything but a literal without
floats (a string, an int, ``[]``), unless either side is a shape, dtype, key set, length or name;
``torch.equal``, ``np.array_equal``, ``assert_array_equal``,
``assert_equal``; ``assert_allclose`` / ``assert_close`` with ``rtol=0, atol=0``; a digest (sha256,
hexdigest, crc32, ...) compared with a literal or a stored value. A comparison that is exact on every
CPU (names, counts, strings of a stored file: no arithmetic) carries the comment
``# exact across CPUs: <why>`` on its line.

Usage: ``python tests/stored_exact.py [FILE ...]`` (default: every tests/*.py); exit 1 on a finding.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

EXACT_CALLS = {"equal", "array_equal", "array_equiv", "assert_array_equal", "assert_equal"}
ZERO_TOL_CALLS = {"assert_allclose", "assert_close"}
DIGESTS = {"hexdigest", "digest", "md5", "sha1", "sha224", "sha256", "sha384", "sha512", "blake2b", "blake2s",
           "crc32", "adler32", "file_digest"}
STORED_STRINGS = ("tests/data", "benchmarks/")
# a path built from __file__ is a stored file when it names a data folder or a file of numbers
DATA_PARTS = {"data", "benchmarks", "docs"}
DATA_SUFFIXES = (".json", ".csv", ".npy", ".npz", ".safetensors", ".pt", ".pth", ".bin", ".tif", ".tiff", ".ply",
                 ".h5", ".txt", ".md", ".toml")
# structure, not numbers: shapes, dtypes, key sets, lengths, names
STRUCTURAL_ATTRS = {"shape", "dtype", "ndim", "name", "suffix", "stem"}
STRUCTURAL_CALLS = {"keys", "len", "type", "size", "dim"}
MARK = "# exact across CPUs:"


def _call_name(node: ast.AST) -> str | None:
    if isinstance(node, ast.Call):
        f = node.func
        return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
    return None


def _names_stored_file(node: ast.AST, checkout: set[str]) -> bool:
    """``node`` builds a path from ``__file__`` (or a name in ``checkout``, bound to such a path) to a
    data folder or a file of numbers."""
    walk = list(ast.walk(node))
    if not any(isinstance(n, ast.Name) and (n.id == "__file__" or n.id in checkout) for n in walk):
        return False
    parts = [n.value for n in walk if isinstance(n, ast.Constant) and isinstance(n.value, str)]
    return any(p in DATA_PARTS or p.endswith(DATA_SUFFIXES) or any(f"{d}/" in p for d in DATA_PARTS) for p in parts)


def _structural(node: ast.AST) -> bool:
    """A shape, dtype, key set, length or name: exact on every CPU."""
    return (isinstance(node, ast.Attribute) and node.attr in STRUCTURAL_ATTRS) or _call_name(node) in STRUCTURAL_CALLS


def _literal_without_floats(node: ast.AST) -> bool:
    """A literal written in the test (str, bytes, int, bool, None, f-string, or a container of
    those): comparing a stored value with it is exact on every CPU."""
    if isinstance(node, ast.Constant):
        return not isinstance(node.value, (float, complex))
    if isinstance(node, ast.JoinedStr):
        return True
    if isinstance(node, (ast.List, ast.Tuple, ast.Set)):
        return all(_literal_without_floats(e) for e in node.elts)
    if isinstance(node, ast.Dict):
        return all(k is None or _literal_without_floats(k) for k in node.keys) and \
            all(_literal_without_floats(v) for v in node.values)
    return False


def _targets(target: ast.AST, value: ast.AST | None) -> list[tuple[ast.AST, ast.AST | None]]:
    """(name target, the part of ``value`` it receives): element-wise for ``a, b = x, y``."""
    if isinstance(target, (ast.Tuple, ast.List)):
        if isinstance(value, (ast.Tuple, ast.List)) and len(value.elts) == len(target.elts):
            return [p for t, v in zip(target.elts, value.elts) for p in _targets(t, v)]
        return [p for t in target.elts for p in _targets(t, value)]
    if isinstance(target, ast.Starred):
        return _targets(target.value, value)
    return [(target, value)] if isinstance(target, ast.Name) else []


class StoredExact:
    """The findings of one source file: ``findings`` lists ``"line N: what"``."""

    def __init__(self, source: str, filename: str = "<test>"):
        self.filename = filename
        self.lines = source.splitlines()
        self.tree = ast.parse(source, filename)
        self.functions = {n.name: n for n in ast.walk(self.tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
        self.scopes: list[ast.AST] = [self.tree, *self.functions.values()]
        self.tainted: dict[int, set[str]] = {id(s): set() for s in self.scopes}
        self.returns_stored: set[str] = set()  # helpers and fixtures whose result is stored
        self.checkout: set[str] = set()  # names bound to a path built from __file__ (ROOT, HERE, ...)
        for node in ast.walk(self.tree):
            if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None and any(
                    isinstance(n, ast.Name) and n.id == "__file__" for n in ast.walk(node.value)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                self.checkout.update(t.id for t in targets if isinstance(t, ast.Name))
        self._propagate()
        self.findings = sorted(set(self._findings()), key=lambda s: int(s.split()[1].rstrip(":")))

    # ------------------------------------------------------------------ taint
    def _own_nodes(self, scope: ast.AST):
        """The nodes of ``scope`` outside the functions defined in it (module: top level only)."""
        stack = list(ast.iter_child_nodes(scope))
        while stack:
            node = stack.pop()
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) and node is not scope:
                if isinstance(node, ast.Lambda):
                    stack.extend(ast.iter_child_nodes(node))
                continue
            yield node
            stack.extend(ast.iter_child_nodes(node))

    def stored(self, node: ast.AST | None, scope: ast.AST) -> bool:
        if node is None:
            return False
        names = self.tainted[id(scope)] | self.tainted[id(self.tree)]
        if _names_stored_file(node, self.checkout):
            return True
        for n in ast.walk(node):
            if isinstance(n, ast.Name) and n.id in names:
                return True
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and any(s in n.value for s in STORED_STRINGS):
                return True
            if _call_name(n) in self.returns_stored:
                return True
        return False

    def _taint(self, scope: ast.AST, name: str) -> bool:
        if name in self.tainted[id(scope)]:
            return False
        self.tainted[id(scope)].add(name)
        return True

    def _step(self, scope: ast.AST) -> bool:
        changed = False
        for node in self._own_nodes(scope):
            pairs: list[tuple[ast.AST, ast.AST | None]] = []
            if isinstance(node, ast.Assign):
                pairs = [p for t in node.targets for p in _targets(t, node.value)]
            elif isinstance(node, (ast.AnnAssign, ast.AugAssign, ast.NamedExpr)) and node.value is not None:
                pairs = _targets(node.target, node.value)
            elif isinstance(node, (ast.For, ast.AsyncFor, ast.comprehension)):
                pairs = _targets(node.target, node.iter)
            elif isinstance(node, ast.withitem) and node.optional_vars is not None:
                pairs = _targets(node.optional_vars, node.context_expr)
            elif isinstance(node, (ast.Return, ast.Yield)) and isinstance(scope, ast.FunctionDef):
                if self.stored(node.value, scope) and scope.name not in self.returns_stored:
                    self.returns_stored.add(scope.name)
                    changed = True
            elif isinstance(node, ast.Call) and _call_name(node) in self.functions:
                changed |= self._taint_parameters(self.functions[_call_name(node)], node, scope)
            for target, value in pairs:
                if self.stored(value, scope):
                    changed |= self._taint(scope, target.id)
        if isinstance(scope, ast.FunctionDef):  # a fixture that returns stored data, as a parameter
            for a in scope.args.args:
                if a.arg in self.returns_stored and a.arg in self.functions:
                    changed |= self._taint(scope, a.arg)
        return changed

    def _taint_parameters(self, fn: ast.AST, call: ast.Call, scope: ast.AST) -> bool:
        params = [a.arg for a in fn.args.posonlyargs + fn.args.args]
        changed = False
        for i, arg in enumerate(call.args):
            if i < len(params) and self.stored(arg, scope):
                changed |= self._taint(fn, params[i])
        for kw in call.keywords:
            if kw.arg is not None and self.stored(kw.value, scope):
                changed |= self._taint(fn, kw.arg)
        return changed

    def _propagate(self) -> None:
        while any([self._step(s) for s in self.scopes]):
            pass

    # ------------------------------------------------------------------ findings
    def _marked(self, node: ast.AST) -> bool:
        span = self.lines[node.lineno - 1:(node.end_lineno or node.lineno)]
        return any(MARK in line and line.split(MARK, 1)[1].strip() for line in span)

    def _findings(self):
        for scope in self.scopes:
            for node in self._own_nodes(scope):
                why = self._why(node, scope)
                if why and not self._marked(node):
                    yield f"line {node.lineno}: {why}"

    def _why(self, node: ast.AST, scope: ast.AST) -> str | None:
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            for op, a, b in zip(node.ops, operands, operands[1:]):
                if isinstance(op, (ast.Eq, ast.NotEq)):
                    why = self._pair(a, b, scope) or self._pair(b, a, scope)
                    if why:
                        return why
            return None
        name = _call_name(node)
        if name in EXACT_CALLS and any(self.stored(a, scope) for a in node.args):
            return f"{name}() of data stored in a committed file: compare within a justified tolerance"
        if name in ZERO_TOL_CALLS and any(self.stored(a, scope) for a in node.args):
            tol = {k.arg: k.value for k in node.keywords}
            if all(isinstance(tol.get(k), ast.Constant) and tol[k].value == 0 for k in ("rtol", "atol")):
                return f"{name}(rtol=0, atol=0) against data stored in a committed file"
        return None

    def _pair(self, a: ast.AST, b: ast.AST, scope: ast.AST) -> str | None:
        """Why ``a == b`` is an exact comparison with stored numbers (``a`` the suspect side)."""
        if _structural(a) or _structural(b):
            return None
        digest = any(_call_name(n) in DIGESTS for n in ast.walk(a))
        if digest and (self.stored(b, scope) or isinstance(b, ast.Constant)):
            return "a digest compared with a stored one: digests of float results differ by CPU"
        if self.stored(a, scope) and not _literal_without_floats(b):
            return "== with data stored in a committed file: use a justified tolerance (or mark an exact " \
                   f"non-numeric comparison '{MARK} <why>')"
        return None


def check_file(path: Path) -> list[str]:
    return [f"{path.name}: {f}" for f in StoredExact(path.read_text(), str(path)).findings]


if __name__ == "__main__":
    here = Path(__file__).resolve().parent
    files = [Path(a) for a in sys.argv[1:]] or sorted(here.glob("*.py"))
    found = [f for p in files for f in check_file(p)]
    print("\n".join(found) or "no exact comparison with stored data")
    sys.exit(1 if found else 0)
