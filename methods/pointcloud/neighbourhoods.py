"""Nearest-neighbour searches over an input point cloud, shared by the point-cloud methods: the K
nearest input points of query points or segments, the distance to the cloud, and the grid points
and edges that lie within a radius of it (the band a method evaluates; farther is "no surface").

Coordinates are canonical ([-1, 1]^3, :mod:`foundation.grid`); KD-trees are pykdtree's (exact,
deterministic). The band is found by marking the voxels holding input points, dilating them by
``ceil(radius / h) + 1`` grid steps (scipy.ndimage) and keeping the candidates whose exact distance
is within the radius.
"""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree
from scipy import ndimage

from foundation.grid import LOWER, edge_inputs, edges_in_points, point_inputs, spacing


def knn_neighbourhoods(points: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` nearest input points of every query, nearest first.

    One exact KD-tree query (pykdtree, the project's KD-tree: multi-threaded through OpenMP,
    deterministic, the same neighbours as scipy's cKDTree). Coordinates are searched in float64, so the
    neighbours are those of the exact Euclidean distance (a tie, probability 0 for sampled points,
    goes to either point).

    Parameters
    ----------
    points : (P, 3) array_like, the input point cloud, ``P >= k``.
    queries : (Q, 3) array_like, the query points (a segment's query is its midpoint,
        :func:`segment_neighbourhoods`).
    k : neighbours per query, ``k >= 1``.

    Returns
    -------
    (Q, k) int64 ndarray: row i lists the indices into ``points`` of the k points nearest
    ``queries[i]``, by increasing distance.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    queries = np.ascontiguousarray(queries, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or queries.ndim != 2 or queries.shape[1] != 3:
        raise ValueError(f"points and queries must be (n, 3) arrays, got {points.shape} and {queries.shape}")
    k = int(k)
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    if len(points) < k:
        raise ValueError(f"a {k}-NN neighbourhood needs at least {k} input points, got {len(points)}")
    if len(queries) == 0:
        return np.zeros((0, k), dtype=np.int64)
    _, idx = KDTree(points).query(queries, k=k)
    return np.asarray(idx, dtype=np.int64).reshape(len(queries), k)  # k = 1: pykdtree returns (Q,)


def segment_neighbourhoods(points: np.ndarray, segments: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` nearest input points of each segment's midpoint m = (u + v) / 2.

    ``segments``: (S, 2, 3) or (S, 6) endpoints ``[u, v]``. Returns (S, k) int64 indices into
    ``points`` (see :func:`knn_neighbourhoods`).
    """
    segments = np.asarray(segments, dtype=np.float64)
    if segments.ndim == 2 and segments.shape[1] == 6:
        segments = segments.reshape(-1, 2, 3)
    if segments.ndim != 3 or segments.shape[1:] != (2, 3):
        raise ValueError(f"segments must be (S, 2, 3) or (S, 6), got {segments.shape}")
    return knn_neighbourhoods(points, 0.5 * (segments[:, 0] + segments[:, 1]), k)


def nearest_distance(cloud: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Distance (Q,) float64 of each query to its nearest point of ``cloud``."""
    if len(queries) == 0:
        return np.zeros(0)
    dist, _ = KDTree(np.asarray(cloud, dtype=np.float64)).query(np.asarray(queries, dtype=np.float64), k=1)
    return np.asarray(dist, dtype=np.float64).reshape(-1)


def near_cloud_mask(cloud: np.ndarray, N: int, radius: float) -> np.ndarray:
    """(N, N, N) bool: grid points within ``radius`` (canonical units) of the cloud, plus the points
    of the dilation margin that the exact test then decides (module docstring)."""
    h = spacing(N)
    ijk = np.clip(np.rint((np.asarray(cloud) - LOWER) / h).astype(np.int64), 0, N - 1)
    mask = np.zeros((N, N, N), dtype=bool)
    mask[tuple(ijk.T)] = True
    return dilate_by_ball(mask, int(np.ceil(radius / h)) + 1)


def dilate_by_ball(mask: np.ndarray, steps: int) -> np.ndarray:
    """``mask`` dilated by the ball of ``steps`` grid steps (scipy.ndimage)."""
    ball = np.linalg.norm(np.indices((2 * steps + 1,) * 3) - steps, axis=0) <= steps
    return ndimage.binary_dilation(mask, structure=ball)


def band_points(cloud: np.ndarray, N: int, radius: float) -> np.ndarray:
    """Integer indices (n, 3) of the grid points within ``radius`` of the cloud."""
    ijk = np.argwhere(near_cloud_mask(cloud, N, radius))
    return ijk[nearest_distance(cloud, point_inputs(N, ijk)) <= radius]


def band_edges(cloud: np.ndarray, N: int, radius: float) -> np.ndarray:
    """Flat ids of the grid edges whose midpoint lies within ``radius`` of the cloud."""
    ids = np.flatnonzero(edges_in_points(N, near_cloud_mask(cloud, N, radius + spacing(N))))
    ends = edge_inputs(N, ids).reshape(-1, 2, 3)
    return ids[nearest_distance(cloud, ends.mean(axis=1)) <= radius]
