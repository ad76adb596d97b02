"""The package layers of docs/architecture.md: a module may import only the packages its layer allows
(``mvm`` itself, for ``__version__``, everywhere), and the packages' real imports form no cycle."""
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
    "metrics": {"core", "errors"},
    "io": {"core", "errors"},
    "scenes": {"core", "io", "parallel", "errors"},
    "net": {"core", "io", "metrics", "errors"},
    "sim": {"core", "io", "errors"},
    "eval": {"core", "io", "metrics", "scenes", "sim", "rig", "errors"},
    "rig": {"core", "io", "metrics", "parallel", "errors"},
    "video": {"core", "io", "scenes", "metrics", "net", "errors"},
    "report": {"core", "io", "metrics", "sim", "errors"},
    "stages": {"core", "io", "scenes", "metrics", "net", "video", "rig", "report", "errors"},
    "batch": {"core", "io", "scenes", "metrics", "eval", "sim", "rig", "net", "video", "report", "stages",
              "parallel", "errors"},
    "settings": {"core", "io", "rig", "sim", "video", "stages", "batch", "net", "errors"},
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


def _package_of(path) -> str:
    """``src/mvm/core/scene.py`` -> ``core``; ``src/mvm/scenes.py`` -> ``scenes``."""
    return path.relative_to(SRC).parts[0].removesuffix(".py")


def import_graph() -> dict[str, dict[str, list[str]]]:
    """The packages' real imports, top-level and inside functions alike: ``{package: {imported
    package: [modules that import it]}}`` (``mvm`` itself, ``__init__`` and ``__main__`` left out)."""
    graph: dict[str, dict[str, list[str]]] = {}
    for path in sorted(SRC.rglob("*.py")):
        package = _package_of(path)
        if package in ("__init__", "__main__"):
            continue
        for imported in _imports(path) - {package, "mvm"}:
            graph.setdefault(package, {}).setdefault(imported, []).append(str(path.relative_to(SRC)))
    return graph


def find_cycle(graph: dict[str, dict[str, list[str]]]) -> list[str] | None:
    """A cycle of ``graph`` as the packages along it, first one repeated at the end
    (``["eval", "sim", "net", "eval"]``), or None."""
    state: dict[str, str] = {}                                               # "open" on the path, "done"
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = "open"
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        path.pop()
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_find_cycle_names_the_cycle():
    assert find_cycle({"a": {"b": []}, "b": {"c": []}, "c": {}}) is None
    assert find_cycle({"a": {"b": []}, "b": {"c": []}, "c": {"a": []}}) == ["a", "b", "c", "a"]
    assert find_cycle({"x": {"y": []}, "y": {"y2": []}, "y2": {"y": []}}) == ["y", "y2", "y"]


def test_package_imports_form_no_cycle():
    graph = import_graph()
    assert {"core", "metrics", "eval", "net", "sim"} <= set(graph)                  # the graph was read
    cycle = find_cycle(graph)
    if cycle:
        steps = [f"{a} -> {b} ({', '.join(graph[a][b])})" for a, b in zip(cycle, cycle[1:])]
        pytest.fail("the package imports form a cycle " + " -> ".join(cycle) + ":\n  " + "\n  ".join(steps))


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


def test_no_module_is_over_500_lines():
    """A module that grows past 500 lines does several jobs: split it by what it holds."""
    long = {str(p.relative_to(SRC)): n for p in sorted(SRC.rglob("*.py"))
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 500}
    assert not long, long


def test_module_names_do_not_collide_outside_the_command_line():
    """Two modules of one name (three ``pipeline.py``) make tracebacks and imports ambiguous;
    ``cli/`` alone names its modules after the commands (``cli/rig.py`` for ``mvm rig``)."""
    seen: dict[str, list[str]] = {}
    for path in sorted(SRC.rglob("*.py")):
        if path.name != "__init__.py" and path.parent.name != "cli":
            seen.setdefault(path.name, []).append(str(path.relative_to(SRC)))
    assert not {name: paths for name, paths in seen.items() if len(paths) > 1}


#: Private names still imported from another module, to be made public or moved: ``(importer, module, name)``.
PRIVATE_IMPORTS_LEFT: set[tuple[str, str, str]] = set()


def test_no_private_name_is_imported_across_modules():
    """A name with a leading underscore is its module's own: another module that needs it needs
    a public function (renamed without the underscore) or the function moved where both can reach it."""
    found = set()
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("mvm")):
                found |= {(str(path.relative_to(SRC)), node.module, a.name) for a in node.names
                          if a.name.startswith("_") and not a.name.startswith("__")}
    assert found == PRIVATE_IMPORTS_LEFT, sorted(found ^ PRIVATE_IMPORTS_LEFT)
