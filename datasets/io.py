"""Mesh loading, validation and the canonical normalisation.

Every shape in salsbench is a :class:`Shape`: triangle arrays in the canonical frame plus the
transform that maps them back to the file's frame. Loading never merges vertices silently (a CAD
mesh's topology is kept as stored; an unindexed STL is welded only at *exactly* coincident
positions, which is what its indexed form would have been), and every failure is a
:class:`MeshError` whose message is one line naming the file and the problem (what is wrong with
the file, never a bare exception of a parser); no numpy warning reaches the user.

Degeneracy is judged scale-free (:func:`foundation.surface.relative_area`), as in the canonical
frame: a valid mesh at 1e-300 or 1e300 loads like the same mesh at 1.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from foundation.errors import one_line
from foundation.storage import mesh_hash
from foundation.surface import MIN_RELATIVE_AREA, relative_area
from datasets.formats import (
    MeshError,
    ascii_stl_vertex_count,
    binary_stl,
    decode_text,
    parse_obj,
    parse_off,
    ply_bytes,
    stl_bytes,
)

#: File extensions the loaders accept.
MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

#: Largest side of the bounding box in the canonical frame.
CANONICAL_SIZE = 1.99
#: :attr:`Shape.kind` of a point cloud given without a GT mesh.
NO_GT = "no GT"


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
    kind : 'closed', 'open' or 'nonmanifold' (what the dataset says it is, for tables), or
        :data:`NO_GT` for a point cloud without a GT mesh.
    points : (p, 3) float64 input point cloud in the same canonical frame, for datasets of point-cloud
        files (the reconstruct task then uses it instead of sampling the mesh); None otherwise.
    sensors : (p, 3) float64, the position of the sensor that saw each of ``points`` (same frame),
        when the cloud file carries them (a scan); None otherwise.

    A shape without faces has no GT (:attr:`has_gt`): a point cloud given without a mesh, in the
    canonical frame of its own points; it can be reconstructed but not scored.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    transform: Normalization = IDENTITY
    source: str = ""
    kind: str = "closed"
    meta: dict = field(default_factory=dict)
    points: np.ndarray | None = None
    sensors: np.ndarray | None = None

    @property
    def has_gt(self) -> bool:
        """True when the shape has a GT mesh to score against (False: a point cloud alone)."""
        return len(self.faces) > 0

    def to_trimesh(self) -> trimesh.Trimesh:
        """A trimesh view of the arrays (no processing, no merging)."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    @property
    def content_hash(self) -> str:
        """SHA-256 (hex, 16 chars) of the canonical vertex and face arrays (and the input cloud, if
        any, and its sensors, if any): the cache key."""
        if self.points is None:
            return mesh_hash(self.vertices, self.faces)
        parts = mesh_hash(self.vertices, self.faces) + mesh_hash(self.points, np.zeros((0, 3)))
        if self.sensors is not None:
            parts += mesh_hash(self.sensors, np.zeros((0, 3)))
        return hashlib.sha256(parts.encode()).hexdigest()[:16]


