"""GIFS surface extraction: per-cube pair flags + UDF -> a triangle mesh (Ye et al., CVPR 2022;
after the authors' ``models/generation.py``: ``combs_to_verts_glb_opt``, ``contrastive_marching_cubes``).

Arrays in, arrays out; no network. A *cube* is a cell of the grid of :mod:`foundation.grid`, named
by its lower grid point ``(i, j, k)``, ``0 <= i, j, k <= N - 2``. Its 8 corners are numbered
``c = 4 di + 2 dj + dk`` (:data:`CORNERS`), its 28 corner pairs (the 12 edges, the 12 face
diagonals and the 4 body diagonals) ``p = 0..27`` in :data:`CORNER_PAIRS` order (lexicographic
``(a, b)``, ``a < b``). A pair's *flag* f is ~1 where the surface separates its two corners, ~0
where it does not (any non-negative value is accepted, as the network's ReLU output).

Algorithm, per cube, all cubes at once:

1. Signs (:func:`corner_signs`): if no flag exceeds ``flag_threshold`` (0.5) the cube holds no
   surface. Otherwise every partition of the corners into two sides is scored,
   ``cost = sum over same-side pairs of f + sum over opposite-side pairs of (1 - f)``, and the
   cheapest is kept: all 2^7 = 128 partitions (corner 0 on side -1, which fixes the global flip
   that does not change the surface), exhaustively, ties to the lowest partition index (bits of
   corners 1..7), which makes "all one side" (no surface) win any tie it is part of.
2. Values: corner value = side x UDF of the corner (a signed distance local to the cube; the
   magnitude floored at :data:`UDF_FLOOR` so that a zero UDF keeps its side).
3. Marching cubes at level 0 in every cube on its own (:func:`local_marching_cubes`): a vertex on
   every edge whose corners lie on opposite sides, at the zero of the linear interpolant of the
   two values, i.e. at fraction ``d_a / (d_a + d_b)`` from corner a (scikit-image's Lewiner
   tables on the cubes laid out as separate blocks of one volume). Cubes never share signs, only
   vertices: the vertices of neighbouring cubes on one grid edge (the same two values, hence the
   same position) are welded into one, as the authors merge equal coordinates; faces that welding
   made degenerate are dropped. Neighbouring cubes may choose opposite global flips, so the faces'
   orientation is not consistent (the authors' meshes are not either).
"""

from __future__ import annotations

import itertools

import numpy as np

from foundation.grid import LOWER, ijk_axis_to_edge_index, spacing
from methods.base import Extraction
from methods.extractors.mesh_ops import drop_unreferenced_vertices
from methods.extractors.marching_cubes import empty_mesh, skimage_marching_cubes

__all__ = ["CORNERS", "CORNER_PAIRS", "CUBE_EDGES", "CUBE_EDGE_AXES", "PARTITIONS", "UDF_FLOOR", "corner_signs",
           "local_marching_cubes", "flag_split_marching_cubes"]

#: (8, 3) int offsets (di, dj, dk) of a cube's corners, corner c = 4 di + 2 dj + dk.
CORNERS = np.array(list(itertools.product((0, 1), repeat=3)), dtype=np.int64)
#: (28, 2) corner indices (a, b), a < b, lexicographic: every pair of corners of a cube.
CORNER_PAIRS = np.array(list(itertools.combinations(range(8), 2)), dtype=np.int64)
#: (128, 8) int8: partition q puts corner c on side +1 where bit c - 1 of q is set, else -1
#: (corner 0 always -1); q = 0 is "all corners on one side".
PARTITIONS = np.where((np.arange(128)[:, None] >> np.arange(7)[None, :]) & 1, 1, -1).astype(np.int8)
PARTITIONS = np.concatenate([-np.ones((128, 1), dtype=np.int8), PARTITIONS], axis=1)
#: (12, 2) the cube's edges as corner pairs (a, b), b = a + one axis step; their axes (12,).
CUBE_EDGES = CORNER_PAIRS[(np.abs(CORNERS[CORNER_PAIRS[:, 0]] - CORNERS[CORNER_PAIRS[:, 1]]).sum(axis=1) == 1)]
CUBE_EDGE_AXES = np.argmax(CORNERS[CUBE_EDGES[:, 1]] - CORNERS[CUBE_EDGES[:, 0]], axis=1)
#: Smallest corner magnitude (canonical units) in the signed values, so a zero UDF keeps its side.
UDF_FLOOR = 1e-7
#: Cubes per chunk of the partition search (a (chunk, 128) float32 matrix).
_CHUNK = 65_536


