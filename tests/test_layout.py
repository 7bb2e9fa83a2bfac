"""The package layout rule: each package imports only from packages listed before it (absolute and relative
imports alike, and never the bare top package `fitter`), `fitter.core` (shipped inside the FMUs) only from numpy
and the standard library, and no package's modules import each other in a cycle at module level (an import
inside a function, made when it runs, is how a cycle is broken on purpose)."""

import ast
import sys
from pathlib import Path

import pytest

from fitter.fmu.build import _NOT_SHIPPED

ROOT = Path(__file__).resolve().parents[1] / "fitter"
ORDER = [
    "core",
    "data",
    "progress",
    "workers",
    "identification",
    "baselines",
    "diagnosis",
    "fmu",
    "reports",
    "cli_support",
    "paper",
    "estimator",
    "batch",
    "cli",
]


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    path = ROOT.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _imports(path: Path, top_level: bool = False) -> set[str]:
    """Absolute names of the modules `path` imports (relative imports resolved; ``from P import m`` gives P.m when
    m is a module of P); with `top_level`, only the imports run when the module is loaded."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level else ast.walk(tree)
    package = _module_name(path) if path.name == "__init__.py" else _module_name(path).rpartition(".")[0]
    names = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            names.add(base)
            names |= {f"{base}.{a.name}" for a in node.names if _is_module(f"{base}.{a.name}")}
    return names


def _package(module: str) -> str:
    return module.split(".")[1] if "." in module else module


MODULES = sorted(p for p in ROOT.rglob("*.py") if p.parent != ROOT or p.name != "__init__.py")


MAX_LINES = 600
"""A module holds one responsibility: at most this many lines (as ruff formats them)."""


def test_no_module_of_the_package_is_over_the_line_limit():
    """Every module of `fitter` (each file ``.py`` in it, ``__init__`` included) at most `MAX_LINES` lines."""
    lengths = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in ROOT.rglob("*.py")}
    assert len(lengths) > 80
    assert {name: n for name, n in lengths.items() if n > MAX_LINES} == {}


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_module_imports_only_from_lower_packages(path):
    rel = path.relative_to(ROOT)
    own = rel.parts[0] if len(rel.parts) > 1 else rel.stem
    rank = ORDER.index(own)
    for name in _imports(path):
        if name == "fitter":
            assert rel.name == "__init__.py" and len(rel.parts) == 1, f"{rel} imports the top package 'fitter'"
        elif name.startswith("fitter."):
            assert ORDER.index(_package(name)) <= rank, f"{rel} imports {name} (above {own})"
        if own == "core" and rel.name not in _NOT_SHIPPED:
            top = name.split(".")[0]
            assert top in {"numpy", "__future__"} or top in sys.stdlib_module_names or name.startswith("fitter.core"), (
                f"{rel}: fitter.core must need only numpy and the standard library ({name})"
            )


def test_no_module_imports_the_top_level_script():
    assert not any("build_fmu" in _imports(p) for p in MODULES)


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of `graph` (module -> modules it imports), or None."""
    state: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> list[str] | None:
        state[node] = 1
        for other in sorted(graph.get(node, ())):
            if state.get(other) == 1:
                return stack[stack.index(other) :] + [other]
            if other not in state and (found := visit(other, stack + [other])):
                return found
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start, [start])):
            return found
    return None


def test_no_import_cycle_at_module_level():
    modules = {_module_name(p): p for p in ROOT.rglob("*.py")}
    graph = {
        name: {m for m in _imports(path, top_level=True) if m in modules and m != name}
        for name, path in modules.items()
    }
    # a package's __init__ importing its own modules is how a package is built, not a cycle
    for name in graph:
        graph[name] = {m for m in graph[name] if not (name.startswith(m + ".") and modules[m].name == "__init__.py")}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def test_the_checks_see_relative_imports_and_cycles():
    """The rules read what they must: a relative import resolves to its absolute module, and a cycle is found."""
    assert "fitter.core.errors" in _imports(ROOT / "core" / "inverse.py")
    assert "fitter.core.effects.spec" in _imports(ROOT / "core" / "effects" / "catalogue.py")
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
