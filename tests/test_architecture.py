"""The package's shape: imports run one way through the layers, in-function imports only for
heavy optional dependencies (with a reason), and no file or function beyond the size limits."""

from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "brfgs"

# Top to bottom: a package may import its own layer's listed peers and anything below, never above.
LAYERS = [
    {"__main__"},
    {"cli"},
    {"workflows", "viewer"},
    {"train", "evaluation", "products", "analysis"},
    {"model"},
    {"render", "brdf", "spectral", "init", "bands", "sim"},
    {"data"},
    {"errors", "__init__"},
]
# Same-layer imports that are allowed (importer, imported); everything else in a layer is separate.
PEERS = {("brdf", "render"), ("init", "bands"), ("sim", "brdf"), ("sim", "render"),
         ("evaluation", "analysis"), ("products", "analysis")}
# Pairs kept apart although the layers would allow the import: training never depends on analysis.
APART = {("train", "analysis")}
# Dependencies that may be imported inside functions (heavy, optional or trap-prone), with a
# "lazy:" comment saying why: pycolmap (via brfgs.init.colmap) must follow zlib; mitsuba/drjit (and
# brfgs.sim's renderer) need DRJIT_LIBLLVM_PATH first; gsplat and lpips are optional; prosail
# compiles numba code on import; matplotlib's backend is chosen before pyplot loads; pvlib, pandas
# and pyproj (~0.7 s together) serve only timed frames and georeferenced scenes.
LAZY_OK = ("pycolmap", "mitsuba", "drjit", "gsplat", "lpips", "prosail", "matplotlib", "brfgs.sim", "brfgs.init",
           "pvlib", "pandas", "pyproj")


def layer_of(package: str) -> int:
    for rank, names in enumerate(LAYERS):
        if package in names:
            return rank
    raise KeyError(package)


def check_edge(importer: str, imported: str) -> str | None:
    """Why ``importer`` (a brfgs sub-package) may not import ``imported``, or None if it may."""
    if importer == imported:
        return None
    a, b = layer_of(importer), layer_of(imported)
    if a > b:
        return f"{importer} (layer {a}) imports {imported} (layer {b}, higher)"
    if (importer, imported) in APART:
        return f"{importer} may not import {imported} (kept apart)"
    if a == b and (importer, imported) not in PEERS:
        return f"{importer} imports its peer {imported} (same layer, not an allowed peer import)"
    return None


def _package(path: Path) -> str:
    rel = path.relative_to(SRC)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", "")) == "TYPE_CHECKING":
            for sub in node.body:
                lines.update(range(sub.lineno, sub.end_lineno + 1))
    return lines


def brfgs_imports(path: Path) -> list[tuple[int, str]]:
    """(line, imported sub-package) of every ``brfgs.*`` import in a module (TYPE_CHECKING blocks aside)."""
    tree = ast.parse(path.read_text())
    skip = _type_checking_lines(tree)
    out = []
    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in skip:
            continue
        names = []
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        out += [(node.lineno, n.split(".")[1]) for n in names if n.startswith("brfgs.")]
    return out


def layer_violations() -> list[str]:
    out = []
    for path in sorted(SRC.rglob("*.py")):
        pkg = _package(path)
        for line, imported in brfgs_imports(path):
            why = check_edge(pkg, imported)
            if why:
                out.append(f"{path.relative_to(SRC.parent)}:{line}: {why}")
    return out


def test_imports_run_one_way_through_the_layers():
    assert layer_violations() == []


def test_the_check_would_fail_on_the_old_train_analysis_cycle():
    # before the clean-up train/evaluate.py imported analysis.metrics and analysis/renderer.py imported train.trainer
    assert check_edge("train", "analysis") is not None
    assert check_edge("analysis", "train") is not None
    assert check_edge("model", "train") is not None
    assert check_edge("data", "model") is not None
    assert check_edge("train", "evaluation") is not None and check_edge("analysis", "evaluation") is not None
    assert check_edge("analysis", "model") is None and check_edge("cli", "train") is None


def _function_imports(tree: ast.AST):
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    yield node


def test_imports_inside_functions_only_for_heavy_optional_dependencies():
    """Outside cli/ (whose command bodies import the library lazily so that --help stays fast),
    an import inside a function must be a heavy optional dependency and say why ('lazy:')."""
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        if _package(path) == "cli":
            continue
        lines = path.read_text().splitlines()
        for node in _function_imports(ast.parse("\n".join(lines))):
            mod = node.module if isinstance(node, ast.ImportFrom) else node.names[0].name
            context = " ".join(lines[max(node.lineno - 2, 0):node.lineno])
            if not (mod or "").startswith(LAZY_OK) or "lazy:" not in context:
                bad.append(f"{path.relative_to(SRC.parent)}:{node.lineno}: import {mod}")
    assert bad == []


def test_code_shape_limits():
    spec = importlib.util.spec_from_file_location("check_code_shape", Path(__file__).parent / "code_shape.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.violations(SRC) == []


@pytest.mark.parametrize("module", ["brfgs.init", "brfgs.model", "brfgs.evaluation.evaluate"])
def test_importing_the_library_does_not_load_pycolmap_or_mitsuba(module, tmp_path):
    """pycolmap must never be imported before zlib (it breaks zlib: 'free(): invalid pointer'),
    and mitsuba needs DRJIT_LIBLLVM_PATH first: both stay out of plain library imports."""
    import subprocess

    code = f"import sys, {module}; print(sorted(m for m in ('pycolmap', 'mitsuba') if m in sys.modules))"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


def test_reading_scenes_does_not_load_pvlib_pandas_or_pyproj():
    """pvlib and pandas (~0.6 s) and pyproj load only for timed frames and georeferenced scenes, so
    that every command (and `brfgs --help`) starts without them."""
    import subprocess

    code = ("import sys, brfgs.data, brfgs.model, brfgs.cli; "
            "print(sorted(m for m in ('pvlib', 'pandas', 'pyproj') if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


def test_the_command_line_and_its_option_modules_start_without_torch():
    """`brfgs --help` and every command's option parsing import the CLI and the option dataclasses only
    (docs/architecture.md): torch (seconds to import) loads when a command runs. The
    `--supersample` limit once pulled it into train/config.py through render/."""
    import subprocess

    code = ("import sys, brfgs.cli, brfgs.train.config, brfgs.train.presets, brfgs.workflows.options; "
            "print('torch' in sys.modules)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "False"


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def module_imports() -> dict[str, set[str]]:
    """{module: the brfgs modules it imports anywhere (module level, in functions, TYPE_CHECKING blocks)}."""
    modules = {_module_name(p): p for p in SRC.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and node.module.startswith("brfgs"):
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module
                           for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names if a.name.startswith("brfgs")]
            deps.update(t for t in targets if t in modules and t != name)
        graph[name] = deps
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_between_modules():
    assert import_cycles(module_imports()) == []


def test_the_cycle_check_finds_a_cycle():
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []
