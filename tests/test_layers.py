"""The layers import downwards only, and no module imports itself in a cycle (docs/architecture.md).

Every ``import`` counts, those inside functions too: an import deferred to call time still
ties the two modules together, and hiding a cycle in a function is what these tests forbid.
"""
from __future__ import annotations

import ast
from pathlib import Path

from builders import REPO_ROOT

PACKAGE = REPO_ROOT / "rjfit"
# (module prefix, layer): a module may import its own package and any lower layer; packages
# of one layer are ordered too (posterior may import sampler, not the other way round)
LAYERS = [("rjfit.errors", 0.0), ("rjfit.io", 0.1), ("rjfit.progress", 0.15), ("rjfit.plotting", 0.2),
          ("rjfit.model", 1), ("rjfit.data", 2), ("rjfit.render", 3), ("rjfit.effects", 3.5), ("rjfit.sampler", 4.0), ("rjfit.posterior", 4.1),
          ("rjfit.baselines", 4.2), ("rjfit.diagnose", 4.3), ("rjfit.pipeline", 5), ("rjfit.cli", 6),
          ("rjfit.__main__", 7), ("rjfit", 8)]


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO_ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _layer(module: str):
    matches = [(prefix, rank) for prefix, rank in LAYERS if module == prefix or module.startswith(prefix + ".")]
    return max(matches, key=lambda match: len(match[0]))


def _imports():
    """{module: [(imported module or name, line)]} of every rjfit import in rjfit/, at any depth.

    ``from rjfit.sampler import passes`` imports the module ``rjfit.sampler.passes``;
    ``from rjfit.data.dataset import Dataset`` the module ``rjfit.data.dataset``.
    """
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {_module_name(path) for path in paths}
    graph = {}
    for path in paths:
        found = []
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in modules else node.module
                         for alias in node.names]
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            else:
                continue
            found += [(name, node.lineno) for name in dict.fromkeys(names)
                      if name == "rjfit" or name.startswith("rjfit.")]
        graph[_module_name(path)] = found
    return graph


def upward_imports(graph) -> list[str]:
    """Imports of ``graph`` ({module: [(name, line)]}) against the layers."""
    upward = []
    for module, imports in graph.items():
        if module == "rjfit":
            continue        # the package's public face re-exports from below
        prefix, rank = _layer(module)
        for name, line in imports:
            other_prefix, other_rank = _layer(name)
            if other_rank > rank or (other_rank == rank and other_prefix != prefix):
                upward.append(f"{module} (line {line}) imports {name}")
    return upward


def import_cycles(graph) -> list[str]:
    """Cycles among the modules of ``graph`` (names that are not modules of it, such as
    ``rjfit.data.dataset.Dataset``, are ignored; the package ``rjfit`` itself is left out)."""
    edges = {module: sorted({name for name, _ in imports if name in graph} - {module, "rjfit"})
             for module, imports in graph.items() if module != "rjfit"}
    state, cycles = {}, []

    def visit(module, path):
        state[module] = "open"
        for other in edges[module]:
            if state.get(other) == "open":
                cycles.append(" -> ".join(path[path.index(other):] + [other]))
            elif other not in state:
                visit(other, path + [other])
        state[module] = "done"

    for module in sorted(edges):
        if module not in state:
            visit(module, [module])
    return cycles


def test_layers_import_downwards_only():
    upward = upward_imports(_imports())
    assert not upward, "imports against the layers of docs/architecture.md:\n" + "\n".join(upward)


def test_no_import_cycles():
    cycles = import_cycles(_imports())
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_checks_find_a_cycle_and_an_upward_import():
    graph = {"rjfit.data.a": [("rjfit.data.b", 3)], "rjfit.data.b": [("rjfit.data.c", 4)],
             "rjfit.data.c": [("rjfit.data.a", 9), ("rjfit.pipeline.fit", 10)], "rjfit.pipeline.fit": []}
    assert import_cycles(graph) == ["rjfit.data.a -> rjfit.data.b -> rjfit.data.c -> rjfit.data.a"]
    assert upward_imports(graph) == ["rjfit.data.c (line 10) imports rjfit.pipeline.fit"]
    siblings = {"rjfit.baselines.y": [("rjfit.diagnose.x", 1)], "rjfit.posterior.z": [("rjfit.sampler.w", 2)]}
    assert upward_imports(siblings) == ["rjfit.baselines.y (line 1) imports rjfit.diagnose.x"]
