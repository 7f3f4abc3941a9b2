"""docs/ARCHITECTURE.md's owner table against the code: every file it names exists, and every name
it gives in brackets after a module is defined there (a module attribute, or a member of a class
named before it in the same brackets), so the table cannot go stale silently."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOC = (REPO / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def _section(title: str) -> str:
    start = DOC.index(f"## {title}")
    end = DOC.find("\n## ", start + 1)
    return DOC[start:end if end > 0 else None]


def _owner_cells() -> list[str]:
    rows = [line for line in _section("One owner per concept").splitlines() if line.startswith("| ")]
    return [row.split(" | ", 1)[1] for row in rows[1:]]  # after the header row


def _module(path: str):
    return importlib.import_module(path.removesuffix(".py").replace("/", "."))


def _qualified(name: str):
    """The object a fully qualified name (``methods.core.fitting.fit``) names, else None."""
    parts = name.split(".")
    if parts[0] not in ("foundation", "datasets", "methods", "reports", "tasks", "runner"):
        return None
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for part in parts[cut:]:
            obj = getattr(obj, part, None)
        return obj
    return None


def test_every_file_and_folder_the_owner_table_names_exists():
    named = {m for cell in _owner_cells() for m in re.findall(r"`([\w./]+(?:\.py|/))`", cell)}
    assert named, "the owner table names no file"
    missing = sorted(p for p in named if not (REPO / p).exists())
    assert not missing, f"named in docs/ARCHITECTURE.md but absent: {missing}"


def test_every_name_given_after_a_module_in_the_owner_table_is_defined_there():
    checked, undefined = 0, []
    for cell in _owner_cells():
        for path, names in re.findall(r"`([\w/]+\.py)` \(([^)]*)\)", cell):
            module = _module(path)
            owners = [module]  # a bare name may also be a member of a class named before it
            for name in re.findall(r"`([^`]+)`", names):
                name = name.removesuffix("()")
                if not IDENTIFIER.match(name):
                    continue
                found = _qualified(name)
                for owner in owners if found is None else ():
                    obj = owner
                    for part in name.split("."):
                        obj = getattr(obj, part, None)
                    if obj is not None:
                        found = obj
                        break
                checked += 1
                if found is None:
                    undefined.append(f"{path}: {name}")
                first = getattr(module, name.split(".")[0], None)
                owners += [c for c in (found, first) if isinstance(c, type)]
    assert checked > 20 and not undefined, undefined


def test_the_layers_table_names_every_top_level_package_of_the_code():
    layers = _section("Layers")
    for package in ("foundation", "datasets", "methods", "reports", "tasks", "runner"):
        assert f"`{package}/" in layers, package
