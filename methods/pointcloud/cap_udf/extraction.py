"""CAP-UDF's surface extraction from an unsigned distance field and its gradient field
(Zhou et al. 2022, ``tools/surface_extraction.py`` and ``tools/utils.py: remove_far`` of their code).

Input: the UDF ``d`` and its gradient ``g`` (any length) on the grid of :mod:`foundation.grid`
(``(N, N, N)`` and ``(N, N, N, 3)``, ``'ij'`` indexing, spacing ``h = 2 / (N - 1)``). Output: an
unoriented triangle mesh in the canonical frame.

1. Candidate cells: the cells whose smallest corner distance is ``<= threshold`` (the authors skip
   every other cell "to accelerate extraction").
2. Signs from the gradient field: in each candidate cell the corner at its lowest index (corner 0,
   offset (0, 0, 0)) is the anchor; a corner whose gradient points against the anchor's
   (``g_i . g_0 < 0``) gets the value ``-d_i``, every other corner ``+d_i``.
3. Each cell with a negative corner is triangulated by marching cubes at level 0 of those values
   (the classic Lorensen case table, :func:`methods.extractors.meshudf.mc_case_table`); a crossing on the cube
   edge between corners a and b sits at ``t = f_a / (f_a - f_b)`` (linear interpolation), all cells
   at once in numpy.
4. Optionally (``far > 0``, the authors' ``train.far`` of their ShapeNet-cars and 3D-scene
   configurations) :func:`remove_far_faces` drops the faces whose mean vertex distance to the input
   cloud is ``>= far``.

Vertices on the same grid edge are merged (the crossing depends only on the edge's two corner values
and signs, so two cells that both cut the edge give the same point); the authors keep a triangle soup
with each cell's vertices apart (``trimesh.Trimesh(..., process=False)``): the same surface.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from foundation.grid import LOWER, ijk_axis_to_edge_index, spacing
from methods.base import Extraction
from methods.extractors.mesh_ops import drop_unreferenced_vertices
from methods.extractors.meshudf import CUBE_CORNERS, CUBE_EDGES, mc_case_table

__all__ = ["candidate_cells", "gradient_signs", "gradient_sign_marching_cubes", "remove_far_faces"]

_EDGE_AXIS = np.repeat(np.arange(3), 4)  # cube edge e runs along axis e // 4 (methods.extractors.meshudf)


def candidate_cells(udf: np.ndarray, threshold: float) -> np.ndarray:
    """Grid indices (C, 3) int64 of the cells whose smallest corner distance is ``<= threshold``
    (NaN corners count as far)."""
    M = udf.shape[0] - 1
    near = np.nan_to_num(udf, nan=np.inf) <= threshold
    ok = np.zeros((M, M, M), dtype=bool)
    for dx, dy, dz in CUBE_CORNERS:  # 8 shifted views
        ok |= near[dx:dx + M, dy:dy + M, dz:dz + M]
    return np.argwhere(ok)


def gradient_signs(G: np.ndarray) -> np.ndarray:
    """Signs (C, 8) in {-1, +1} of the corners of each cell from their gradients ``G`` (C, 8, 3):
    -1 where ``g_i . g_0 < 0`` (corner 0 the anchor, always +1)."""
    dots = np.einsum("cij,cj->ci", G, G[:, 0])
    return np.where(dots < 0, -1.0, 1.0)


def gradient_sign_marching_cubes(udf: np.ndarray, grad: np.ndarray, threshold: float) -> Extraction:
    """CAP-UDF's mesh of the zero set of a grid UDF (module docstring, steps 1-3).

    Parameters
    ----------
    udf : (N, N, N) unsigned distances >= 0 on the grid, canonical units (NaN: unknown, far).
    grad : (N, N, N, 3) gradients of the UDF on the grid (any length; NaN read as 0).
    threshold : cells whose smallest corner distance exceeds it are skipped (canonical units).

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (n, 3) float64, canonical frame; faces (m, 3) int64,
    unoriented.
    """
    udf, grad = np.asarray(udf), np.asarray(grad)
    if udf.ndim != 3 or len(set(udf.shape)) != 1 or udf.shape[0] < 2:
        raise ValueError(f"udf must have shape (N, N, N) with N >= 2, got {udf.shape}")
    N = udf.shape[0]
    if grad.shape != (N, N, N, 3):
        raise ValueError(f"grad must have shape ({N}, {N}, {N}, 3), got {grad.shape}")
    h = spacing(N)
    ijk = candidate_cells(udf, threshold)
    corner_ijk = ijk[:, None, :] + CUBE_CORNERS[None]  # (C, 8, 3)
    corners = tuple(np.moveaxis(corner_ijk, 2, 0))
    D = np.nan_to_num(udf[corners].astype(np.float64), nan=np.inf)  # (C, 8)
    G = np.nan_to_num(grad[corners].astype(np.float64))  # (C, 8, 3)
    Fv = gradient_signs(G) * D if len(D) else np.zeros((0, 8))
    negative = Fv < 0
    case = np.packbits(negative, axis=1, bitorder="little")[:, 0].astype(np.int64)
    table, counts = mc_case_table()
    active = np.flatnonzero(counts[case])
    if len(active) == 0:
        return Extraction(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    ijk, Fv, negative, case = ijk[active], Fv[active], negative[active], case[active]
    ntri = counts[case]
    # crossings: cube edges whose corners have opposite signs
    cc, ee = np.nonzero(negative[:, CUBE_EDGES[:, 0]] != negative[:, CUBE_EDGES[:, 1]])
    c0, c1 = CUBE_EDGES[ee, 0], CUBE_EDGES[ee, 1]
    f0, f1 = Fv[cc, c0], Fv[cc, c1]
    t = f0 / (f0 - f1)
    axis = _EDGE_AXIS[ee]
    start = ijk[cc] + CUBE_CORNERS[c0]  # grid index of the edge's lower endpoint
    # one vertex per grid edge: t = d_a / (d_a + d_b) whichever corner is negative
    key = ijk_axis_to_edge_index(N, start, axis)
    uniq, vid = np.unique(key, return_inverse=True)
    vid = vid.reshape(-1)
    position = start.astype(np.float64)
    position[np.arange(len(t)), axis] += t
    vertices = np.empty((len(uniq), 3))
    vertices[vid] = LOWER + position * h
    vid_of = np.full((len(ijk), 12), -1, dtype=np.int64)
    vid_of[cc, ee] = vid
    cell = np.repeat(np.arange(len(ijk)), ntri)
    slot = np.arange(len(cell)) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    return Extraction(vertices, vid_of[cell[:, None], table[case[cell], slot]])


def remove_far_faces(vertices: np.ndarray, faces: np.ndarray, cloud: np.ndarray,
                     far: float) -> tuple[np.ndarray, np.ndarray]:
    """The mesh without the faces whose mean vertex distance to ``cloud`` (P, 3) is ``>= far``
    (same units as the vertices), unreferenced vertices dropped."""
    if len(faces) == 0:
        return vertices, faces
    dist, _ = cKDTree(np.asarray(cloud, dtype=np.float64)).query(vertices, distance_upper_bound=far)
    return drop_unreferenced_vertices(vertices, faces[dist[faces].mean(axis=1) < far])
