"""The import contract of docs/ARCHITECTURE.md, checked over the source: every import statement of
every project module (also those inside functions), so a lazy import cannot hide an upward arrow.

Layers, lowest first: foundation (``benchmark``, ``datasets``), methods, reports, run (``runner``).
A module may import its own layer and the ones below it; and the modules import each other without
a cycle.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from runner.cache import project_imports

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("benchmark", "datasets", "methods", "reports", "runner")
LAYERS = ("foundation", "methods", "reports", "run")


def layer(module: str) -> str | None:
    top = module.split(".")[0]
    if top == "runner":
        return "run"
    if top in ("benchmark", "datasets"):
        return "foundation"
    return top if top in PACKAGES else None


def project_modules() -> dict[str, Path]:
    modules = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """{module: project modules it imports} (``from a import b`` counts ``a.b`` when it is a module,
    and the package ``a`` always)."""
    return {name: project_imports(name, path, PACKAGES) - {name} for name, path in modules.items()}


def folder_graph(modules: dict[str, Path], graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """{folder: the other folders its modules import}, a folder named like its package."""
    def folder(name):
        return ".".join(modules[name].parent.relative_to(REPO).parts)

    folders: dict[str, set[str]] = {folder(m): set() for m in modules}
    for a, targets in graph.items():
        folders[folder(a)].update(folder(b) for b in targets if folder(b) != folder(a))
    return folders


@pytest.fixture(scope="module")
def graph():
    return import_graph(project_modules())


def test_no_module_imports_a_higher_layer(graph):
    upward = [f"{a} ({layer(a)}) -> {b} ({layer(b)})" for a, targets in graph.items() for b in sorted(targets)
              if LAYERS.index(layer(b)) > LAYERS.index(layer(a))]
    assert not upward, "upward imports:\n" + "\n".join(upward)


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def test_the_modules_import_each_other_without_a_cycle(graph):
    cycles = import_cycles(graph)
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_the_folders_import_each_other_without_a_cycle(graph):
    cycles = import_cycles(folder_graph(project_modules(), graph))
    assert not cycles, "folder cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_the_checker_sees_lazy_and_relative_imports():
    modules = project_modules()
    graph = import_graph(modules)
    assert layer("runner.cli") == "run" and layer("benchmark.metrics.edges") == "foundation"
    assert "methods.base" in graph["runner.plan"]  # imported inside a function
    assert any(t.startswith("reports") for t in graph["runner.export"])
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []
