"""Mesh loading, validation and the canonical normalisation (SPEC sections 1-2).

Every shape in salsbench is a :class:`Shape`: triangle arrays in the canonical frame plus the
transform that maps them back to the file's frame. Loading never merges vertices silently (a CAD
mesh's topology is kept as stored; an unindexed STL is welded only at *exactly* coincident
positions, which is what its indexed form would have been), and every failure is a
:class:`MeshError` whose message is one line naming the file and the problem.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

#: File extensions the loaders accept.
MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

#: Largest side of the bounding box in the canonical frame (SPEC section 1).
CANONICAL_SIZE = 1.99


class MeshError(ValueError):
    """A mesh that cannot be used; the message is one line naming the file and the problem."""


@dataclass(frozen=True)
class Normalization:
    """canonical = (original - centre) * scale; original = canonical / scale + centre."""

    centre: tuple[float, float, float]
    scale: float

    def apply(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - np.asarray(self.centre)) * self.scale

    def invert(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) / self.scale + np.asarray(self.centre)

    def then(self, other: "Normalization") -> "Normalization":
        """The composition: first self, then other (both maps are scale + translation)."""
        scale = self.scale * other.scale
        # other.apply(self.apply(x)) = ((x - c1) s1 - c2) s2 = (x - (c1 + c2 / s1)) s1 s2
        centre = tuple(np.asarray(self.centre) + np.asarray(other.centre) / self.scale)
        return Normalization(tuple(float(c) for c in centre), float(scale))

    def to_dict(self) -> dict:
        return {"centre": list(self.centre), "scale": self.scale}


IDENTITY = Normalization((0.0, 0.0, 0.0), 1.0)


@dataclass
class Shape:
    """A triangle mesh in the canonical frame.

    Attributes
    ----------
    name : unique name within a dataset (file stem for real meshes).
    vertices : (n, 3) float64, canonical frame (inside [-0.995, 0.995]^3).
    faces : (m, 3) int64 vertex indices.
    transform : maps the source file's frame to the canonical frame.
    source : where the shape came from (a path, or a generator description).
    kind : 'closed', 'open' or 'nonmanifold' (what the dataset says it is, for tables).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    transform: Normalization = IDENTITY
    source: str = ""
    kind: str = "closed"
    meta: dict = field(default_factory=dict)

    def to_trimesh(self) -> trimesh.Trimesh:
        """A trimesh view of the arrays (no processing, no merging)."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    @property
    def content_hash(self) -> str:
        """SHA-256 (hex, 16 chars) of the canonical vertex and face arrays: the cache key."""
        return mesh_hash(self.vertices, self.faces)


def mesh_hash(vertices: np.ndarray, faces: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.hexdigest()[:16]


def canonical_transform(vertices: np.ndarray) -> Normalization:
    """The SPEC section 1 transform: centre the bounding box, scale its largest side to 1.99."""
    vertices = np.asarray(vertices, dtype=np.float64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    side = float(np.max(hi - lo))
    if not np.isfinite(side) or side <= 0:
        raise MeshError(f"bounding box has zero size (largest side {side})")
    return Normalization(tuple(float(c) for c in (lo + hi) / 2), CANONICAL_SIZE / side)


def validate_arrays(vertices: np.ndarray, faces: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Check triangle arrays; return them as float64 / int64. Raises :class:`MeshError`."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise MeshError(f"{what}: no vertices found")
    if faces.ndim != 2 or len(faces) == 0:
        raise MeshError(f"{what}: no faces found")
    if faces.shape[1] != 3:
        raise MeshError(f"{what}: faces have {faces.shape[1]} vertices after triangulation (need 3)")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{what}: face indices out of range [0, {len(vertices)})")
    if not np.all(np.isfinite(vertices)):
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise MeshError(f"{what}: {bad} vertices have NaN or infinite coordinates")
    used = vertices[np.unique(faces)]
    if np.ptp(used, axis=0).max() <= 0:
        raise MeshError(f"{what}: all vertices coincide (degenerate mesh)")
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    if not area > 0:
        raise MeshError(f"{what}: total surface area is zero (degenerate mesh)")
    return vertices, faces


def read_mesh_arrays(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh file as raw (vertices, faces) in the file's own frame, validated.

    * ``.obj`` and ``.off`` are read by this module's own parsers (:func:`parse_obj`,
      :func:`parse_off`): vertices exactly as listed, polygons fan-triangulated, nothing split or
      merged (trimesh's OBJ loader splits vertices per object/material group).
    * ``.ply``, ``.stl``, ``.glb``/``.gltf`` go through trimesh with ``process=False``. A scene
      (glTF nodes, several PLY/STL solids) becomes one mesh: every triangle-mesh instance with its
      node transform applied, concatenated (vertex seams as stored: no merging).
    * Only an unindexed file (STL stores three vertices per triangle) is welded, at exactly equal
      positions, which is what its indexed form would have been.
    """
    path = Path(path)
    what = str(path)
    if not path.exists():
        raise MeshError(f"{what}: file not found")
    if path.is_dir():
        raise MeshError(f"{what}: is a directory, not a mesh file")
    suffix = path.suffix.lower()
    if suffix not in MESH_EXTENSIONS:
        raise MeshError(f"{what}: unsupported extension '{path.suffix}' (use one of {', '.join(MESH_EXTENSIONS)})")
    if path.stat().st_size == 0:
        raise MeshError(f"{what}: file is empty")
    if suffix in (".obj", ".off"):
        text = _read_text(path, what)
        parse = parse_obj if suffix == ".obj" else parse_off
        try:
            vertices, faces = parse(text)
        except MeshError as exc:
            raise MeshError(f"{what}: {exc}") from None
        except (ValueError, IndexError, OverflowError) as exc:
            raise MeshError(f"{what}: unreadable {suffix[1:].upper()} ({_one_line(exc)})") from None
        return validate_arrays(vertices, faces, what)
    try:
        loaded = trimesh.load(str(path), process=False, maintain_order=True)
    except Exception as exc:  # trimesh raises many exception types on corrupt files
        raise MeshError(f"{what}: unreadable ({_one_line(exc)})") from None
    if isinstance(loaded, trimesh.Scene):
        kinds = sorted({type(g).__name__ for g in loaded.geometry.values()})
        if not any(isinstance(g, trimesh.Trimesh) for g in loaded.geometry.values()):
            found = f"only {', '.join(kinds)}" if kinds else "nothing readable"
            raise MeshError(f"{what}: contains no triangle mesh ({found})")
        loaded = loaded.to_mesh()
    if isinstance(loaded, trimesh.PointCloud):
        raise MeshError(f"{what}: is a point cloud ({len(loaded.vertices)} vertices, no faces); a triangle mesh is needed")
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{what}: contains no triangle mesh (got {type(loaded).__name__})")
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces)
    if len(vertices) and not len(faces):
        raise MeshError(f"{what}: has {len(vertices)} vertices but no faces (a point cloud?); a triangle mesh is needed")
    if suffix == ".stl" and len(faces) and len(vertices) == 3 * len(faces):
        vertices, faces = weld_exact(vertices, faces)
    return validate_arrays(vertices, faces, what)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return " ".join(text.split())[:200] if text else type(exc).__name__


def _read_text(path: Path, what: str) -> str:
    """A text mesh file as str; binary data gives a one-line MeshError."""
    data = path.read_bytes()
    head = np.frombuffer(data[:65536], dtype=np.uint8)
    control = (head < 32) & ~np.isin(head, (9, 10, 11, 12, 13))
    if control.any():
        raise MeshError(f"{what}: holds binary data, not a text {path.suffix[1:].upper()} file")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # comments/names in a legacy encoding; numbers are ASCII


def _numbers_per_line(lines: list[str] | tuple[str, ...], dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """Parse whitespace-separated numbers of many lines at once.

    Returns ``(values, counts)``: all numbers flat in reading order and how many each line holds
    (vectorised: the separators are counted in one byte array, no loop over lines).
    """
    if len(lines) == 0:
        return np.zeros(0, dtype), np.zeros(0, np.int64)
    joined = "\n".join(" ".join(line.split()) for line in lines)
    buffer = np.frombuffer(joined.encode("utf-8", errors="replace"), dtype=np.uint8)
    line_of_byte = np.concatenate([[0], np.cumsum(buffer == 10)[:-1]])
    is_token_start = (buffer > 32) & np.concatenate([[True], buffer[:-1] <= 32])
    counts = np.bincount(line_of_byte[is_token_start], minlength=len(lines)).astype(np.int64)
    values = np.array(joined.split(), dtype=np.float64)
    if dtype is not np.float64:
        if not np.all(np.isfinite(values)) or np.any(values != np.round(values)):
            raise MeshError("face line holds a non-integer vertex index")
        values = values.astype(dtype)
    return values, counts


def _fan_triangles(indices: np.ndarray, starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons stored flat: polygon p is ``indices[starts[p] : starts[p] + sizes[p]]``
    and becomes triangles (v0, v_j, v_j+1), j = 1 .. size - 2 (the order trimesh and most tools use)."""
    if np.any(sizes < 3):
        bad = int(np.flatnonzero(sizes < 3)[0])
        raise MeshError(f"face {bad + 1} has {int(sizes[bad])} vertices (need at least 3)")
    per_polygon = sizes - 2
    polygon = np.repeat(np.arange(len(sizes)), per_polygon)
    j = np.arange(len(polygon)) - np.repeat(np.cumsum(per_polygon) - per_polygon, per_polygon) + 1
    first = starts[polygon]
    return np.stack([indices[first], indices[first + j], indices[first + j + 1]], axis=1)


_OBJ_LINE = re.compile(r"^[ \t]*(v|f)[ \t]+([^\r\n#]*)", re.M)


def parse_obj(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (first three numbers of each ``v`` line, in file order) and fan-triangulated ``f``
    polygons of an OBJ text. Texture/normal indices (``v/vt/vn``) are ignored; negative indices
    count back from the last vertex defined before the face (OBJ rule). Other statements (``vt``,
    ``vn``, ``o``, ``g``, ``usemtl``, lines, points) are ignored; groups share one vertex list."""
    matches = _OBJ_LINE.findall(text)
    if not matches:
        raise MeshError("no vertices found (not an OBJ mesh?)")
    tags, rests = zip(*matches)
    is_vertex = np.array(tags) == "v"
    vertex_lines = [r for r, v in zip(rests, is_vertex) if v]
    face_lines = [r for r, v in zip(rests, is_vertex) if not v]
    if not vertex_lines:
        raise MeshError("no vertices found (not an OBJ mesh?)")
    values, counts = _numbers_per_line(vertex_lines)
    if np.any(counts < 3):
        bad = int(np.flatnonzero(counts < 3)[0])
        raise MeshError(f"vertex {bad + 1} has {int(counts[bad])} coordinates (need 3)")
    starts = np.cumsum(counts) - counts
    vertices = values[starts[:, None] + np.arange(3)]
    if not face_lines:
        raise MeshError(f"{len(vertices)} vertices but no faces (a point cloud?); a triangle mesh is needed")
    face_text = re.sub(r"/[^\s]*", "", "\n".join(face_lines)).split("\n")
    indices, sizes = _numbers_per_line(face_text, dtype=np.int64)
    if np.any(indices == 0):
        raise MeshError("face index 0 (OBJ indices start at 1)")
    # vertices defined before each face line, for negative (relative) indices
    defined_before = np.cumsum(is_vertex)[~is_vertex]
    per_index = np.repeat(defined_before, sizes)
    indices = np.where(indices < 0, per_index + indices, indices - 1)
    faces = _fan_triangles(indices, np.cumsum(sizes) - sizes, sizes)
    return vertices, faces


_OFF_HEADER = re.compile(r"^(ST)?(C)?(N)?(4)?(n)?OFF(.*)$", re.I)


def parse_off(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and fan-triangulated faces of an OFF text.

    Accepts the common variants and quirks: ``OFF``/``COFF``/``NOFF``/``STOFF`` headers in any
    case, counts on the header line (``OFF 8 6 0``) or glued to it (ModelNet's ``OFF490 518 0``) or
    spread over lines, ``#`` comments anywhere, blank lines, CRLF, tabs, extra per-vertex columns
    (normals, colours, texture coordinates) and per-face colours after the indices."""
    lines = [line for line in (raw.split("#", 1)[0].strip() for raw in text.splitlines()) if line]
    if not lines:
        raise MeshError("no OFF header")
    header = _OFF_HEADER.match(lines[0])
    if header is None:
        raise MeshError(f"no OFF header (first line starts with {lines[0][:20]!r})")
    if header.group(4) or header.group(5):
        raise MeshError("4D / n-dimensional OFF is not supported")
    count_tokens = header.group(6).split()
    row = 1
    if not count_tokens and row < len(lines):  # counts on their own line (the usual layout)
        count_tokens, row = lines[row].split(), row + 1
    if len(count_tokens) == 1:  # counts spread over several lines: read all three
        while len(count_tokens) < 3 and row < len(lines):
            count_tokens, row = count_tokens + lines[row].split(), row + 1
    try:
        n_vertices, n_faces = int(count_tokens[0]), int(count_tokens[1])
    except (IndexError, ValueError):
        raise MeshError("malformed vertex/face count line") from None
    if n_vertices <= 0:
        raise MeshError("no vertices (vertex count is 0)")
    if n_faces <= 0:
        raise MeshError(f"{n_vertices} vertices but no faces (a point cloud?); a triangle mesh is needed")
    if len(lines) < row + n_vertices + n_faces:
        raise MeshError(
            f"file ends early: header promises {n_vertices} vertices and {n_faces} faces, "
            f"found {len(lines) - row} data lines"
        )
    values, counts = _numbers_per_line(lines[row : row + n_vertices])
    if np.any(counts < 3):
        bad = int(np.flatnonzero(counts < 3)[0])
        raise MeshError(f"vertex {bad + 1} has {int(counts[bad])} coordinates (need 3)")
    vertices = values[(np.cumsum(counts) - counts)[:, None] + np.arange(3)]
    values, counts = _numbers_per_line(lines[row + n_vertices : row + n_vertices + n_faces])
    line_starts = np.cumsum(counts) - counts
    sizes = values[line_starts]
    if np.any(sizes != np.round(sizes)) or np.any(counts < sizes + 1):
        bad = int(np.flatnonzero((sizes != np.round(sizes)) | (counts < sizes + 1))[0])
        raise MeshError(f"face {bad + 1} is malformed (its vertex count does not match its indices)")
    sizes = sizes.astype(np.int64)
    indices = values[np.repeat(line_starts + 1, sizes) + _ranks(sizes)]
    if np.any(indices != np.round(indices)):
        raise MeshError("face line holds a non-integer vertex index")
    faces = _fan_triangles(indices.astype(np.int64), np.cumsum(sizes) - sizes, sizes)
    return vertices, faces


def _ranks(sizes: np.ndarray) -> np.ndarray:
    """0, 1, .., sizes[0]-1, 0, 1, .., sizes[1]-1, ... (positions within consecutive runs)."""
    return np.arange(int(sizes.sum())) - np.repeat(np.cumsum(sizes) - sizes, sizes)


def classify_topology(faces: np.ndarray) -> str:
    """'closed' when every undirected edge has exactly two faces, 'nonmanifold' when some edge has
    more than two, else 'open' (some edge has one face: a boundary). Vertex ids as stored."""
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    if np.any(uses > 2):
        return "nonmanifold"
    return "closed" if np.all(uses == 2) else "open"


def weld_exact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices whose coordinates are bit-for-bit equal (no tolerance)."""
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[faces]


def load_shape(path: str | os.PathLike, name: str | None = None, kind: str = "closed") -> Shape:
    """Load, validate and normalise a mesh file into a :class:`Shape` (canonical frame)."""
    path = Path(path)
    vertices, faces = read_mesh_arrays(path)
    try:
        transform = canonical_transform(vertices[np.unique(faces)])
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None
    return Shape(
        name=name or path.stem,
        vertices=transform.apply(vertices),
        faces=faces,
        transform=transform,
        source=str(path),
        kind=kind,
    )


def normalize_shape(name: str, vertices: np.ndarray, faces: np.ndarray, source: str = "", kind: str = "closed") -> Shape:
    """Validate triangle arrays in any frame and return them as a canonical :class:`Shape`."""
    vertices, faces = validate_arrays(vertices, faces, name)
    transform = canonical_transform(vertices[np.unique(faces)])
    return Shape(name, transform.apply(vertices), faces, transform, source or name, kind)


def save_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a mesh (PLY/OBJ/...) without processing; creates parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=False, validate=False).export(str(path))
