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
        raise MeshError(f"{what}: no vertices")
    if faces.ndim != 2 or len(faces) == 0:
        raise MeshError(f"{what}: no faces")
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

    Scenes (glTF, multi-object OBJ) become one mesh. Vertices are not merged, except that an
    unindexed file (STL stores three vertices per triangle) is welded at exactly equal positions.
    """
    path = Path(path)
    what = str(path)
    if not path.exists():
        raise MeshError(f"{what}: file not found")
    if path.is_dir():
        raise MeshError(f"{what}: is a directory, not a mesh file")
    if path.suffix.lower() not in MESH_EXTENSIONS:
        raise MeshError(f"{what}: unsupported extension '{path.suffix}' (use one of {', '.join(MESH_EXTENSIONS)})")
    if path.stat().st_size == 0:
        raise MeshError(f"{what}: file is empty")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False, maintain_order=True)
    except Exception as exc:  # trimesh raises many exception types on corrupt files
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MeshError(f"{what}: unreadable ({msg})") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{what}: contains no triangle mesh (got {type(loaded).__name__})")
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces)
    if path.suffix.lower() == ".stl" and len(faces) and len(vertices) == 3 * len(faces):
        vertices, faces = weld_exact(vertices, faces)
    return validate_arrays(vertices, faces, what)


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
