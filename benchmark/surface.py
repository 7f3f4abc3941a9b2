"""Area-uniform samples on a triangle mesh: the project's one surface sampler.

The metrics (:mod:`benchmark.metrics`, SPEC section 7) and the training sampler
(:mod:`benchmark.sampler`, SPEC section 3) both draw their surface points with
:func:`sample_surface`, so "a point on the mesh" means the same thing everywhere.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sample_surface"]


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points on a triangle mesh, with the unit normal of their face.

    Face ``f`` is drawn with probability ``area_f / sum(area)`` (zero-area faces never), then a
    uniform point ``a + u (b - a) + v (c - a)`` with ``(u, v)`` uniform on the unit triangle
    (``u, v ~ U[0, 1)``, reflected to ``(1 - u, 1 - v)`` when ``u + v > 1``). Normal:
    ``(b - a) x (c - a) / |...|``.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex positions (any length unit; the points come out in the same unit).
    faces : (F, 3) array_like of int
        Vertex indices of the triangles.
    n : int
        Number of points.
    rng : numpy.random.Generator
        Source of the ``3 n`` uniform draws (``n`` for the faces, then ``(n, 2)`` for ``(u, v)``);
        the result is a deterministic function of its state.

    Returns
    -------
    points : (n, 3) float64 ndarray
        Points on the surface, same unit as ``vertices``.
    normals : (n, 3) float64 ndarray
        Unit normal of the face each point came from (orientation as the face's vertex order).

    Raises
    ------
    TypeError
        When ``rng`` is not a Generator (seeds become generators in :mod:`benchmark.seeding` only).
    ValueError
        When the mesh has no face of positive finite area.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    a = vertices[faces[:, 0]]
    e1 = vertices[faces[:, 1]] - a
    e2 = vertices[faces[:, 2]] - a
    cross = np.cross(e1, e2)
    double_area = np.linalg.norm(cross, axis=1)
    double_area = np.where(np.isfinite(double_area), double_area, 0.0)
    cumulative = np.cumsum(double_area)
    total = cumulative[-1] if len(cumulative) else 0.0
    if not total > 0:
        raise ValueError("mesh has no face with positive area to sample")
    # face f is chosen when cumulative[f-1] <= x < cumulative[f]: a zero-area face never is
    face = np.searchsorted(cumulative, rng.random(n) * total, side="right")
    face = np.minimum(face, np.flatnonzero(double_area > 0)[-1])
    uv = rng.random((n, 2))
    flip = uv.sum(axis=1) > 1.0
    uv[flip] = 1.0 - uv[flip]
    points = a[face] + uv[:, :1] * e1[face] + uv[:, 1:] * e2[face]
    normals = cross[face] / double_area[face, None]
    return points, normals