def corner_signs(flags: np.ndarray, flag_threshold: float = 0.5) -> np.ndarray:
    """(C, 8) int8 sides (+1 / -1) of every cube's corners from its 28 pair flags (module docstring,
    step 1); all -1 where no flag exceeds ``flag_threshold``.

    ``flags``: (C, 28) non-negative, :data:`CORNER_PAIRS` order."""
    flags = np.asarray(flags, dtype=np.float32)
    if flags.ndim != 2 or flags.shape[1] != len(CORNER_PAIRS):
        raise ValueError(f"flags must be (C, {len(CORNER_PAIRS)}), got shape {flags.shape}")
    # opposite[q, p] = 1 where partition q puts the two corners of pair p on opposite sides
    opposite = (PARTITIONS[:, CORNER_PAIRS[:, 0]] != PARTITIONS[:, CORNER_PAIRS[:, 1]]).astype(np.float32)
    best = np.zeros(len(flags), dtype=np.int64)
    for start in range(0, len(flags), _CHUNK):
        f = flags[start:start + _CHUNK]
        # cost = sum_p f_p + sum_p opposite_p (1 - 2 f_p); the first term is the same for every q
        best[start:start + _CHUNK] = np.argmin((1.0 - 2.0 * f) @ opposite.T, axis=1)
    best[flags.max(axis=1, initial=0.0) <= flag_threshold] = 0
    return PARTITIONS[best]


