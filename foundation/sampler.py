"""The shared training sampler: one set of samples that every method draws from.

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
point the point-based methods get. Surface centres are drawn by the project's one surface sampler
(:func:`foundation.surface.sample_surface`). Every draw comes from the one ``numpy.random.Generator``
the caller passes: the run layer passes ``job_streams(shape_hash, seed).sampler_rng()``
(:mod:`foundation.seeding`), so the same (shape, seed) gives the same samples for every method.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from foundation.surface import sample_surface

#: (name, fraction of M, centre kind, sigma) for the five groups of the paper.
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
    """

    centres: np.ndarray
    points: np.ndarray
    segments: np.ndarray
    group: np.ndarray

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


def sample_training_data(vertices: np.ndarray, faces: np.ndarray, total: int, rng: np.random.Generator) -> Samples:
    """Draw the five-group samples (points and segments from the same centres) for one shape.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Mesh vertices, canonical frame.
    faces : (F, 3) array_like of int
        Triangles.
    total : int
        M, the number of centres (= points = segments).
    rng : numpy.random.Generator
        The one source of every draw, in this order: the surface centres of the three surface
        groups (:func:`foundation.surface.sample_surface`), the bbox centres, the space centres,
        then the noise ``e1`` and ``e2``.

    Returns
    -------
    Samples
        float32 arrays in the canonical frame, groups in :data:`GROUPS` order.
    """
    if total <= 0:
        raise ValueError(f"sample count must be positive, got {total}")
    vertices = np.asarray(vertices, dtype=np.float64)
    used = vertices[np.unique(faces)]
    lo, hi = used.min(axis=0) - BBOX_PADDING, used.max(axis=0) + BBOX_PADDING
    counts = group_counts(total)
    centres, sigmas, groups = [], [], []
    n_surface = int(sum(c for c, g in zip(counts, GROUPS) if g[2] == "surface"))
    surface, _ = sample_surface(vertices, faces, n_surface, rng)
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
    return Samples(c.astype(np.float32), points, segments, np.concatenate(groups))
