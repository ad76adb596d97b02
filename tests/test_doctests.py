"""The examples in mvm's docstrings run, and give what they show.

Every module of the package whose source holds a ``>>>`` example is imported and its examples
run with :mod:`doctest`, one test per module; a module whose optional dependency is not
installed (torch, onnxruntime, …) is skipped, not failed. Modules without examples are not
imported, so this stays fast and finds examples in modules added or moved later.
"""
from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

import mvm

PACKAGE = Path(mvm.__file__).resolve().parent


def modules_with_examples() -> list[str]:
    names = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if ">>>" in path.read_text(encoding="utf-8"):
            parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


MODULES = modules_with_examples()


def test_the_package_has_examples():
    assert MODULES, f"no >>> example found under {PACKAGE}"


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] != "mvm":
            pytest.skip(f"{name} needs {exc.name}, not installed")
        raise
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    reports: list[str] = []
    examples = 0
    for test in finder.find(module, name):
        examples += len(test.examples)
        runner.run(test, out=reports.append)
    assert examples > 0, f"{name}: '>>>' in the source but no example found by doctest"
    assert runner.failures == 0, "".join(reports)
