"""Sharp-edge points of an oriented point set (Neural Dual Contouring's test).

A sample ``p`` is an edge point when a sample ``q`` of the same set lies within ``r`` of it
(``|p - q| <= r``) with ``|n_p . n_q| < 0.2``. :func:`sharp_edge_points` finds them exactly, fast
enough for 1M samples; a set far denser than ``r`` (a degenerate prediction much smaller than its
GT) is still decided exactly when its normals take few distinct values (the faces of a small
polyhedron), and refused (:class:`EdgeSearchTooDense`) otherwise, where the search would take
minutes and tens of GB.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["sharp_edge_points", "EdgeSearchTooDense", "MAX_EDGE_PAIRS", "MAX_NORMAL_GROUPS"]

_MAX_CELLS_PER_AXIS = 1 << 20
_PAIR_BLOCK = 100_000
_DOT_CHUNK = 4_000_000

#: Default work limit of :func:`sharp_edge_points`: an upper bound on the ordered candidate pairs
#: (cell counts times 27-neighbourhood counts, above the true count; the bound of 1M-sample CAD
#: meshes: docs/PERFORMANCE.md, section 8).
MAX_EDGE_PAIRS = 1_000_000_000
#: Most distinct normals for which a search past ``max_pairs`` is still decided, one nearest-neighbour
#: query per sample (:func:`_edge_points_by_normal_groups`): a mesh's samples carry their face's
#: normal, so a prediction of up to this many face orientations (a degenerate mesh of a few thousand
#: faces far smaller than its GT: seconds at 1M samples).
MAX_NORMAL_GROUPS = 4096
_GROUP_BLOCK = 256


class EdgeSearchTooDense(ValueError):
    """The exact edge-point search would enumerate more pairs than allowed (a degenerate input,
    e.g. a prediction far smaller than the GT so that all its samples lie within a few radii)."""


def sharp_edge_points(
    points: np.ndarray, normals: np.ndarray, radius: float, dot_threshold: float = 0.2, max_pairs: float = MAX_EDGE_PAIRS
) -> np.ndarray:
    """Boolean mask of the samples that are sharp-edge points (NDC's test).

    ``p`` is an edge point when some sample ``q`` of the same set has ``|p - q| <= radius`` and
    ``|n_p . n_q| < dot_threshold`` (``q = p`` never qualifies for unit normals). Exact: every pair
    within ``radius`` that could qualify is tested; no k-NN truncation.

    Method (chosen for speed at n = 1M: a full radius search visits every neighbour pair, of which
    only the few near edges matter):

    1. *Conservative cell filter.* Hash the points into cubic cells of side ``s >= radius``; any
       neighbour of ``p`` lies in the 27 cells around p's cell. Per cell c take a representative
       normal ``m_c`` (its first point's) and ``dev_c = max_{p in c} angle(n_p, m_c)``, angles between
       *lines* (``arccos |dot|``, a metric on directions). For two cells c0, c1 of a 27-block every
       pair of their points has ``angle <= dev_c0 + angle(m_c0, m_c1) + dev_c1``; if that bound is below
       ``arccos(dot_threshold)`` (minus 1e-6 rad for rounding) for all 27 neighbours of c0, no pair
       touching c0 can qualify: c0 is *safe*. A qualifying pair therefore joins two points of unsafe
       cells, and the search is restricted to them (the share of the samples they hold on CAD meshes:
       docs/PERFORMANCE.md, section 8).
    2. *Exact search* on the remaining candidates: scipy ``cKDTree.query_pairs(radius)`` (inclusive
       ``<=``, like sklearn's ``query_radius`` that NDC uses), in slabs of cell layers along the
       longest axis (each slab plus one layer of halo), so memory stays bounded.

    When the cell counts bound the candidate pairs above ``max_pairs`` (samples far denser than the
    radius) and the normals take at most :data:`MAX_NORMAL_GROUPS` distinct values, the same test is
    decided per group of equal normals instead (:func:`_edge_points_by_normal_groups`); with more,
    raises :class:`EdgeSearchTooDense` (one line: minutes of work and tens of GB).
    The filter assumes unit (or zero) normals; with other normals it is skipped (plain exact search).
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    n = len(points)
    flags = np.zeros(n, dtype=bool)
    if n < 2 or not dot_threshold > 0 or not radius >= 0:
        return flags
    lengths = np.linalg.norm(normals, axis=1)
    unit = bool(np.all((np.abs(lengths - 1.0) < 1e-6) | (lengths == 0)))

    lo = points.min(axis=0)
    extent = float(np.max(points.max(axis=0) - lo))
    cell = max(float(radius), extent / _MAX_CELLS_PER_AXIS)
    if not cell > 0:
        cell = 1.0
    ijk = np.floor((points - lo) / cell).astype(np.int64) + 1  # +1: neighbour keys never wrap
    dims = ijk.max(axis=0) + 2
    keys = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]

    max_angle = np.arccos(dot_threshold) - 1e-6 if unit and dot_threshold <= 1.0 else -1.0
    candidate, pair_bound = _unsafe_points(keys, normals, dims, max_angle)
    if pair_bound > max_pairs:
        group_normals, group = np.unique(normals, axis=0, return_inverse=True)
        if len(group_normals) <= MAX_NORMAL_GROUPS:
            return _edge_points_by_normal_groups(points, group_normals, group.reshape(-1), radius, dot_threshold)
        raise EdgeSearchTooDense(
            f"edge-point search too dense: up to {pair_bound:.3g} sample pairs within r = {radius:.4g} "
            f"(limit {max_pairs:.3g}); the samples span only {extent:.4g}"
        )
    cand = np.flatnonzero(candidate)
    if len(cand) < 2:
        return flags

    # slabs of cell layers along the axis with the most layers
    axis = int(np.argmax(np.ptp(ijk[cand], axis=0)))
    layer = ijk[cand, axis]
    order = np.lexsort((keys[cand], layer))  # by layer, then cell: spatially coherent trees
    cand, layer = cand[order], layer[order]
    block_first_layer = np.unique(np.concatenate([layer[:1], layer[_PAIR_BLOCK::_PAIR_BLOCK]]))
    block_last_layer = np.concatenate([block_first_layer[1:], [layer[-1] + 1]])  # inclusive halo layer
    starts = np.searchsorted(layer, block_first_layer, side="left")
    stops = np.searchsorted(layer, block_last_layer, side="right")
    for start, stop in zip(starts, stops):  # a loop over chunks, one at a time in this thread
        members = cand[start:stop]
        pairs = cKDTree(points[members]).query_pairs(float(radius), output_type="ndarray")
        for chunk in range(0, len(pairs), _DOT_CHUNK):
            i, j = members[pairs[chunk : chunk + _DOT_CHUNK]].T
            hit = np.abs(np.einsum("ij,ij->i", normals[i], normals[j])) < dot_threshold
            flags[i[hit]] = True
            flags[j[hit]] = True
    return flags


def _edge_points_by_normal_groups(points: np.ndarray, group_normals: np.ndarray, group: np.ndarray, radius: float,
                                  dot_threshold: float) -> np.ndarray:
    """:func:`sharp_edge_points` for samples whose normals take few distinct values, at any density.

    ``group_normals[group[i]]`` is the normal of sample ``i``. A sample of group ``a`` is an edge point
    exactly when its nearest other sample among the groups ``b`` with ``|n_a . n_b| < dot_threshold``
    whose bounding boxes come within ``radius`` of a's lies within ``radius`` (inclusive): per group
    one KD-tree over those groups' samples and one nearest-neighbour query per sample (its own index
    excluded, which only matters for a group perpendicular to itself, i.e. zero normals), whatever
    the number of pairs within ``radius``.
    """
    flags = np.zeros(len(points), dtype=bool)
    k = len(group_normals)
    order = np.argsort(group, kind="stable")
    members = np.split(order, np.cumsum(np.bincount(group, minlength=k))[:-1])
    lo = np.minimum.reduceat(points[order], np.r_[0, np.cumsum([len(m) for m in members[:-1]])], axis=0)
    hi = np.maximum.reduceat(points[order], np.r_[0, np.cumsum([len(m) for m in members[:-1]])], axis=0)
    reach = np.nextafter(float(radius), np.inf)
    for start in range(0, k, _GROUP_BLOCK):  # rows of the group-pair matrices, a block at a time
        rows = slice(start, min(start + _GROUP_BLOCK, k))
        perpendicular = np.abs(group_normals[rows] @ group_normals.T) < dot_threshold
        gap = np.maximum(0.0, np.maximum(lo[rows, None, :] - hi[None], lo[None] - hi[rows, None, :]))
        candidates = perpendicular & (np.linalg.norm(gap, axis=2) <= reach)
        for row in np.flatnonzero(candidates.any(axis=1)):  # a loop over groups, at most MAX_NORMAL_GROUPS
            a = start + row
            others = np.concatenate([members[b] for b in np.flatnonzero(candidates[row])])
            distance, nearest = cKDTree(points[others]).query(points[members[a]], k=2, distance_upper_bound=reach)
            itself = others[np.minimum(nearest[:, 0], len(others) - 1)] == members[a]
            closest = np.where(itself, distance[:, 1], distance[:, 0])
            flags[members[a][closest <= radius]] = True
    return flags


def _unsafe_points(keys: np.ndarray, normals: np.ndarray, dims: np.ndarray, max_angle: float) -> tuple[np.ndarray, float]:
    """Step 1 of :func:`sharp_edge_points`: the points whose cell is not provably edge-free, and an
    upper bound on the ordered pairs among them within the radius (sum over unsafe cells c of
    ``count(c) * count(unsafe cells among the 27 around c)``). ``max_angle < 0``: no cell is safe."""
    cell_keys, first, inverse, counts = np.unique(keys, return_index=True, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    offsets = [(dx * dims[1] + dy) * dims[2] + dz for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]

    def neighbours(offset):
        other = cell_keys + offset
        pos = np.minimum(np.searchsorted(cell_keys, other), len(cell_keys) - 1)
        hit = np.flatnonzero(cell_keys[pos] == other)
        return hit, pos[hit]

    if max_angle < 0:
        unsafe = np.ones(len(cell_keys), dtype=bool)
    else:
        rep = normals[first]
        cos_to_rep = np.abs(np.einsum("ij,ij->i", normals, rep[inverse]))
        min_cos = np.ones(len(cell_keys))
        np.minimum.at(min_cos, inverse, cos_to_rep)
        dev = np.arccos(np.clip(min_cos, 0.0, 1.0))
        bound = 2.0 * dev  # a cell with itself: dev + 0 + dev
        for offset in offsets:
            if offset == 0:
                continue
            c0, c1 = neighbours(offset)
            cos = np.abs(np.einsum("ij,ij->i", rep[c0], rep[c1]))
            bound[c0] = np.maximum(bound[c0], dev[c0] + np.arccos(np.clip(cos, 0.0, 1.0)) + dev[c1])
        unsafe = ~(bound < max_angle)
    unsafe_counts = np.where(unsafe, counts, 0).astype(np.float64)
    around = np.zeros(len(cell_keys))
    for offset in offsets:
        c0, c1 = neighbours(offset)
        around[c0] += unsafe_counts[c1]
    return unsafe[inverse], float(np.dot(unsafe_counts, around))
