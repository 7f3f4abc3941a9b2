"""The run layer's caches: fitted weights and extracted meshes, keyed by what defines them.

Layout under the cache root (:func:`foundation.storage.cache_root`): ``fields/`` exact grid fields
(:class:`foundation.field_cache.FieldCache`), ``weights/<method>_<key>.pt`` fitted networks,
``meshes/<method>_<key>.npz`` extracted meshes. Every entry is written atomically with a checksum
(:func:`foundation.storage.write_checked`); a damaged entry is recomputed and counted
(:class:`foundation.storage.CacheStats`), never used.

Keys, all built here: weights (:func:`fit_key`), meshes (:func:`mesh_key`), the reconstruct
task's trained networks (:func:`network_key`), and the code digest recorded with every result
(:func:`task_code_digest`).

Jobs that need the same fit (a sweep of extraction settings) share it: the job that fits holds the
weights entry's lock (``locks/weights_<method>_<key>.lock``, :meth:`RunCaches.fit_lock`); the others wait
and load the saved weights. With the caches off every job fits for itself.

:func:`code_digest` follows the imports it finds in the source (``import``/``from`` statements,
also inside functions) through the project's packages (foundation, methods, datasets, tasks, runner) and hashes
what every module reached computes: its syntax tree without docstrings, so comments, docstrings
and layout do not invalidate a cache, while any change of code does. A module that cannot be found raises instead of counting as empty, so a
renamed module never silently stops invalidating the caches that depend on it.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import importlib.util
import io
import json
from functools import lru_cache
from pathlib import Path
from typing import Iterator

import numpy as np

from foundation.field_cache import FieldCache
from foundation.storage import CacheStats, entry_lock, read_entry, write_checked
from tasks.spec import digest

#: Top-level packages whose modules enter code digests.
PROJECT_PACKAGES = ("foundation", "methods", "datasets", "tasks", "runner")


def _source_under(root: Path, name: str) -> Path | None:
    """The source file of module ``name`` in a source tree ``root`` (a package's ``__init__.py`` or
    a ``.py`` file), or None."""
    base = root.joinpath(*name.split("."))
    for path in (base / "__init__.py", base.with_name(base.name + ".py")):
        if path.is_file():
            return path
    return None


def _module_file(name: str, root: Path | None = None) -> Path:
    """The source file of project module ``name``: as Python imports it, or in the source tree
    ``root`` (another commit's files)."""
    if root is not None:
        path = _source_under(root, name)
    else:
        spec = importlib.util.find_spec(name)
        path = Path(spec.origin) if spec is not None and spec.origin and spec.origin.endswith(".py") else None
    if path is None:
        raise ModuleNotFoundError(f"code digest: project module '{name}' has no source file")
    return path


def _is_module(name: str, root: Path | None = None) -> bool:
    if root is not None:
        return _source_under(root, name) is not None
    try:
        spec = importlib.util.find_spec(name)
    except ModuleNotFoundError:  # a parent is not a package (``from a.b import Attribute``)
        return False
    return spec is not None and bool(spec.origin) and spec.origin.endswith(".py")


@lru_cache(maxsize=None)
def _top_level_names(source: str) -> frozenset[str]:
    """The names a module's top level binds (def, class, assignment or import), from its source."""
    names = set()
    for node in ast.parse(source).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update(a.asname or a.name.split(".")[0] for a in node.names)
        targets = list(node.targets) if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        while targets:
            t = targets.pop()
            if isinstance(t, (ast.Tuple, ast.List)):
                targets.extend(t.elts)
            elif isinstance(t, ast.Name):
                names.add(t.id)
    return frozenset(names)


def _defines(path: Path, attribute: str) -> bool:
    """True when a module's top level binds ``attribute`` (def, class, assignment or import)."""
    return attribute in _top_level_names(path.read_text(encoding="utf-8"))


@lru_cache(maxsize=None)
def _import_statements(source: str, filename: str) -> tuple[tuple[str, ...], tuple[tuple[int, str, str], ...]]:
    """The modules of a source's ``import`` statements, and (level, module, name) per name of its
    ``from`` statements (those inside functions included), as written."""
    imports, froms = [], []
    for node in ast.walk(ast.parse(source, filename=filename)):
        if isinstance(node, ast.Import):
            imports.extend(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            froms.extend((node.level, node.module or "", a.name) for a in node.names)
    return tuple(imports), tuple(froms)


def project_imports(name: str, path: Path, packages: tuple[str, ...] = PROJECT_PACKAGES,
                    root: Path | None = None) -> set[str]:
    """Modules of ``packages`` named by the import statements of module ``name`` (source ``path``),
    those inside functions included, relative ones resolved.

    ``import a.b`` and the ``a.b`` of ``from a.b import c`` must exist (else ModuleNotFoundError);
    ``a.b.c`` counts when ``c`` is a module rather than an attribute. ``root``: resolve the modules
    in that source tree instead of where Python imports them from."""
    imports, froms = _import_statements(path.read_text(encoding="utf-8"), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    required: set[str] = set(imports)
    optional: set[tuple[str, str]] = set()
    for level, base, attribute in froms:
        if level:
            parts = package.split(".")
            base = ".".join(parts[: len(parts) - level + 1] + ([base] if base else []))
        required.add(base)
        optional.add((base, attribute))
    required = {m for m in required if m.split(".")[0] in packages}
    for mod in required:
        if not _is_module(mod, root):
            raise ModuleNotFoundError(f"code digest: '{name}' imports '{mod}', which does not exist")
    found = set(required)
    for base, attribute in optional:
        if base not in required:
            continue
        if _is_module(f"{base}.{attribute}", root):
            found.add(f"{base}.{attribute}")
        elif attribute != "*" and not _defines(_module_file(base, root), attribute):
            raise ModuleNotFoundError(f"code digest: '{name}' imports '{base}.{attribute}', which does not exist")
    return found


def _computing_source(path: Path) -> bytes:
    """The module's code without docstrings, as source text regenerated from its syntax tree: equal
    for two files whose code is equal whatever their comments, docstrings, formatting and methods'
    presentation metadata, and the same text under every Python version that parses it (a dump of
    the tree is not: its node fields change between versions)."""
    return _code_without_docstrings(path.read_text(encoding="utf-8"), str(path))


@lru_cache(maxsize=None)
def _code_without_docstrings(source: str, filename: str) -> bytes:
    """The code regenerated from the syntax tree without docstrings and without the presentation metadata of
    ``@register_method(order=..., color=..., note=...)`` (how tables show a method computes nothing)."""
    tree = ast.parse(source, filename=filename)
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            for decorator in node.decorator_list:
                if isinstance(decorator, ast.Call) and getattr(decorator.func, "id", None) == "register_method":
                    decorator.keywords = []
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return ast.unparse(tree).encode()


def code_modules(*modules: str, root: Path | None = None) -> dict[str, Path]:
    """``modules`` and every project module they import, transitively (their packages included):
    {module name: source file}, sorted by name. ``root``: the modules of that source tree (e.g. a
    commit's files, :func:`commit_tree`) instead of those Python imports."""
    importlib.invalidate_caches()
    seen: dict[str, Path] = {}
    todo = list(modules)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        path = _module_file(name, root)
        seen[name] = path
        todo.extend(project_imports(name, path, root=root) - set(seen))
        parent = name.rpartition(".")[0]
        if parent and parent not in seen:
            todo.append(parent)
    return dict(sorted(seen.items()))


@lru_cache(maxsize=None)
def code_digest(*modules: str, root: Path | None = None) -> str:
    """SHA-256 (16 hex) over the code of :func:`code_modules` of ``modules`` (module docstring):
    comments and docstrings do not count. ``root``: of that source tree's modules."""
    h = hashlib.sha256()
    for name, path in code_modules(*modules, root=root).items():
        h.update(name.encode() + b"\0" + _computing_source(path) + b"\0")
    return h.hexdigest()[:16]


#: The modules that turn a predicted mesh and its GT into metric values (with what they import):
#: the code a stored row's numbers depend on once its mesh exists.
METRIC_MODULES = ("foundation.metrics",)


def metric_code_digest(root: Path | None = None) -> str:
    """The code digest of the metrics (:data:`METRIC_MODULES`); ``root``: of another source tree."""
    return code_digest(*METRIC_MODULES, root=root)


@contextlib.contextmanager
def commit_tree(commit: str, repo: Path) -> Iterator[Path]:
    """The project's packages (:data:`PROJECT_PACKAGES`) as they were at ``commit`` of the git
    checkout ``repo``, in a temporary folder (for :func:`code_digest` ``root``); ValueError (one
    line) when git does not know the commit."""
    import subprocess
    import tarfile
    import tempfile

    archive = subprocess.run(["git", "archive", "--format=tar", commit, *PROJECT_PACKAGES], cwd=repo,
                             capture_output=True)
    if archive.returncode != 0:
        reason = archive.stderr.decode(errors="replace").strip().splitlines()
        raise ValueError(f"commit {commit}: not in the git history of {repo} ({reason[0] if reason else 'git failed'})")
    with tempfile.TemporaryDirectory(prefix="salsbench-commit-") as folder:
        with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
            tar.extractall(folder, filter="data")
        yield Path(folder)


def task_code_modules(spec) -> tuple[str, ...]:
    """The modules that compute a task's result (with what they import, :func:`code_modules`): its
    body (``spec.body``, a module of :mod:`tasks`), the loading of its shape and, for a job,
    its method's module (a plugin's too). The task frame, the command line, the executors, the
    progress display and the reports are not among them: an edit there leaves every result valid."""
    modules = [spec.body, "tasks.load"]
    if spec.kind == "job":
        from tasks.rows import row_kind

        modules.append(row_kind(spec.task, spec.method).module)
    return tuple(dict.fromkeys(modules))


def task_code_digest(spec) -> str:
    """The code digest of a task's result (:func:`task_code_modules`), recorded with its row: a
    row from other code is stale."""
    return code_digest(*task_code_modules(spec))


def fit_key(method, shape_hash: str, budget: str | None, budget_params: dict, seed: int) -> str:
    """The cache key of a per-shape fit: the shape's content hash, the method whose fit it is
    (``method.fit_name``), its network's input and output, every value of the budget record, the
    seed, the fit's code (:func:`fit_code_digest`) and the method's fit parameters."""
    from methods.core.budgets import budget_values

    return digest({"shape": shape_hash, "method": method.fit_name, "input": method.input_kind,
                   "output_dim": method.output_dim, "budget": budget_values(method.budget(budget, budget_params)),
                   "seed": seed, "code": fit_code_digest(method), "fit_params": method.fit_params()})


def mesh_key(method, shape_hash: str, mode: str, grid: int, weights_key: str | None) -> str:
    """The cache key of an extracted mesh: the shape, the method and its full parameters, the mode,
    the grid, the fit it extracts (None in oracle mode), the extraction's code
    (:func:`extraction_code_digest`) and the data it reads (``method.extraction_data_digest``)."""
    return digest({"shape": shape_hash, "method": method.name, "params": method.params, "mode": mode,
                   "grid": grid, "weights": weights_key, "code": extraction_code_digest(method),
                   "data": method.extraction_data_digest()})


def network_code_modules(method) -> tuple[str, ...]:
    """The modules whose code a learned method's network depends on (with what they import): the
    method's module and its ``training_modules``."""
    return (type(method).__module__, *method.training_modules)


def network_key(method, budget, training_set: str, training_seed: int) -> str:
    """The cache key of a network a learned reconstruction method trains across shapes: its training
    set's digest, the method, every value of its budget record, the training seed and the code of
    :func:`network_code_modules`."""
    from methods.core.budgets import budget_values

    return digest({"training_set": training_set, "method": method.name, "budget": budget_values(budget),
                   "seed": training_seed, "code": code_digest(*network_code_modules(method))})


def fit_code_modules(method) -> tuple[str, ...]:
    """The modules whose code a fit depends on (with what they import): the module of the method
    the fit belongs to (``method.fit_name``), the fitting loop, the sampler, the exact fields."""
    from methods.base import METHODS

    return (METHODS.get(method.fit_name).__module__, "methods.core.fitting", "foundation.sampler", "foundation.fields")


def fit_code_digest(method) -> str:
    """The code digest of a fit (:func:`fit_code_modules`)."""
    return code_digest(*fit_code_modules(method))


def extraction_code_digest(method) -> str:
    """Code an extraction depends on: the method's module (with its extractor and query code)."""
    return code_digest(type(method).__module__, "foundation.field_cache")


class RunCaches:
    """The caches of one job: fields, weights and meshes under ``root`` (None: every cache off)."""

    def __init__(self, root: str | Path | None, stats: CacheStats):
        self.root = Path(root) if root is not None else None
        self.stats = stats
        self.fields = FieldCache(self.root / "fields" if self.root is not None else None, stats)

    def _path(self, kind: str, method: str, key: str, suffix: str) -> Path | None:
        return None if self.root is None else self.root / kind / f"{method}_{key}{suffix}"

    # -- weights ----------------------------------------------------------------------------
    def load_weights(self, method, key: str, device):
        """(model, final loss) from the cache, or None (absent, damaged or refused: the caller fits
        and overwrites the entry). An entry that is not a plain weights record, e.g. one that would
        run code when unpickled, is refused unread and counted as rejected."""
        from methods.core import fitting
        from methods.core.weights import WeightsError

        return read_entry(self._path("weights", method.fit_name, key, ".pt"), self.stats, "weights",
                          lambda data: fitting.model_from_bytes(data, device=device, method_name=method.fit_name),
                          refused=(WeightsError, ValueError))

    def save_weights(self, method, key: str, fit, budget) -> None:
        from methods.core import fitting

        path = self._path("weights", method.fit_name, key, ".pt")
        if path is not None:
            write_checked(path, fitting.model_to_bytes(fit.model, budget, method.fit_name, fit.final_loss))

    @contextlib.contextmanager
    def fit_lock(self, method, key: str) -> Iterator[None]:
        """Hold the lock of one weights entry (:func:`foundation.storage.entry_lock`): a
        second job needing the same fit waits, then loads it."""
        if self.root is None:
            yield
            return
        with entry_lock(self.root, f"weights_{method.fit_name}_{key}"):
            yield

    # -- meshes -----------------------------------------------------------------------------
    def load_mesh(self, method: str, key: str):
        """(vertices, faces, timings, info, fit_loss) from the cache, or None."""
        return read_entry(self._path("meshes", method, key, ".npz"), self.stats, "mesh", _mesh_from_bytes)

    def save_mesh(self, method: str, key: str, vertices, faces, timings: dict, info: dict, fit_loss) -> None:
        path = self._path("meshes", method, key, ".npz")
        if path is None:
            return
        buf = io.BytesIO()
        np.savez(buf, vertices=vertices, faces=faces, timings=json.dumps(timings), info=json.dumps(info),
                 fit_loss=np.float64(np.nan if fit_loss is None else fit_loss))
        write_checked(path, buf.getvalue())


def _mesh_from_bytes(data: bytes):
    """(vertices, faces, timings, info, fit_loss) of a mesh entry's payload (:meth:`RunCaches.save_mesh`)."""
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        loss = float(z["fit_loss"])
        return (np.asarray(z["vertices"]), np.asarray(z["faces"]), json.loads(str(z["timings"])),
                json.loads(str(z["info"])), None if np.isnan(loss) else loss)
