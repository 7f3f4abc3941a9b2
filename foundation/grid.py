"""The regular grid every method is extracted on.

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
  first: ``u`` = start point, ``v = u + h e_a``. Written out, with ``(n0, n1, n2) = edge_shape(N, a)``
  and :func:`edge_offsets` ``off = (0, E_0, E_0 + E_1, E)``::

      edge id = off[a] + (i n1 + j) n2 + k

  This module is the one owner of that numbering: :func:`ijk_axis_to_edge_index` encodes,
  :func:`edge_index_to_ijk_axis` decodes, :func:`edge_endpoint_values` lays per-point values out
  per edge; every other module calls them.
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


def edge_index_to_ijk_axis(N: int, edge_ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Decode flat edge ids (module docstring) into lower-endpoint grid indices and axes.

    Parameters
    ----------
    N : grid resolution (points per axis).
    edge_ids : (K,) integer flat edge ids in ``[0, num_edges(N))``; default: every edge, in order.

    Returns
    -------
    ijk : (K, 3) int64 grid index of each edge's lower endpoint ``u``.
    axis : (K,) int64 axis (0, 1, 2) the edge runs along.
    """
    off = edge_offsets(N)
    if edge_ids is None:
        edge_ids = np.arange(off[-1], dtype=np.int64)
    edge_ids = np.asarray(edge_ids, dtype=np.int64)
    if edge_ids.size and (edge_ids.min() < 0 or edge_ids.max() >= off[-1]):
        raise ValueError(f"edge ids must lie in [0, {off[-1]}) for N={N}, "
                         f"got [{edge_ids.min()}, {edge_ids.max()}]")
    axis = np.searchsorted(off, edge_ids, side="right") - 1
    local = edge_ids - off[axis]
    # the edge array along `axis` has shape (n0, n1, n2): N - 1 along `axis`, N elsewhere
    n1 = N - (axis == 1)
    n2 = N - (axis == 2)
    ijk = np.empty((len(edge_ids), 3), dtype=np.int64)
    ijk[:, 2] = local % n2
    rest = local // n2
    ijk[:, 1] = rest % n1
    ijk[:, 0] = rest // n1
    return ijk, axis


def ijk_axis_to_edge_index(N: int, ijk: np.ndarray, axis: np.ndarray | int) -> np.ndarray:
    """Flat edge ids (module docstring) of the edges starting at grid index ``ijk`` along ``axis``.

    Parameters
    ----------
    N : grid resolution (points per axis).
    ijk : (K, 3) integer grid index of each edge's lower endpoint; the index along ``axis`` must be
        ``<= N - 2`` and the others ``<= N - 1`` (not checked: callers build valid edges).
    axis : (K,) integer axes, or one axis for all edges.

    Returns
    -------
    (K,) int64 flat edge ids.
    """
    ijk = np.asarray(ijk, dtype=np.int64)
    axis = np.asarray(axis, dtype=np.int64)
    n1 = N - (axis == 1)
    n2 = N - (axis == 2)
    return edge_offsets(N)[axis] + (ijk[:, 0] * n1 + ijk[:, 1]) * n2 + ijk[:, 2]


def edge_endpoint_values(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A per-point grid array read at both endpoints of every edge, in flat edge order.

    Parameters
    ----------
    values : (N, N, N, ...) array on the grid points ('ij' order).

    Returns
    -------
    lower, upper : (E, ...) arrays, E = num_edges(N): ``values`` at ``u`` and at ``v = u + h e_axis``
        (contiguous slices per axis, no index arithmetic).
    """
    values = np.asarray(values)
    N = values.shape[0]
    if values.ndim < 3 or values.shape[1:3] != (N, N):
        raise ValueError(f"values must have shape (N, N, N, ...), got {values.shape}")
    tail = values.shape[3:]
    lower, upper = [], []
    for a in range(3):  # the three axis blocks of the flat order
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[a], hi[a] = slice(0, N - 1), slice(1, N)
        lower.append(values[tuple(lo)].reshape((-1,) + tail))
        upper.append(values[tuple(hi)].reshape((-1,) + tail))
    return np.concatenate(lower), np.concatenate(upper)


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


def point_inputs(N: int, ijk: np.ndarray) -> np.ndarray:
    """Canonical coordinates (P, 3) float32 of integer grid indices ``ijk`` (P, 3)."""
    return (LOWER + np.asarray(ijk, dtype=np.float64) * spacing(N)).astype(np.float32)


def edge_inputs(N: int, edge_ids: np.ndarray | None = None) -> np.ndarray:
    """Segment inputs ``[u, v]`` (E, 6) float32 of grid edges (flat ids; default all)."""
    u, v = edge_endpoints(N, edge_ids, dtype=np.float32)
    return np.concatenate([u, v], axis=1)


def edges_in_points(N: int, mask: np.ndarray) -> np.ndarray:
    """(E,) bool in flat edge order: both endpoints of the edge are in the point mask (N, N, N)."""
    lower, upper = edge_endpoint_values(mask)
    return lower & upper
