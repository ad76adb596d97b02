"""The documentation points at things that exist: every repository path it names (``tests/…``,
``benchmarks/…``, ``configs/…``, …), every relative link and every ``#section`` anchor."""
from __future__ import annotations

import re

import pytest

from helpers import REPO

PAGES = sorted([REPO / "README.md", REPO / "CHANGELOG.md", *(REPO / "docs").glob("*.md")])
COMMENTED = sorted([*(REPO / "configs").glob("*.toml"), REPO / "tests" / "data" / "bad" / "expected.toml",
                    *(REPO / "benchmarks").glob("*.py"), *(REPO / "scripts").glob("*.*")])
REPO_PATH = re.compile(r"(?<![\w./-])((?:src|tests|benchmarks|configs|docs|scripts)/[\w./-]*\w)")
LINK = re.compile(r"\]\(([^)#\s]*)(?:#([^)\s]+))?\)")


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page) -> set[str]:
    found, in_code = set(), False
    for line in page.read_text(encoding="utf-8").splitlines():
        in_code ^= line.startswith("```")
        if not in_code and line.startswith("#"):
            found.add(slug(line.lstrip("#")))
    return found


@pytest.mark.parametrize("page", PAGES + COMMENTED, ids=lambda p: str(p.relative_to(REPO)))
def test_named_paths_exist(page):
    missing = sorted({m for m in REPO_PATH.findall(page.read_text(encoding="utf-8")) if not (REPO / m).exists()})
    assert not missing, f"{page.name} names paths that do not exist: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_links_and_anchors_resolve(page):
    broken = []
    for target, anchor in LINK.findall(page.read_text(encoding="utf-8")):
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        path = (page.parent / target) if target else page
        if not path.exists():
            broken.append(target)
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            broken.append(f"{target}#{anchor}")
    assert not broken, f"{page.name} links to what does not exist: {broken}"


def test_slug_follows_github():
    assert slug("Whole data sets: `mvm batch` and `mvm status`") == "whole-data-sets-mvm-batch-and-mvm-status"
    assert slug("The paper's Tables 1–2 on simulated clips") == "the-papers-tables-12-on-simulated-clips"


def test_readme_names_every_dependency_and_extra():
    """The README's install section agrees with pyproject.toml: every dependency and extra is named."""
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    requirements = project["dependencies"] + [r for extra in project["optional-dependencies"].values() for r in extra]
    names = {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0] for r in requirements}
    missing = sorted(n for n in names if n not in readme)
    missing += sorted(f"[{e}]" for e in project["optional-dependencies"] if f"`{e}`" not in readme)
    assert not missing, f"README.md does not name these dependencies or extras of pyproject.toml: {missing}"
