"""The shared training sampler (SPEC section 3): one set of samples that every method draws from.

Centres ``c`` are drawn in five groups (fractions of the total count M, noise sigma in canonical
units):

=========  ========  ==========================================  =====
group      fraction  centre                                      sigma
=========  ========  ==========================================  =====
surface-1  0.50      area-uniform point on the mesh               0.005
surface-2  0.30      area-uniform point on the mesh               0.01
surface-3  0.10      area-uniform point on the mesh               0.03
bbox       0.08      uniform in the mesh AABB padded by 0.01      0.08
space      0.02      uniform in [-1, 1]^3                         0.08
=========  ========  ==========================================  =====

Point-based fields (BOF, SDF, UDF) train on ``x = c + e``; SALS trains on segments
``(u, v) = (c + e1, c + e2)`` with ``u == x``: the first endpoint of every segment is exactly the
point the point-based methods get. Everything comes from one ``numpy.random.Generator`` seeded by
(shape content hash, seed), so the same seed gives the same samples for every method.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

#: (name, fraction of M, centre kind, sigma) for the five groups (SPEC section 3, *paper*).
GROUPS: tuple[tuple[str, float, str, float], ...] = (
    ("surface-1", 0.50, "surface", 0.005),
    ("surface-2", 0.30, "surface", 0.01),
    ("surface-3", 0.10, "surface", 0.03),
    ("bbox", 0.08, "bbox", 0.08),
    ("space", 0.02, "space", 0.08),
)

#: Padding of the mesh's bounding box for the 'bbox' group, canonical units per side.
BBOX_PADDING = 0.01


@dataclass
class Samples:
    """Training samples shared by all methods, canonical frame, float32.

    Attributes
    ----------
    centres : (M, 3) the drawn centres c.
    points : (M, 3) x = c + e1, the samples of point-based fields.
    segments : (M, 2, 3) (u, v) = (c + e1, c + e2), with u == points.
    group : (M,) int8 index into :data:`GROUPS`.
    seed : the seed the generator was derived from.
    """

    centres: np.ndarray
    points: np.ndarray
    segments: np.ndarray
    group: np.ndarray
    seed: int

    def __len__(self) -> int:
        return len(self.points)


def group_counts(total: int) -> np.ndarray:
    """Split ``total`` samples into the five groups by their fractions (largest remainder)."""
    fractions = np.array([g[1] for g in GROUPS])
    raw = fractions * total
    counts = np.floor(raw).astype(np.int64)
    remainder = total - counts.sum()
    counts[np.argsort(-(raw - counts), kind="stable")[:remainder]] += 1
    return counts


def sampling_rng(shape_hash: str, seed: int) -> np.random.Generator:
    """The generator for (shape, seed): independent of process, platform and method."""
    digest = hashlib.sha256(f"{shape_hash}:{int(seed)}".encode()).digest()
    return np.random.default_rng(np.frombuffer(digest[:16], dtype=np.uint32))


def sample_surface_points(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` area-uniform points on a triangle mesh, (n, 3) float64 (faces by area, then barycentric)."""
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cdf = np.cumsum(area)
    face = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"), len(faces) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    flip = r1 + r2 > 1.0
    r1[flip], r2[flip] = 1.0 - r1[flip], 1.0 - r2[flip]
    t = tri[face]
    return t[:, 0] + r1[:, None] * (t[:, 1] - t[:, 0]) + r2[:, None] * (t[:, 2] - t[:, 0])


def sample_training_data(
    vertices: np.ndarray, faces: np.ndarray, total: int, seed: int, shape_hash: str | None = None
) -> Samples:
    """Draw the five-group samples (points and segments from the same centres) for one shape.

    Parameters
    ----------
    vertices, faces : the mesh in the canonical frame.
    total : M, the number of centres (= points = segments).
    seed : the run's seed; combined with ``shape_hash`` (default: hash of the arrays).
    """
    if total <= 0:
        raise ValueError(f"sample count must be positive, got {total}")
    if shape_hash is None:
        from datasets.io import mesh_hash  # local import: sampler works on plain arrays

        shape_hash = mesh_hash(vertices, faces)
    rng = sampling_rng(shape_hash, seed)
    vertices = np.asarray(vertices, dtype=np.float64)
    used = vertices[np.unique(faces)]
    lo, hi = used.min(axis=0) - BBOX_PADDING, used.max(axis=0) + BBOX_PADDING
    counts = group_counts(total)
    centres, sigmas, groups = [], [], []
    n_surface = int(sum(c for c, g in zip(counts, GROUPS) if g[2] == "surface"))
    surface = sample_surface_points(vertices, faces, n_surface, rng)
    offset = 0
    for gi, (count, (_, _, kind, sigma)) in enumerate(zip(counts, GROUPS)):
        if kind == "surface":
            c = surface[offset:offset + count]
            offset += count
        elif kind == "bbox":
            c = lo + rng.random((count, 3)) * (hi - lo)
        else:
            c = -1.0 + 2.0 * rng.random((count, 3))
        centres.append(c)
        sigmas.append(np.full(count, sigma))
        groups.append(np.full(count, gi, dtype=np.int8))
    c = np.concatenate(centres)
    sigma = np.concatenate(sigmas)[:, None]
    e1 = rng.standard_normal((total, 3)) * sigma
    e2 = rng.standard_normal((total, 3)) * sigma
    points = (c + e1).astype(np.float32)
    segments = np.stack([points, (c + e2).astype(np.float32)], axis=1)
    return Samples(c.astype(np.float32), points, segments, np.concatenate(groups), int(seed))
