"""The import contract of docs/ARCHITECTURE.md, checked over the source: every import statement of
every project module (also those inside functions), so a lazy import cannot hide an upward arrow.

Layers, lowest first: foundation (``foundation``, ``datasets``), methods, reports, tasks (what a
task computes), run (``runner``).
A module may import its own layer and the ones below it; and the modules import each other without
a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tasks.cache import project_imports

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("foundation", "datasets", "methods", "reports", "tasks", "runner")
LAYERS = ("foundation", "methods", "reports", "tasks", "run")


def layer(module: str) -> str | None:
    top = module.split(".")[0]
    if top == "runner":
        return "run"
    if top in ("foundation", "datasets"):
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
    assert layer("runner.cli") == "run" and layer("foundation.metrics.edges") == "foundation"
    assert "methods.base" in graph["runner.plan"]  # imported inside a function
    assert any(t.startswith("reports") for t in graph["runner.export"])
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []


# -- methods/: the rooms of the field ---------------------------------------------------------------
METHOD_ROOMS = ("methods.fields", "methods.pointcloud")


def registers_a_method(path: Path) -> bool:
    """True when the module's top level defines a class decorated ``@register_method`` (with or
    without presentation arguments)."""
    return any(isinstance(node, ast.ClassDef) and any(getattr(getattr(d, "func", d), "id", None) == "register_method"
                                                      for d in node.decorator_list)
               for node in ast.parse(path.read_text(encoding="utf-8")).body)


def method_modules(modules: dict[str, Path]) -> set[str]:
    return {name for name, path in modules.items() if name.startswith(METHOD_ROOMS) and registers_a_method(path)}


def imports_used_only_as_bases(path: Path, target: str) -> bool:
    """True when every import of ``target`` in the module at ``path`` is ``from target import
    Names`` and each name is a base class of a class the module defines (a subclass, nothing else)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    bases = {b.id for node in ast.walk(tree) if isinstance(node, ast.ClassDef) for b in node.bases
             if isinstance(b, ast.Name)}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(a.name == target or a.name.startswith(target + ".") for a in node.names):
            return False
        if isinstance(node, ast.ImportFrom) and node.module == target:
            if any((a.asname or a.name) not in bases for a in node.names):
                return False
            used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)} - bases
            if any((a.asname or a.name) in used for a in node.names if (a.asname or a.name) not in bases):
                return False
    return True


def method_imports_other_than_subclassing(modules: dict[str, Path], graph: dict[str, set[str]]) -> list[str]:
    methods_ = method_modules(modules)
    return [f"{a} -> {b}" for a in sorted(methods_) for b in sorted(graph[a] & methods_)
            if not imports_used_only_as_bases(modules[a], b)]


def test_a_method_module_imports_another_only_to_subclass_it(graph):
    modules = project_modules()
    assert {"methods.fields.sals", "methods.fields.sdf_ndc", "methods.pointcloud.poco.method",
            "methods.pointcloud.knn.sals_knn"} <= method_modules(modules)
    bad = method_imports_other_than_subclassing(modules, graph)
    assert not bad, "a method module imports another method module for more than a base class " \
                    "(move the shared code into a shared module):\n" + "\n".join(bad)


def test_extractors_and_core_never_import_a_method(graph):
    modules = project_modules()
    methods_ = method_modules(modules) | {m for m in modules if m.startswith(METHOD_ROOMS)}
    lower = [m for m in modules if m.startswith(("methods.extractors", "methods.core"))]
    bad = [f"{a} -> {b}" for a in sorted(lower) for b in sorted(graph[a] & methods_)]
    assert not bad, "extractors and core import method modules:\n" + "\n".join(bad)


def test_the_method_rule_sees_an_import_that_is_not_a_base(tmp_path):
    subclass = tmp_path / "sub.py"
    subclass.write_text("from methods.fields.sdf import SDFMethod\nclass A(SDFMethod):\n    pass\n")
    helper = tmp_path / "helper.py"
    helper.write_text("from methods.fields.sdf import SDFMethod, helper\nclass A(SDFMethod):\n    x = helper()\n")
    module = tmp_path / "module.py"
    module.write_text("import methods.fields.sdf as sdf\nclass A(sdf.SDFMethod):\n    pass\n")
    assert imports_used_only_as_bases(subclass, "methods.fields.sdf")
    assert not imports_used_only_as_bases(helper, "methods.fields.sdf")
    assert not imports_used_only_as_bases(module, "methods.fields.sdf")
    assert registers_a_method(REPO / "methods" / "fields" / "sals.py")
    assert not registers_a_method(REPO / "methods" / "pointcloud" / "knn" / "training.py")
