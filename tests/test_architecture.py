"""The package layers of docs/architecture.md: a module may import only the packages its layer allows
(``mvm`` itself, for ``__version__``, everywhere)."""
from __future__ import annotations

import ast

import pytest

from helpers import REPO

SRC = REPO / "src" / "mvm"

#: Package -> the mvm packages its modules may import (besides itself).
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "parallel": set(),
    "core": {"errors"},
    "io": {"core", "errors"},
    "scenes": {"core", "io", "parallel", "errors"},
    "net": {"core", "io", "eval", "errors"},
    "sim": {"core", "io", "net", "errors"},
    "eval": {"core", "io", "scenes", "sim", "rig", "errors"},
    "rig": {"core", "io", "eval", "parallel", "errors"},
    "video": {"core", "io", "scenes", "eval", "net", "errors"},
    "report": {"core", "io", "eval", "sim", "errors"},
    "batch": {"core", "io", "scenes", "eval", "sim", "rig", "net", "video", "report", "parallel", "errors"},
    "settings": {"core", "io", "rig", "sim", "video", "batch", "net", "errors"},
}


def _imports(path) -> set[str]:
    """The top-level mvm packages that ``path`` imports: ``mvm.core.scene`` -> ``core``."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = [node.module] if isinstance(node, ast.ImportFrom) and node.module else \
            [a.name for a in node.names] if isinstance(node, ast.Import) else []
        for name in names:
            parts = name.split(".")
            if parts[0] == "mvm" and len(parts) > 1:
                found.add(parts[1])
            elif parts[0] == "mvm":
                found.add("mvm")
    return found


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_its_layers(package):
    root = SRC / package
    files = sorted(root.rglob("*.py")) if root.is_dir() else [root.with_suffix(".py")]
    wrong = {str(f.relative_to(SRC)): sorted(_imports(f) - ALLOWED[package] - {package, "mvm"})
             for f in files}
    wrong = {f: names for f, names in wrong.items() if names}
    assert not wrong, f"imports across layers (docs/architecture.md): {wrong}"


def test_every_package_has_a_layer():
    packages = {p.stem for p in SRC.iterdir() if (p / "__init__.py").exists() or p.suffix == ".py"}
    unplaced = packages - {"cli", "__init__", "__main__"} - set(ALLOWED)
    assert not unplaced, f"add these to docs/architecture.md and ALLOWED: {sorted(unplaced)}"


def test_no_function_of_the_core_is_over_60_lines():
    long = []
    for path in sorted((SRC / "core").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 60:
                long.append(f"{path.relative_to(SRC)}:{node.lineno} {node.name} "
                            f"({node.end_lineno - node.lineno + 1} lines)")
    assert not long, long
