"""GeoUDF's edge-based marching cubes (E-MC): a mesh from an unsigned distance field and its
gradient on the grid, written after the authors' ``eval_rec.py`` (``custom_marching_cube``,
``edge_detector``, ``glb_optimize_cube``, ``edge_interp_point``), not copied from it.

Input: the UDF u (N, N, N) and its unit gradient g (N, N, N, 3) on the grid of
:mod:`foundation.grid` (point ``[i, j, k]`` at ``-1 + (i, j, k) h``, canonical units). Per cell:

1. Cull: a cell is processed only if the UDF at its lowest corner is at most ``cull h`` (2 h).
2. Crossing test of every pair of its 8 corners (the 28 pairs: 12 edges, 12 face diagonals, 4 body
   diagonals; :func:`crossing_pairs`): the surface separates corners p1 and p2 when one of them
   lies on it (u < ``snap``), or when both lie within ``near h`` of it (1.1 h), their gradients
   point away from each other (g1 . g2 < 0) and each points away from the pair's midpoint c
   ((p1 - c) . g1 > 0 and (p2 - c) . g2 > 0): the two corners sit on opposite sides.
3. Labels (:func:`cube_labels`): of the 128 in/out labellings of the 8 corners with corner 7
   (offset (0, 1, 1)) out, the one whose "labels differ" pattern disagrees with the
   fewest of the 28 crossing flags (the first such labelling in binary order, bit c = corner c).
4. Triangles: the marching-cubes case of those labels (:func:`triangle_table`, the classic
   Lorensen table of scikit-image), a vertex on each cut cell edge at
   ``(p1 u2 + p2 u1) / (u1 + u2)`` (:func:`edge_points`; a corner with u <= ``snap`` is taken as the
   vertex itself, the midpoint when both are).
5. Cleaning: vertices at the same position merged, then (trimesh, as the authors) duplicate and
   degenerate faces removed and the triangle and quad holes filled.

The cells' labels are chosen independently, so neighbouring cells may disagree at a shared corner:
the mesh is unoriented and may have gaps, as the authors'. Corner order (``CORNERS``): (0,0,0),
(1,0,0), (1,0,1), (0,0,1), (0,1,0), (1,1,0), (1,1,1), (0,1,1) in (i, j, k) offsets, the authors'.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np
import trimesh
from skimage.measure import marching_cubes as _skimage_marching_cubes

from foundation.grid import LOWER, ijk_axis_to_edge_index, spacing
from methods.base import Extraction
from methods.extractors.marching_cubes import empty_mesh

__all__ = ["CORNERS", "CELL_EDGES", "CORNER_PAIRS", "triangle_table", "crossing_pairs", "cube_labels",
           "edge_points", "edge_marching_cubes"]

#: Grid-index offsets of a cell's 8 corners (the authors' order).
CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1], [0, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1]],
                   dtype=np.int64)
#: The 12 cell edges as corner pairs, lower corner first (the authors' order).
CELL_EDGES = np.array([[0, 1], [1, 2], [3, 2], [0, 3], [4, 5], [5, 6], [7, 6], [4, 7], [0, 4], [1, 5], [2, 6],
                       [3, 7]], dtype=np.int64)
#: All 28 corner pairs (i < j), in lexicographic order.
CORNER_PAIRS = np.array(list(itertools.combinations(range(8), 2)), dtype=np.int64)
#: The 128 candidate labellings (128, 8): row x holds the bits of x (bit c = corner c; corner 7 out).
LABELLINGS = ((np.arange(128)[:, None] >> np.arange(8)[None, :]) & 1).astype(bool)


@functools.lru_cache(maxsize=1)
def triangle_table() -> np.ndarray:
    """(256, 5, 3) int64: for each marching-cubes case (bit c set = corner c labelled in), up to 5
    triangles as triples of :data:`CELL_EDGES` indices, -1 padded.

    Built once from scikit-image's Lorensen marching cubes on the single cell with value -1 at the
    corners of the case and +1 elsewhere (level 0): each vertex it returns is the midpoint of a cell
    edge, which names the edge."""
    midpoints = {tuple(CORNERS[a] + CORNERS[b]): e for e, (a, b) in enumerate(CELL_EDGES)}
    table = np.full((256, 5, 3), -1, dtype=np.int64)
    for case in range(1, 255):
        volume = np.ones((2, 2, 2), dtype=np.float32)
        bits = (case >> np.arange(8)) & 1
        volume[tuple(CORNERS[bits == 1].T)] = -1.0
        verts, faces, _, _ = _skimage_marching_cubes(volume, level=0.0, method="lorensen")
        edges = np.array([midpoints[tuple(np.rint(2 * v).astype(np.int64))] for v in verts])
        table[case, :len(faces)] = edges[faces]
    return table


def crossing_pairs(udf: np.ndarray, grad: np.ndarray, corners: np.ndarray, h: float, snap: float,
                   near: float = 1.1) -> np.ndarray:
    """Whether the surface passes between each of the 28 corner pairs of each cell (step 2).

    Parameters
    ----------
    udf : (C, 8) UDF at the cells' corners (canonical units).
    grad : (C, 8, 3) unit UDF gradients there.
    corners : (C, 8, 3) corner positions.
    h : grid spacing; ``near h`` bounds both corners' UDF in the gradient test.
    snap : a corner with UDF below it lies on the surface.

    Returns
    -------
    (C, 28) bool, pairs in :data:`CORNER_PAIRS` order.
    """
    a, b = CORNER_PAIRS[:, 0], CORNER_PAIRS[:, 1]
    u1, u2 = udf[:, a], udf[:, b]
    g1, g2 = grad[:, a], grad[:, b]
    half = 0.5 * (corners[:, a] - corners[:, b])  # p1 - c; p2 - c = -half
    opposite = ((g1 * g2).sum(-1) < 0) & (u1 < near * h) & (u2 < near * h)
    outward = ((half * g1).sum(-1) > 0) & ((-half * g2).sum(-1) > 0)
    return (u1 < snap) | (u2 < snap) | (opposite & outward)


def cube_labels(crossing: np.ndarray) -> np.ndarray:
    """(C, 8) bool labels of the cells' corners (step 3): per cell the first of :data:`LABELLINGS`
    minimising the number of pairs whose crossing flag differs from "their labels differ".
    ``crossing``: (C, 28) bool from :func:`crossing_pairs`."""
    differ = (LABELLINGS[:, CORNER_PAIRS[:, 0]] != LABELLINGS[:, CORNER_PAIRS[:, 1]]).astype(np.float32)  # (128, 28)
    flags = np.asarray(crossing, dtype=np.float32)
    mismatches = flags @ (1.0 - differ).T + (1.0 - flags) @ differ.T  # (C, 128)
    return LABELLINGS[np.argmin(mismatches, axis=1)]


def edge_points(p1: np.ndarray, u1: np.ndarray, p2: np.ndarray, u2: np.ndarray, snap: float) -> np.ndarray:
    """Vertex on each edge (p1, p2) (E, 3) with UDF values u1, u2 (E,) (step 4): the UDF-weighted
    point ``(p1 u2 + p2 u1) / (u1 + u2)``; p1 where only u1 <= snap, p2 where only u2 <= snap, the
    midpoint where both are."""
    on1, on2 = u1 <= snap, u2 <= snap
    total = np.where(on1 | on2, 1.0, u1 + u2)
    x = (p1 * u2[:, None] + p2 * u1[:, None]) / total[:, None]
    x = np.where((on1 & ~on2)[:, None], p1, x)
    x = np.where((on2 & ~on1)[:, None], p2, x)
    return np.where((on1 & on2)[:, None], 0.5 * (p1 + p2), x)


def _clean(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Step 5: merge equal vertices, drop duplicate and degenerate faces, fill triangle and quad
    holes (trimesh)."""
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    mesh.update_faces(mesh.unique_faces())
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    trimesh.repair.fill_holes(mesh)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def edge_marching_cubes(udf: np.ndarray, grad: np.ndarray, snap: float, cull: float = 2.0,
                        near: float = 1.1) -> Extraction:
    """GeoUDF's E-MC (module docstring) on the grid of :mod:`foundation.grid`.

    Parameters
    ----------
    udf : (N, N, N) finite UDF values (canonical units); points far from the surface only need a
        value above ``cull h``.
    grad : (N, N, N, 3) unit gradients (zero where unknown).
    snap : a UDF below it is "on the surface" (canonical units; the authors' 0.0005 in their frame).
    cull, near : the cell cull (``cull h``) and the pair test bound (``near h``), in grid spacings.

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (V, 3) float64 canonical frame, faces (F, 3) int64
    (unoriented), info ``emc_cells`` (cells tested), ``emc_cut_cells`` (cells with triangles).
    """
    udf = np.asarray(udf, dtype=np.float64)
    grad = np.asarray(grad, dtype=np.float64)
    if udf.ndim != 3 or len(set(udf.shape)) != 1 or udf.shape[0] < 2:
        raise ValueError(f"udf must have shape (N, N, N) with N >= 2, got {udf.shape}")
    if grad.shape != udf.shape + (3,):
        raise ValueError(f"grad must have shape {udf.shape + (3,)}, got {grad.shape}")
    if not np.all(np.isfinite(udf)):
        raise ValueError("udf has non-finite values; give far points any value above cull h")
    N = udf.shape[0]
    h = spacing(N)
    cells = np.argwhere(udf[:-1, :-1, :-1] <= cull * h)  # (C, 3) lowest corners
    ijk = cells[:, None, :] + CORNERS[None]  # (C, 8, 3)
    at = tuple(np.moveaxis(ijk, -1, 0))
    labels = cube_labels(crossing_pairs(udf[at], grad[at], LOWER + ijk * h, h, snap, near))
    case = (labels.astype(np.int64) << np.arange(8)).sum(axis=1)
    triangles = triangle_table()[case]  # (C, 5, 3)
    cut = triangles[:, 0, 0] >= 0
    info = {"emc_cells": int(len(cells)), "emc_cut_cells": int(cut.sum())}
    cells, triangles = cells[cut], triangles[cut]
    cell_of, slot = np.nonzero(triangles[:, :, 0] >= 0)
    if len(cell_of) == 0:
        return Extraction(*empty_mesh(), info)
    local = triangles[cell_of, slot]  # (T, 3) cell edge indices
    start = CORNERS[CELL_EDGES[:, 0]]  # (12, 3) lower corner offset of each cell edge
    axis = np.argmax(CORNERS[CELL_EDGES[:, 1]] - start, axis=1)  # (12,)
    edge_ids = ijk_axis_to_edge_index(N, (cells[cell_of][:, None, :] + start[local]).reshape(-1, 3),
                                      axis[local].reshape(-1))
    unique_edges, corner_of = np.unique(edge_ids, return_inverse=True)
    e_start = (cells[cell_of][:, None, :] + start[local]).reshape(-1, 3)
    first = np.zeros(len(unique_edges), dtype=np.int64)
    first[corner_of] = np.arange(len(edge_ids))  # any occurrence gives the same edge
    lo = e_start[first]
    hi = lo + np.eye(3, dtype=np.int64)[axis[local].reshape(-1)[first]]
    points = edge_points(LOWER + lo * h, udf[tuple(lo.T)], LOWER + hi * h, udf[tuple(hi.T)], snap)
    return Extraction(*_clean(points, corner_of.reshape(-1, 3)), info)
