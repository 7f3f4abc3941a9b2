"""Directory datasets: any folder of meshes, ABC meshes filtered by a list, non-manifold ABC
pairs, and the SALS paper's two ABC test sets as named, checked datasets (``sals-abc50``,
``sals-nonmanifold50``: committed lists and SHA-256 manifest, default folder
``../shared/data/abc-ppsurf``).

Folders are scanned recursively by default (``recursive=True``; the raw ABC layout keeps each model
in its own sub-folder), skipping hidden files and folders; files are sorted by their path relative
to ``data_dir``. Only the file names are read when a dataset is built (and, with a ``manifest``,
the bytes of the matched files, to check their SHA-256): meshes are opened by ``load(name)``,
which raises :class:`~datasets.io.MeshError` for that shape alone.

ABC list matching (``match_list_entry``): an entry ``<id>_<hash>_trimesh_<NNN>`` (the ABC stem)
matches, in this order of preference,

1. the file whose stem equals the entry;
2. a file whose stem has no ``_trimesh_NNN`` suffix and equals the entry's ``<id>_<hash>`` (a
   mesh stored under the model name, without the part number);
3. for an entry without the suffix (``<id>_<hash>`` or only the 8-digit ``<id>``), the first file
   in sorted order whose stem starts with it followed by ``_`` (or equals it).

A stem that appears with several extensions resolves to the first of ``.ply .obj .off .stl .glb
.gltf`` (then the shortest relative path).
"""

from __future__ import annotations

import re
import warnings
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from datasets.io import MESH_EXTENSIONS, MeshError, Shape, classify_topology, load_shape, normalize_shape
from datasets.manifest import check_file, read_manifest
from datasets.registry import (
    Dataset,
    DatasetError,
    DatasetNotFoundError,
    MissingShapesWarning,
    as_bool,
    as_int,
    existing_dir,
    register_dataset,
    select_subset,
    shared_data_dir,
)

#: Preference among files sharing a stem.
EXTENSION_PREFERENCE = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")

_ABC_STEM = re.compile(r"^(?P<id>\d{8})(?:_(?P<hash>[0-9a-fA-F]{8,}))?(?P<part>_trimesh_\d+)?$")


def scan_meshes(data_dir: Path, recursive: bool = True) -> list[Path]:
    """Mesh files (extensions in MESH_EXTENSIONS, any case) under ``data_dir``, sorted by relative
    path; hidden files and folders (names starting with '.') are skipped."""
    pattern = "**/*" if recursive else "*"
    found = [
        p for p in data_dir.glob(pattern)
        if p.suffix.lower() in MESH_EXTENSIONS
        and p.is_file()
        and not any(part.startswith(".") for part in p.relative_to(data_dir).parts)
    ]
    return sorted(found, key=lambda p: p.relative_to(data_dir).as_posix())


def index_by_stem(files: list[Path], data_dir: Path) -> dict[str, Path]:
    """stem -> file; a stem present several times keeps the preferred extension, then the shortest
    relative path (see module docstring)."""
    def rank(p: Path):
        ext = p.suffix.lower()
        order = EXTENSION_PREFERENCE.index(ext) if ext in EXTENSION_PREFERENCE else len(EXTENSION_PREFERENCE)
        rel = p.relative_to(data_dir).as_posix()
        return (order, len(rel), rel)

    index: dict[str, Path] = {}
    for path in sorted(files, key=rank):
        index.setdefault(path.stem, path)
    return dict(sorted(index.items()))


