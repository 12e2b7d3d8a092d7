"""docs/architecture.md names every module of ``rjfit/``, each in its own package's section.

The modules are read from the tree when the test runs, so a module added, moved or removed
without the doc following fails here. A package's section is a heading that names its path
(``### `rjfit/sampler/moves/` ``) and runs to the next heading of the same or a higher level;
a module is named there as its file name in backticks (`` `accept.py` ``). A package's
``__init__.py`` is named by its section. A file name in a section that is not a module of
that package (stale, or in the wrong section) fails too.
"""
from __future__ import annotations

import re

from builders import REPO_ROOT

DOC = REPO_ROOT / "docs" / "architecture.md"
PACKAGE = REPO_ROOT / "rjfit"
HEADING = re.compile(r"^(#{1,6})\s+`(rjfit/(?:[\w]+/)*)`\s*$")
FILE_NAME = re.compile(r"`([\w]+\.py)`")


def tree_modules(package_dir) -> dict[str, set]:
    """{package path ('rjfit/sampler/'): {module file names other than __init__.py}} of every folder of
    ``package_dir`` that holds Python files (namespace packages, without ``__init__.py``, included)."""
    packages = {}
    for path in sorted(package_dir.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        modules = packages.setdefault(path.parent.relative_to(package_dir.parent).as_posix() + "/", set())
        if path.name != "__init__.py":
            modules.add(path.name)
    return packages


def doc_sections(text: str) -> dict[str, set]:
    """{package path: {file names in backticks}} of each package section of the doc's ``text``."""
    sections, current, level = {}, None, 0
    for line in text.splitlines():
        heading = re.match(r"^(#{1,6})\s", line)
        if heading:
            named = HEADING.match(line)
            if named:
                current, level = named.group(2), len(named.group(1))
                sections.setdefault(current, set())
                continue
            if current is not None and len(heading.group(1)) <= level:
                current = None
        if current is not None:
            sections[current].update(FILE_NAME.findall(line))
    return sections


def mismatches(packages: dict, sections: dict) -> list[str]:
    """What the doc misses or names wrongly, one line each."""
    out = [f"{package}: no section" for package in sorted(packages) if package not in sections]
    for package, modules in sorted(packages.items()):
        named = sections.get(package, set())
        out += [f"{package}{name}: not named in its section" for name in sorted(modules - named)]
        out += [f"{package}{name}: named, but no such module there" for name in sorted(named - modules)]
    out += [f"{package}: a section for a package that does not exist" for package in sorted(set(sections) - set(packages))]
    return out


def test_every_module_is_named_in_its_package_section():
    problems = mismatches(tree_modules(PACKAGE), doc_sections(DOC.read_text(encoding="utf-8")))
    assert not problems, "docs/architecture.md and rjfit/ disagree:\n" + "\n".join(problems)


def test_the_check_finds_a_missing_a_misplaced_and_a_stale_module():
    packages = {"rjfit/": {"cli.py", "io.py"}, "rjfit/data/": {"exr.py", "mesh.py"}, "rjfit/model/": set()}
    text = "\n".join(["# Doc", "### `rjfit/`", "`cli.py` and `mesh.py`", "## Other", "`io.py` outside any section",
                      "### `rjfit/data/`", "| `exr.py` | `gone.py` |"])
    assert sorted(mismatches(packages, doc_sections(text))) == [
        "rjfit/data/gone.py: named, but no such module there", "rjfit/data/mesh.py: not named in its section",
        "rjfit/io.py: not named in its section", "rjfit/mesh.py: named, but no such module there",
        "rjfit/model/: no section"]
