"""The regular grid every method is extracted on (SPEC section 1).

Frame: the canonical frame, the cube [-1, 1]^3. ``N`` points per axis, spacing ``h = 2 / (N - 1)``.

Conventions shared by the exact fields, the network queries and every extractor:

* Scalar grid fields are arrays of shape ``(N, N, N)`` indexed ``[i, j, k]`` -> point
  ``(-1 + i h, -1 + j h, -1 + k h)`` (``'ij'`` indexing, x index first). A vertex that
  scikit-image's ``marching_cubes`` returns in index coordinates maps to the frame with
  :func:`index_to_world`.
* Edges: for each axis ``a`` in (0, 1, 2) the edges along ``a`` start at grid point ``(i, j, k)``
  whose index along ``a`` is ``< N - 1``; they form an array of shape :func:`edge_shape` ``(N, a)``
  (``N - 1`` along ``a``, ``N`` elsewhere). The *flat edge order* concatenates the three axes,
  each in C order of its shape: 3 (N - 1) N^2 edges in all. An edge is stored lower endpoint
  first: ``u`` = start point, ``v = u + h e_a``.
* Cells: ``(N - 1)^3``, cell ``(i, j, k)`` spans ``[i, i+1] x [j, j+1] x [k, k+1]`` in index units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LOWER, UPPER = -1.0, 1.0


def spacing(N: int) -> float:
    """Grid spacing h = 2 / (N - 1) in canonical units."""
    if N < 2:
        raise ValueError(f"grid resolution N must be >= 2, got {N}")
    return (UPPER - LOWER) / (N - 1)


def axis_coords(N: int) -> np.ndarray:
    """The N coordinates of grid points along one axis, float64."""
    return np.linspace(LOWER, UPPER, N)


def grid_points(N: int, dtype=np.float64) -> np.ndarray:
    """All grid points, shape (N, N, N, 3), ``'ij'`` indexing."""
    c = axis_coords(N).astype(dtype)
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1)


def index_to_world(ijk: np.ndarray, N: int) -> np.ndarray:
    """Map (fractional) grid indices (..., 3) to canonical coordinates."""
    return LOWER + np.asarray(ijk, dtype=np.float64) * spacing(N)


def world_to_index(xyz: np.ndarray, N: int) -> np.ndarray:
    """Map canonical coordinates (..., 3) to fractional grid indices."""
    return (np.asarray(xyz, dtype=np.float64) - LOWER) / spacing(N)


def edge_shape(N: int, axis: int) -> tuple[int, int, int]:
    """Shape of the array of edges along ``axis``: N - 1 along it, N along the other two."""
    shape = [N, N, N]
    shape[axis] = N - 1
    return tuple(shape)


def edge_counts(N: int) -> tuple[int, int, int]:
    """Number of edges along each axis ((N - 1) N^2 each)."""
    return tuple(int(np.prod(edge_shape(N, a))) for a in range(3))


def edge_offsets(N: int) -> np.ndarray:
    """Start of each axis' block in the flat edge order, plus the total: shape (4,)."""
    return np.concatenate([[0], np.cumsum(edge_counts(N))])


def num_edges(N: int) -> int:
    """Total number of grid edges, 3 (N - 1) N^2 (6,242,304 at N = 128)."""
    return 3 * (N - 1) * N * N


def edge_start_indices(N: int) -> np.ndarray:
    """Integer grid index (i, j, k) of the lower endpoint of every edge, flat order, (E, 3) int32."""
    out = []
    for a in range(3):
        idx = np.indices(edge_shape(N, a), dtype=np.int32).reshape(3, -1).T
        out.append(idx)
    return np.concatenate(out, axis=0)


def edge_axes(N: int) -> np.ndarray:
    """Axis (0, 1, 2) of every edge in flat order, (E,) int8."""
    return np.repeat(np.arange(3, dtype=np.int8), edge_counts(N))


def edge_endpoints(N: int, edge_ids: np.ndarray | None = None, dtype=np.float32):
    """Endpoints ``(u, v)`` of edges in canonical coordinates, each (E, 3).

    ``edge_ids`` selects edges by flat index (default: all edges). ``u`` is the lower endpoint,
    ``v = u + h e_axis``.
    """
    ijk, axis = edge_index_to_ijk_axis(N, edge_ids)
    h = spacing(N)
    u = (LOWER + ijk * h).astype(dtype)
    v = u.copy()
    v[np.arange(len(v)), axis] += h
    return u, v


def edge_index_to_ijk_axis(N: int, edge_ids: np.ndarray | None = None):
    """Decode flat edge indices into (lower-endpoint grid index (E, 3) int64, axis (E,) int64)."""
    offsets = edge_offsets(N)
    if edge_ids is None:
        edge_ids = np.arange(offsets[-1], dtype=np.int64)
    edge_ids = np.asarray(edge_ids, dtype=np.int64)
    axis = np.searchsorted(offsets, edge_ids, side="right") - 1
    local = edge_ids - offsets[axis]
    ijk = np.empty((len(edge_ids), 3), dtype=np.int64)
    for a in range(3):  # three vectorised passes, one per axis block
        m = axis == a
        if np.any(m):
            ijk[m] = np.stack(np.unravel_index(local[m], edge_shape(N, a)), axis=-1)
    return ijk, axis


def ijk_axis_to_edge_index(N: int, ijk: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Flat edge index of the edge starting at grid index ``ijk`` (E, 3) along ``axis`` (E,)."""
    ijk = np.asarray(ijk, dtype=np.int64)
    axis = np.asarray(axis, dtype=np.int64)
    offsets = edge_offsets(N)
    out = np.empty(len(ijk), dtype=np.int64)
    for a in range(3):
        m = axis == a
        if np.any(m):
            out[m] = offsets[a] + np.ravel_multi_index(tuple(ijk[m].T), edge_shape(N, a))
    return out


def split_by_axis(values: np.ndarray, N: int) -> list[np.ndarray]:
    """Split a flat per-edge array (E, ...) into three arrays shaped ``edge_shape(N, a) + (...)``."""
    off = edge_offsets(N)
    tail = values.shape[1:]
    return [values[off[a]:off[a + 1]].reshape(edge_shape(N, a) + tail) for a in range(3)]


@dataclass
class EdgeField:
    """A line segment field sampled on every grid edge (flat edge order, see module docstring).

    Attributes
    ----------
    N : grid resolution (points per axis).
    hit : (E,) bool, o: the edge intersects the surface (first hit from the lower endpoint).
    s : (E,) float32, s = 1 - tau of that hit (tau = t / h measured from the lower endpoint ``u``),
        so the hit point is ``s u + (1 - s) v``; 0 where there is no hit.
    normal : (E, 3) float32 unit normal at the hit (sign irrelevant), 0 where there is no hit.
    """

    N: int
    hit: np.ndarray
    s: np.ndarray
    normal: np.ndarray

    def __post_init__(self):
        E = num_edges(self.N)
        if self.hit.shape != (E,) or self.s.shape != (E,) or self.normal.shape != (E, 3):
            raise ValueError(
                f"EdgeField arrays must have shapes ({E},), ({E},), ({E}, 3) for N={self.N}; got "
                f"{self.hit.shape}, {self.s.shape}, {self.normal.shape}"
            )

    def hit_points(self) -> tuple[np.ndarray, np.ndarray]:
        """(flat ids of intersected edges, their hit points (K, 3) float64)."""
        ids = np.flatnonzero(self.hit)
        u, v = edge_endpoints(self.N, ids, dtype=np.float64)
        s = self.s[ids].astype(np.float64)[:, None]
        return ids, s * u + (1.0 - s) * v