def local_marching_cubes(cubes: np.ndarray, corner_values: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes at level 0 in each cube on its own, vertices welded (module docstring, step 3).

    scikit-image meshes the cubes laid out as separate 2 x 2 x 2 blocks of one volume (a mask keeps
    the cells between blocks out); each of its vertices is then put back on its cube's edge: the
    nearest of the cube's edges whose corners change sign, at the fraction ``v_a / (v_a - v_b)``
    from its lower corner a, recomputed in float64 from the values (scikit-image's float32
    positions differ in the last bits between cubes), and the vertices on one grid edge (numbered
    by :func:`foundation.grid.ijk_axis_to_edge_index`) are welded into one.

    Parameters
    ----------
    cubes : (C, 3) int lower grid points of the cubes, in [0, N - 2].
    corner_values : (C, 8) float signed corner values, :data:`CORNERS` order (no zeros: a zero
        counts as positive).
    N : grid points per axis of :mod:`foundation.grid`.

    Returns
    -------
    vertices (V, 3) float64 canonical frame, faces (F, 3) int64 (orientation per cube).
    """
    cubes = np.asarray(cubes, dtype=np.int64).reshape(-1, 3)
    values = np.asarray(corner_values, dtype=np.float64).reshape(-1, 8)
    if len(cubes) != len(values):
        raise ValueError(f"{len(cubes)} cubes but {len(values)} rows of corner values")
    if len(cubes) and (cubes.min() < 0 or cubes.max() > N - 2):
        raise ValueError(f"cube indices must lie in [0, {N - 2}] for a grid of {N} points")
    positive = values >= 0
    crossing = positive.any(axis=1) & ~positive.all(axis=1)
    cubes, values, positive = cubes[crossing], values[crossing], positive[crossing]
    if len(cubes) == 0:
        return empty_mesh()
    C = len(cubes)
    side = int(np.ceil(C ** (1.0 / 3.0)))
    while side ** 3 < C:
        side += 1
    block = np.stack(np.unravel_index(np.arange(C), (side,) * 3), axis=1)  # (C, 3)
    volume = np.ones((2 * side,) * 3, dtype=np.float64)
    at = 2 * block[:, None, :] + CORNERS[None, :, :]  # (C, 8, 3)
    volume[at[..., 0], at[..., 1], at[..., 2]] = values
    # scikit-image meshes the cell whose upper corner holds a True mask value
    mask = np.zeros(volume.shape, dtype=bool)
    mask[2 * block[:, 0] + 1, 2 * block[:, 1] + 1, 2 * block[:, 2] + 1] = True
    found = skimage_marching_cubes(volume, level=0.0, mask=mask, allow_degenerate=False)
    if found is None:  # no triangle at all
        return empty_mesh()
    position, faces, _, _ = found
    position = position.astype(np.float64)
    owner_block = np.clip(np.floor(position / 2.0).astype(np.int64), 0, side - 1)
    owner = np.ravel_multi_index(owner_block.T, (side,) * 3)
    local = position - 2.0 * owner_block
    # the vertex's edge: the nearest sign-changing edge of its cube
    a, b = CUBE_EDGES[:, 0], CUBE_EDGES[:, 1]
    across = np.ones((12, 3), dtype=bool)
    across[np.arange(12), CUBE_EDGE_AXES] = False
    offset = local[:, None, :] - CORNERS[a][None, :, :]  # (V, 12, 3)
    distance = np.where(across[None], offset ** 2, 0.0).sum(axis=2)
    distance[positive[owner][:, a] == positive[owner][:, b]] = np.inf
    edge = np.argmin(distance, axis=1)
    va, vb = values[owner, a[edge]], values[owner, b[edge]]
    fraction = va / (va - vb)
    lower = cubes[owner] + CORNERS[a[edge]]
    index = lower.astype(np.float64)
    index[np.arange(len(index)), CUBE_EDGE_AXES[edge]] += fraction
    key = ijk_axis_to_edge_index(N, lower, CUBE_EDGE_AXES[edge])
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    return drop_unreferenced_vertices(LOWER + index[first] * spacing(N), faces.astype(np.int64))


def flag_split_marching_cubes(cubes: np.ndarray, flags: np.ndarray, corner_udf: np.ndarray, N: int,
                              flag_threshold: float = 0.5) -> Extraction:
    """The GIFS mesh of the given cubes (module docstring).

    Parameters
    ----------
    cubes : (C, 3) int lower grid points of the cubes, in [0, N - 2].
    flags : (C, 28) pair flags (:data:`CORNER_PAIRS` order), ~1 where the surface separates the pair.
    corner_udf : (C, 8) unsigned distances (canonical units) of the corners (:data:`CORNERS` order).
    N : grid points per axis (:mod:`foundation.grid`).
    flag_threshold : a cube holds surface only where some flag exceeds it (the authors' 0.5).

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (V, 3) float64 canonical frame, faces (F, 3) int64,
    info {"surface_cubes": cubes with corners on both sides}.
    """
    flags = np.asarray(flags, dtype=np.float32)
    corner_udf = np.asarray(corner_udf, dtype=np.float64)
    if corner_udf.shape != (len(flags), 8):
        raise ValueError(f"corner_udf must be ({len(flags)}, 8), got shape {corner_udf.shape}")
    signs = corner_signs(flags, flag_threshold)
    values = signs * np.maximum(corner_udf, UDF_FLOOR)
    surface = (signs > 0).any(axis=1)
    V, F = local_marching_cubes(np.asarray(cubes)[surface], values[surface], N)
    return Extraction(V, F, {"surface_cubes": int(surface.sum())})
