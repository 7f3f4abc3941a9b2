"""Area-uniform samples on a triangle mesh and its scale-free area: the project's one owner of
"a point on the mesh" and of "this mesh has no area".

The metrics (:mod:`foundation.metrics`) and the training sampler
(:mod:`foundation.sampler`) both draw their surface points with
:func:`sample_surface`; mesh validation (:mod:`datasets.io`) and the metrics' empty-prediction
test both call a mesh degenerate by :func:`relative_area` and :data:`MIN_RELATIVE_AREA`.

Both work on the triangles rescaled by a power of two, ``2^-k`` with ``k`` the binary exponent of
the largest finite coordinate (:func:`binary_exponent`). Such a rescale is exact in floating point,
so the results equal those of the unscaled arithmetic wherever that neither overflows nor
underflows, and a mesh at 1e-300 or 1e300 is handled like one at 1 (its cross products would
otherwise underflow to 0 or overflow to inf).
"""

from __future__ import annotations

import numpy as np

__all__ = ["sample_surface", "relative_area", "MIN_RELATIVE_AREA", "binary_exponent"]

#: A mesh whose total area is below this fraction of its bounding box's largest side squared is
#: degenerate: its faces lie on a line or at a point, up to rounding (collinear float64 vertices
#: leave cross products of ~1e-16 side^2 per face).
MIN_RELATIVE_AREA = 1e-12


def binary_exponent(values: np.ndarray) -> int:
    """The ``k`` with ``max |finite value|`` in ``[2^(k-1), 2^k)`` (0 when there is none).

    ``np.ldexp(values, -k)`` is then an exact rescale of the finite values into (-1, 1)
    (exact unless a value falls below the normal range, ~2e-308, after scaling).
    """
    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    hi = np.max(values, where=finite, initial=0.0)
    lo = np.min(values, where=finite, initial=0.0)
    return int(np.frexp(max(hi, -lo))[1])


def _scaled_triangles(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """``(vertices[faces] * 2^-k, k)``: the (F, 3, 3) corners rescaled exactly into (-1, 1)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64).reshape(-1, 3)]
    k = binary_exponent(tri)
    return np.ldexp(tri, -k, out=tri), k


def relative_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total area of the triangles over the largest side of their bounding box, squared.

    Scale-free (a unit square: 1; a unit cube's surface: 6; collinear triangles: 0) and computed
    without overflow or underflow at any scale (module docstring). Faces with non-finite corners
    count as area 0 and do not widen the box.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex positions, any unit.
    faces : (F, 3) array_like of int
        Triangles (indices must be in range).

    Returns
    -------
    float
        ``sum(area) / max_side^2``, dimensionless; 0.0 without faces or without extent.
    """
    tri, _ = _scaled_triangles(vertices, faces)
    finite = np.all(np.isfinite(tri), axis=(1, 2))
    tri = tri[finite]
    if len(tri) == 0:
        return 0.0
    side = float(np.max(tri.max(axis=(0, 1)) - tri.min(axis=(0, 1))))
    area = 0.5 * float(np.sum(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)))
    return area / side**2 if side > 0 else 0.0


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points on a triangle mesh, with the unit normal of their face.

    Face ``f`` is drawn with probability ``area_f / sum(area)`` (zero-area faces never), then a
    uniform point ``a + u (b - a) + v (c - a)`` with ``(u, v)`` uniform on the unit triangle
    (``u, v ~ U[0, 1)``, reflected to ``(1 - u, 1 - v)`` when ``u + v > 1``). Normal:
    ``(b - a) x (c - a) / |...|``. Computed on the corners rescaled by a power of two (module
    docstring): exact, and free of overflow and underflow at any scale.

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
        When ``rng`` is not a Generator (seeds become generators in :mod:`foundation.seeding` only).
    ValueError
        When the mesh has no face of positive finite area.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    tri, k = _scaled_triangles(vertices, faces)
    a = tri[:, 0]
    with np.errstate(invalid="ignore"):  # corners at inf: NaN areas, never drawn (below)
        e1 = tri[:, 1] - a
        e2 = tri[:, 2] - a
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
    points = np.ldexp(a[face] + uv[:, :1] * e1[face] + uv[:, 1:] * e2[face], k)
    normals = cross[face] / double_area[face, None]
    return points, normals