def read_list_file(path: Any) -> list[str]:
    """Entries of a list file: one per line, surrounding blanks stripped, blank lines and '#'
    comments (whole-line or trailing) ignored, duplicates dropped (first kept)."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise DatasetNotFoundError(f"list file {path} does not exist")
    entries = [line.split("#", 1)[0].strip() for line in path.read_text(encoding="utf-8", errors="replace").splitlines()]
    return list(dict.fromkeys(e for e in entries if e))


def match_list_entry(entry: str, index: dict[str, Path]) -> Path | None:
    """The file for one ABC list entry (rules in the module docstring), or None."""
    if entry in index:
        return index[entry]
    parsed = _ABC_STEM.match(entry)
    if parsed is None:
        return None
    if parsed.group("part"):
        model = entry[: parsed.start("part")]
        if parsed.group("hash") and model in index:
            return index[model]
        return None
    prefix = entry + "_"
    for stem, path in index.items():  # sorted: first match wins
        if stem.startswith(prefix) or stem == entry:
            return path
    return None


def _load_with_kind(path: Path, name: str, kind: str | None) -> Shape:
    shape = load_shape(path, name=name)
    shape.kind = kind or classify_topology(shape.faces)
    return shape


class _FolderDataset(Dataset):
    """Shared code: a name -> file mapping built from a folder listing."""

    def __init__(self, data_dir, recursive, limit, seed, kind):
        self.data_dir = existing_dir(data_dir, self.name)
        self.recursive = as_bool(recursive, "recursive")
        self.limit = as_int(limit, "limit", minimum=0, allow_none=True)
        self.seed = as_int(seed, "seed", allow_none=True)
        if kind is not None and kind not in ("closed", "open", "nonmanifold"):
            raise DatasetError(f"option 'kind' must be closed, open or nonmanifold, got {kind!r}")
        self.kind = kind
        self.files = scan_meshes(self.data_dir, self.recursive)
        self.missing: list[str] = []

    def _shape_path(self, name: str) -> Path:
        if name not in self._paths:
            raise self._unknown_shape(name)
        return self._paths[name]

    def names(self) -> list[str]:
        return list(self._paths)

    def load(self, name: str) -> Shape:
        return _load_with_kind(self._shape_path(name), name, self.kind)

    def stored_files(self, name: str) -> tuple[tuple[Path, str], ...]:
        return ((self._shape_path(name), "mesh"),)

    def options(self) -> dict[str, Any]:
        return {"data_dir": str(self.data_dir), "recursive": self.recursive, "limit": self.limit,
                "seed": self.seed, "kind": self.kind}


@register_dataset("meshes")
class MeshFolderDataset(_FolderDataset):
    """Every mesh file (.obj .ply .stl .off .glb .gltf) in ``data_dir``, sorted by relative path;
    recursive by default. Shape names are file stems, or the relative path with extension
    ('sub/part.ply') for files whose stem is not unique. ``kind`` (default: from the topology of each mesh,
    see :func:`datasets.io.classify_topology`) labels the shapes. ``limit``/``seed``: see
    :func:`datasets.registry.select_subset`."""

    name = "meshes"

    def __init__(self, data_dir=None, recursive=True, limit=None, seed=None, kind=None):
        super().__init__(data_dir, recursive, limit, seed, kind)
        if not self.files:
            raise DatasetError(f"dataset 'meshes': no mesh files ({' '.join(MESH_EXTENSIONS)}) in {self.data_dir}")
        stem_uses = Counter(p.stem for p in self.files)
        names = [p.stem if stem_uses[p.stem] == 1 else p.relative_to(self.data_dir).as_posix() for p in self.files]
        chosen = set(select_subset(names, self.limit, self.seed))
        self._paths = {n: p for n, p in zip(names, self.files) if n in chosen}


@register_dataset("abc")
class ABCDataset(_FolderDataset):
    """ABC meshes in ``data_dir`` (recursive by default), optionally filtered by ``list_file`` (one
    ABC stem per line, matched as in the module docstring, shapes named and ordered as the list).
    Entries with no file are listed in ``.missing`` and reported by one MissingShapesWarning line;
    ``strict=True`` raises DatasetError instead. Without a list: every mesh file, named by stem,
    sorted. ``manifest`` (a SHA-256 manifest, :mod:`datasets.manifest`, paths relative to
    ``data_dir``): every matched file is checked against it when the dataset is built; a shape whose
    file is altered or not pinned is left out (in ``.missing``) with one MissingShapesWarning line
    naming the file (DatasetError with ``strict=True``). ``limit``/``seed`` then pick a subset
    (first ``limit``, or a seeded random subset) of the shapes that remain."""

    name = "abc"

    def __init__(self, data_dir=None, list_file=None, limit=None, seed=None, strict=False, recursive=True, kind=None,
                 manifest=None):
        super().__init__(data_dir, recursive, limit, seed, kind)
        self.list_file = None if list_file in (None, "") else Path(list_file).expanduser()
        self.manifest = None if manifest in (None, "") else Path(manifest).expanduser()
        self.strict = as_bool(strict, "strict")
        self.by_stem = index_by_stem(self.files, self.data_dir)
        if self.list_file is None:
            paths = dict(self.by_stem)
        else:
            entries = read_list_file(self.list_file)
            matched = {e: match_list_entry(e, self.by_stem) for e in entries}
            paths = {e: p for e, p in matched.items() if p is not None}
            self.missing = [e for e, p in matched.items() if p is None]
            _report_missing(self, len(entries))
        paths = {n: files[0] for n, files in _keep_pinned(self, {n: (p,) for n, p in paths.items()}).items()}
        if not paths:
            what = f"matching {self.list_file}" if self.list_file else f"({' '.join(MESH_EXTENSIONS)})"
            raise DatasetError(f"dataset '{self.name}': no mesh files {what} in {self.data_dir}")
        chosen = set(select_subset(list(paths), self.limit, self.seed))
        self._paths = {n: p for n, p in paths.items() if n in chosen}

    def options(self) -> dict[str, Any]:
        return {**super().options(), "list_file": None if self.list_file is None else str(self.list_file),
                "strict": self.strict, "manifest": None if self.manifest is None else str(self.manifest)}

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "missing": list(self.missing),
                "files": {n: p.relative_to(self.data_dir).as_posix() for n, p in self._paths.items()}}


@register_dataset("abc-nonmanifold")
class ABCNonManifoldDataset(ABCDataset):
    """Non-manifold ABC shapes: each ``list_file`` line ``A+B`` names two ABC stems; the shape is the
    soup of both normalised parts (:func:`compose_soup`), named ``A+B``, kind 'nonmanifold'. Lines
    whose parts lack a file are in ``.missing`` (warning, or DatasetError with ``strict=True``).
    Without a list, the sorted stems of ``data_dir`` are paired consecutively (1st+2nd, 3rd+4th,
    ...; an odd last one is left out). ``manifest``: as for ``abc``; a pair with an altered or
    unpinned part is left out (one warning line per such file, naming the pairs it leaves out)."""

    name = "abc-nonmanifold"

    def __init__(self, data_dir=None, list_file=None, limit=None, seed=None, strict=False, recursive=True,
                 manifest=None):
        _FolderDataset.__init__(self, data_dir, recursive, limit, seed, "nonmanifold")
        self.list_file = None if list_file in (None, "") else Path(list_file).expanduser()
        self.manifest = None if manifest in (None, "") else Path(manifest).expanduser()
        self.strict = as_bool(strict, "strict")
        self.by_stem = index_by_stem(self.files, self.data_dir)
        if self.list_file is None:
            stems = list(self.by_stem)
            pairs = {f"{a}+{b}": (self.by_stem[a], self.by_stem[b]) for a, b in zip(stems[0::2], stems[1::2])}
        else:
            lines = read_list_file(self.list_file)
            malformed = [line for line in lines if line.count("+") != 1 or "" in line.split("+")]
            if malformed:
                raise DatasetError(f"{self.list_file}: line {malformed[0]!r} is not of the form A+B")
            pairs, self.missing = {}, []
            for line in lines:
                a, b = (part.strip() for part in line.split("+"))
                path_a, path_b = match_list_entry(a, self.by_stem), match_list_entry(b, self.by_stem)
                if path_a is None or path_b is None:
                    self.missing.append(line)
                else:
                    pairs[f"{a}+{b}"] = (path_a, path_b)
            _report_missing(self, len(lines))
        pairs = _keep_pinned(self, pairs)
        if not pairs:
            what = f" matching {self.list_file}" if self.list_file else ""
            raise DatasetError(f"dataset '{self.name}': no complete pair of meshes{what} in {self.data_dir}")
        chosen = set(select_subset(list(pairs), self.limit, self.seed))
        self._pairs = {n: p for n, p in pairs.items() if n in chosen}
        self._paths = {n: p[0] for n, p in self._pairs.items()}

    def load(self, name: str) -> Shape:
        self._shape_path(name)
        part_names = name.split("+")
        parts = [load_shape(path, name=n) for path, n in zip(self._pairs[name], part_names)]
        return compose_soup(name, parts)

    def stored_files(self, name: str) -> tuple[tuple[Path, str], ...]:
        self._shape_path(name)
        return tuple((path, "mesh") for path in self._pairs[name])

    def describe(self) -> dict[str, Any]:
        return {**Dataset.describe(self), "missing": list(self.missing),
                "files": {n: [p.relative_to(self.data_dir).as_posix() for p in pair] for n, pair in self._pairs.items()}}


#: The committed lists and manifest of the SALS paper's ABC test sets (docs/ABC-UNSEEN.md, "The
#: SALS paper's test sets"): the 50 parts, the 50 pairs of the same parts, the SHA-256 of the parts.
LISTS_DIR = Path(__file__).resolve().parents[1] / "lists"
SALS_ABC_LIST = LISTS_DIR / "sals-abc50.txt"
SALS_NONMANIFOLD_LIST = LISTS_DIR / "sals-nonmanifold50.txt"
SALS_ABC_MANIFEST = LISTS_DIR / "sals-abc50.sha256"
#: Where the paper's parts live by default: ``abc-ppsurf`` in the shared data folder.
PPSURF_SUBDIR = "abc-ppsurf"


def default_ppsurf_dir() -> Path:
    """``abc-ppsurf`` in :func:`~datasets.registry.shared_data_dir` (the 104 raw ABC parts of
    cg-tuwien/ppsurf_modeling: every part of the SALS paper's lists)."""
    return shared_data_dir() / PPSURF_SUBDIR


@register_dataset("sals-abc50")
class SALSABCDataset(ABCDataset):
    """The SALS paper's ABC test set: the 50 parts of ``lists/sals-abc50.txt`` (rsy6318/SALS,
    ``data/abc_list.txt``), in its order, each file checked against ``lists/sals-abc50.sha256``.
    A missing or altered file is one MissingShapesWarning line naming it, and the other parts run
    (``strict=True``: DatasetError instead). ``data_dir``: default ``../shared/data/abc-ppsurf``
    (:func:`default_ppsurf_dir`); any folder holding the same files (found recursively by stem).
    ``limit``/``seed``: as for ``abc``."""

    name = "sals-abc50"

    def __init__(self, data_dir=None, limit=None, seed=None, strict=False):
        super().__init__(default_ppsurf_dir() if data_dir in (None, "") else data_dir, list_file=SALS_ABC_LIST,
                         limit=limit, seed=seed, strict=strict, manifest=SALS_ABC_MANIFEST)


@register_dataset("sals-nonmanifold50")
class SALSNonManifoldDataset(ABCNonManifoldDataset):
    """The SALS paper's non-manifold ABC test set: the 50 ``A+B`` pairs of
    ``lists/sals-nonmanifold50.txt`` (rsy6318/SALS, ``data/non_manifold_abc_list.txt``; 41 of the
    50 parts of ``sals-abc50``), each pair the soup of its two parts (``abc-nonmanifold``), every part
    checked against ``lists/sals-abc50.sha256``. A missing or altered part is one warning line
    naming it and the pairs it leaves out; the other pairs run. ``data_dir``, ``limit``, ``seed``,
    ``strict``: as for ``sals-abc50``."""

    name = "sals-nonmanifold50"

    def __init__(self, data_dir=None, limit=None, seed=None, strict=False):
        super().__init__(default_ppsurf_dir() if data_dir in (None, "") else data_dir,
                         list_file=SALS_NONMANIFOLD_LIST, limit=limit, seed=seed, strict=strict,
                         manifest=SALS_ABC_MANIFEST)


def compose_soup(name: str, parts: list[Shape], kind: str = "nonmanifold") -> Shape:
    """One shape from several canonical-frame shapes: their triangles concatenated (vertex ids
    offset, no boolean union, no merging), then renormalised to the canonical frame.

    ``transform`` of the result maps the parts' common canonical frame to the final one (each
    part's own file -> canonical transform is in ``meta['parts']``)."""
    if not parts:
        raise MeshError(f"{name}: no parts to compose")
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    vertices = np.vstack([p.vertices for p in parts])
    faces = np.vstack([p.faces + o for p, o in zip(parts, offsets)])
    shape = normalize_shape(name, vertices, faces, source="+".join(p.source for p in parts), kind=kind)
    shape.meta["parts"] = [
        {"name": p.name, "source": p.source, "faces": int(len(p.faces)), "transform": p.transform.to_dict()} for p in parts
    ]
    return shape


def _report_missing(dataset: ABCDataset, total: int) -> None:
    if not dataset.missing:
        return
    shown = ", ".join(dataset.missing[:2]) + (", ..." if len(dataset.missing) > 2 else "")
    what = "name a pair of meshes" if isinstance(dataset, ABCNonManifoldDataset) else "name a mesh"
    message = (f"dataset '{dataset.name}': {len(dataset.missing)} of {total} lines of {dataset.list_file} do not "
               f"{what} found in {dataset.data_dir} ({shown}); see .missing")
    if dataset.strict:
        raise DatasetError(message)
    warnings.warn(message, MissingShapesWarning, stacklevel=4)


def _keep_pinned(dataset: ABCDataset, shapes: dict[str, tuple[Path, ...]]) -> dict[str, tuple[Path, ...]]:
    """``shapes`` (name -> its files) without those whose files fail ``dataset.manifest`` (all of
    them when it is None). Each failing file is one MissingShapesWarning line (DatasetError with
    ``strict``) naming it and the shapes it leaves out; those shapes go to ``dataset.missing``.
    Each file is read once, however many shapes use it."""
    if dataset.manifest is None:
        return shapes
    pins = read_manifest(dataset.manifest)
    problems: dict[Path, str | None] = {}
    left_out: dict[Path, list[str]] = {}
    kept = {}
    for name, files in shapes.items():
        for path in files:
            if path not in problems:
                pinned = pins.get(path.relative_to(dataset.data_dir).as_posix())
                problems[path] = check_file(path, pinned, dataset.manifest.name)
        bad = [path for path in files if problems[path]]
        for path in bad:
            left_out.setdefault(path, []).append(name)
        if bad:
            dataset.missing.append(name)
        else:
            kept[name] = files
    for path, names in left_out.items():
        shown = ", ".join(names[:2]) + (", ..." if len(names) > 2 else "")
        message = f"dataset '{dataset.name}': {problems[path]}; left out: {len(names)} shape(s) ({shown})"
        if dataset.strict:
            raise DatasetError(message)
        warnings.warn(message, MissingShapesWarning, stacklevel=4)
    return kept
