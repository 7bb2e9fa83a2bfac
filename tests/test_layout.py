"""The package layout rule: each package imports only from packages listed before it, and
`fitter.core` (shipped inside the FMUs) only from numpy and the standard library."""
import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "fitter"
ORDER = ["core", "data", "progress", "identification", "baselines", "diagnosis", "fmu", "reports", "cli_support",
         "paper", "estimator", "batch", "cli"]


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def _package(module: str) -> str:
    return module.split(".")[1]


MODULES = sorted(p for p in ROOT.rglob("*.py") if p.parent != ROOT or p.name != "__init__.py")


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_module_imports_only_from_lower_packages(path):
    rel = path.relative_to(ROOT)
    own = rel.parts[0] if len(rel.parts) > 1 else rel.stem
    rank = ORDER.index(own)
    for name in _imports(path):
        if name.startswith("fitter."):
            assert ORDER.index(_package(name)) <= rank, f"{rel} imports {name} (above {own})"
        if own == "core":
            top = name.split(".")[0]
            assert top in {"numpy", "__future__"} or top in sys.stdlib_module_names or name.startswith(
                "fitter.core"), f"{rel}: fitter.core must need only numpy and the standard library ({name})"


def test_no_module_imports_the_top_level_script():
    assert not any("build_fmu" in _imports(p) for p in MODULES)