def canonical_transform(vertices: np.ndarray) -> Normalization:
    """The canonical transform: centre the bounding box, scale its largest side to 1.99."""
    vertices = np.asarray(vertices, dtype=np.float64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    with np.errstate(over="ignore"):  # a box beyond float64 is refused below, in one line
        side = float(np.max(hi - lo))
        centre, scale = (lo + hi) / 2, CANONICAL_SIZE / side if side > 0 else 0.0
    if not side > 0:
        raise MeshError(f"bounding box has zero size (largest side {side})")
    if not (np.isfinite(side) and np.isfinite(scale) and np.all(np.isfinite(centre))):
        raise MeshError(f"bounding box (largest side {side:.3g}) cannot be normalised in float64")
    return Normalization(tuple(float(c) for c in centre), scale)


def validate_arrays(vertices: np.ndarray, faces: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Check triangle arrays; return them as float64 / int64. Raises :class:`MeshError`.

    Refused: no vertices, no faces, non-triangles, indices out of range, NaN/inf coordinates, all
    vertices at one point, and faces that lie on a line or a point (total area below
    :data:`~foundation.surface.MIN_RELATIVE_AREA` of the largest bounding-box side squared: the
    test of the canonical frame, so the mesh's scale does not matter).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise MeshError(f"{what}: no vertices found")
    if faces.ndim != 2 or len(faces) == 0:
        raise MeshError(f"{what}: {len(vertices)} vertices but no faces (a point cloud?); a triangle mesh is needed")
    if faces.shape[1] != 3:
        raise MeshError(f"{what}: faces have {faces.shape[1]} vertices after triangulation (need 3)")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{what}: face indices out of range [0, {len(vertices)})")
    if not np.all(np.isfinite(vertices)):
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise MeshError(f"{what}: {bad} vertices have NaN or infinite coordinates")
    used = vertices[np.unique(faces)]
    if np.all(used.min(axis=0) == used.max(axis=0)):
        raise MeshError(f"{what}: all vertices coincide (degenerate mesh)")
    area = relative_area(vertices, faces)
    if not area >= MIN_RELATIVE_AREA:
        raise MeshError(f"{what}: total surface area is zero relative to its size ({area:.3g} x the largest "
                        f"bounding-box side squared, below {MIN_RELATIVE_AREA:g}; degenerate mesh)")
    return vertices, faces


def read_mesh_arrays(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh file as (vertices, faces) in the file's own frame, validated
    (:func:`read_mesh_file`, then :func:`validate_arrays`)."""
    return validate_arrays(*read_mesh_file(path), str(path))


def read_mesh_file(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The (vertices (n, 3) float64, faces (m, 3) int64) a mesh file stores, content unchecked.

    The *file* is checked (one-line :class:`MeshError` when it is missing or not a readable mesh
    file of its extension); its *content* is not: the arrays may be empty, hold NaN or out-of-range
    indices (:func:`validate_arrays` refuses those; a prediction to score is read this way).

    * ``.obj`` and ``.off`` are read by this module's own parsers (:func:`parse_obj`,
      :func:`parse_off`): vertices exactly as listed, polygons fan-triangulated, nothing split or
      merged (trimesh's OBJ loader splits vertices per object/material group).
    * ``.stl``: binary when the size is 84 + 50 x the header's triangle count, else ASCII when it
      starts with ``solid`` and ends with ``endsolid`` (decoded here: UTF-8, else Latin-1, so
      trimesh's optional encoding detector never decides), else not an STL file. Parsed by trimesh;
      an ASCII file of which it reads fewer triangles than it has ``vertex`` lines / 3 is refused.
    * ``.ply``: the header is checked here (named problems instead of trimesh's bare KeyError) and
      so is the size of the data it declares (an ASCII line per element, a binary body long enough;
      before any allocation), then parsed by trimesh (a header in Latin-1 re-encoded as UTF-8);
      ``.glb``/``.gltf`` by trimesh. All with ``process=False``, trimesh's log and numpy's
      floating-point warnings silenced (:func:`quiet_trimesh`). A scene (glTF nodes, several
      PLY/STL solids) becomes one mesh: every triangle-mesh instance with its node transform
      applied, concatenated (vertex seams as stored: no merging).
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
    data = path.read_bytes()
    if not data:
        raise MeshError(f"{what}: file is empty")
    kind = suffix[1:].upper()
    try:
        if suffix in (".obj", ".off"):
            parse = parse_obj if suffix == ".obj" else parse_off
            return parse(decode_text(data, kind))
        # STL, PLY: trimesh reads the bytes checked (and decoded) here; glTF: the path (its resources)
        stl = stl_bytes(data) if suffix == ".stl" else None
        source = io.BytesIO(stl if stl is not None else ply_bytes(data)) if suffix in (".stl", ".ply") else str(path)
    except MeshError as exc:
        raise MeshError(f"{what}: {exc}") from None
    except (ValueError, IndexError, OverflowError) as exc:
        raise MeshError(f"{what}: unreadable {kind} ({one_line(exc, with_type=False)})") from None
    try:
        with quiet_trimesh():
            loaded = trimesh.load(source, file_type=suffix[1:], process=False, maintain_order=True)
    except Exception as exc:  # trimesh raises many exception types on corrupt files
        problem = "PLY data does not match its header" if suffix == ".ply" else f"unreadable {kind}"
        raise MeshError(f"{what}: {problem} ({one_line(exc, with_type=False)})") from None
    if isinstance(loaded, trimesh.Scene):
        meshes = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        if loaded.geometry and not meshes:
            kinds = sorted({type(g).__name__ for g in loaded.geometry.values()})
            raise MeshError(f"{what}: contains no triangle mesh (only {', '.join(kinds)})")
        with quiet_trimesh():
            loaded = loaded.to_mesh() if meshes else trimesh.Trimesh()
    if isinstance(loaded, trimesh.PointCloud):
        return np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3), np.zeros((0, 3), dtype=np.int64)
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{what}: contains no triangle mesh (got {type(loaded).__name__})")
    vertices = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    if stl is not None and not binary_stl(data) and ascii_stl_vertex_count(stl) != 3 * len(faces):
        raise MeshError(f"{what}: unreadable ASCII STL ({ascii_stl_vertex_count(stl):,} 'vertex' lines, but only "
                        f"{len(faces):,} whole triangles could be read: a malformed number or facet?)")
    if suffix == ".stl" and len(faces) and len(vertices) == 3 * len(faces):
        vertices, faces = weld_exact(vertices, faces)
    return vertices, faces


@contextlib.contextmanager
def quiet_trimesh():
    """Silence trimesh while it parses a file: its log (tracebacks of what it skips: a facet normal
    it cannot read, ...) and numpy's floating-point warnings (its normals of NaN/inf vertices). What
    is wrong with the file is said by our one-line error (:func:`validate_arrays` refuses NaN/inf)."""
    logger = logging.getLogger("trimesh")
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        with np.errstate(all="ignore"):
            yield
    finally:
        logger.setLevel(level)


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
