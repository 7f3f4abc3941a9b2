"""MeshUDF-style extraction of an unsigned distance field (`udf`; Guillard et al. 2022).

Input: the UDF ``d`` and its unit gradient ``g`` on the grid of :mod:`foundation.grid` (``(N, N, N)``
and ``(N, N, N, 3)``, ``'ij'`` indexing, spacing ``h = 2 / (N - 1)``). Output: an unoriented
triangle mesh in the canonical frame [-1, 1]^3 (it may have small holes).

1. Candidate cubes (grid cells): mean corner ``d < 1.05 h`` and max corner ``d <= 1.74 h``.
2. Pseudo-signs per cube from gradient agreement. The anchor is the corner with the largest ``d``
   (its gradient is the most reliable) and gets +. ``sign_rule='anchor'`` (the simple version):
   a corner whose gradient points the same way as the anchor's (``g_i . g_A >= 0``) gets +, the
   others -. ``sign_rule='hybrid'`` (default): the same where the gradients clearly agree or
   disagree (``|g_i . g_A| > 0.5``); where they are nearly orthogonal (the two faces of a sharp
   edge, where the anchor rule cuts holes), the corner takes its side of the anchor's tangent
   plane through the anchor's closest surface point ``q_A = x_A - d_A g_A``:
   ``sign(g_A . (x_i - q_A)) = sign(d_A + g_A . (x_i - x_A))``. On an analytic cube UDF the
   anchor rule leaves holes along the cube's edges, the hybrid rule a closed mesh short of the
   cube's area only by marching cubes' chamfer at the edges (docs/PERFORMANCE.md, section 7).
3. Each candidate cube is triangulated with the marching-cubes case table (256 sign cases -> up to
   5 triangles over the 12 cube edges) at level 0 of ``sign * d``, all cubes at once in numpy. A
   crossing on the cube edge between corners 0 and 1 (signed values ``f0 < 0 <= f1`` or the
   reverse) sits at ``t = f0 / (f0 - f1) = d0 / (d0 + d1)``; it depends only on the grid edge, so
   neighbouring cubes that both cut an edge produce the same point, and vertices are merged by
   grid edge id (a crossing at a corner, ``t`` in {0, 1}, is merged by grid point).
4. Faces whose largest vertex UDF is ``>= h / 6`` are removed. The vertex UDF is ``udf_at(vertices)``
   when a callable is given (neural / oracle mode: the true field), else the first-order estimate
   from the edge's two corners ``min_i |d_i + g_i . (p - x_i)|`` (exact for a plane). Plain
   linear (trilinear) interpolation of ``d`` is not used: along an edge it gives
   ``2 d0 d1 / (d0 + d1)``, i.e. ``h / 2`` for a surface crossing mid-edge, so the ``h / 6`` test
   would remove almost every face.

The case table is generated once from scikit-image's classic (Lorensen) marching cubes run on the
256 sign patterns of a single 2x2x2 cube.
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from foundation.grid import LOWER, ijk_axis_to_edge_index, num_edges, spacing
from foundation.timing import record, stage
from methods.base import Extraction
from methods.extractors.mesh_ops import drop_unreferenced_vertices

__all__ = ["meshudf_marching_cubes", "candidate_cubes", "mc_case_table", "CUBE_CORNERS", "CUBE_EDGES"]

#: Corner c of a cube sits at offset (c & 1, (c >> 1) & 1, (c >> 2) & 1) in index units.
CUBE_CORNERS = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=np.int64)


def _cube_edges() -> np.ndarray:
    """(12, 2) corner pairs; edges 4a..4a+3 run along axis a, lower corner first."""
    edges = []
    for a in range(3):
        b, c = [x for x in range(3) if x != a]
        for ob, oc in ((0, 0), (1, 0), (0, 1), (1, 1)):
            lo = (ob << b) | (oc << c)
            edges.append((lo, lo | (1 << a)))
    return np.array(edges, dtype=np.int64)


#: The 12 cube edges as (lower corner, upper corner); edge e runs along axis e // 4.
CUBE_EDGES = _cube_edges()
_EDGE_AXIS = np.repeat(np.arange(3), 4)


@functools.lru_cache(maxsize=1)
def mc_case_table() -> tuple[np.ndarray, np.ndarray]:
    """Marching-cubes case table: (triangles (256, 5, 3) cube-edge ids padded with -1, counts (256,)).

    Case bit c is set when corner c is on the negative side. Generated from scikit-image's
    ``marching_cubes(method='lorensen')`` on a 2x2x2 volume holding -1 / +1 at the corners: its
    vertices are edge midpoints, mapped back to :data:`CUBE_EDGES` ids.
    """
    from skimage.measure import marching_cubes

    # midpoint of each cube edge (index units, doubled to stay integer) -> edge id
    mid2 = CUBE_CORNERS[CUBE_EDGES[:, 0]] + CUBE_CORNERS[CUBE_EDGES[:, 1]]
    lookup = {tuple(m): e for e, m in enumerate(mid2)}
    table = np.full((256, 5, 3), -1, dtype=np.int64)
    counts = np.zeros(256, dtype=np.int64)
    for case in range(1, 255):  # 254 tiny table-building calls, once per process
        negative = (case >> np.arange(8)) & 1
        vol = np.where(negative, -1.0, 1.0).reshape(2, 2, 2, order="F")  # vol[dx, dy, dz]
        verts, faces, _, _ = marching_cubes(vol, 0.0, method="lorensen")
        edge_of_vertex = np.array([lookup[tuple(np.rint(2 * v).astype(np.int64))] for v in verts])
        counts[case] = len(faces)
        table[case, : len(faces)] = edge_of_vertex[faces]
    return table, counts


def candidate_cubes(udf: np.ndarray, mean_factor: float = 1.05, max_factor: float = 1.74) -> np.ndarray:
    """Grid index (C, 3) int64 of the cells with mean corner d < mean_factor h and max corner d <= max_factor h."""
    N = udf.shape[0]
    h = spacing(N)
    M = N - 1
    near = udf <= max_factor * h
    ok = np.ones((M, M, M), dtype=bool)
    for dx, dy, dz in CUBE_CORNERS:  # 8 shifted views
        ok &= near[dx:dx + M, dy:dy + M, dz:dz + M]
    ijk = np.argwhere(ok)
    corner_ids = _corner_ids(N, ijk)
    mean = udf.reshape(-1)[corner_ids].mean(axis=1)
    return ijk[mean < mean_factor * h]


def _corner_ids(N, ijk):
    """Flat grid-point ids (C, 8) of the corners of cells ``ijk``."""
    base = (ijk[:, 0] * N + ijk[:, 1]) * N + ijk[:, 2]
    offs = (CUBE_CORNERS[:, 0] * N + CUBE_CORNERS[:, 1]) * N + CUBE_CORNERS[:, 2]
    return base[:, None] + offs[None, :]


def _pseudo_signs(D, G, rule, h):
    """Pseudo-signs (C, 8) in {-1, +1} of the corners of each cube, the anchor corner being +1.

    ``D`` (C, 8) corner distances, ``G`` (3, C, 8) corner gradients (component-major).
    """
    C = len(D)
    rows = np.arange(C)
    anchor = np.argmax(D, axis=1)
    g_anchor = G[:, rows, anchor]  # (3, C)
    dots = G[0] * g_anchor[0][:, None] + G[1] * g_anchor[1][:, None] + G[2] * g_anchor[2][:, None]
    if rule == "anchor":
        return np.where(dots >= 0, 1.0, -1.0)
    # 'hybrid': where gradients are nearly orthogonal (|g_i . g_A| <= 0.5, e.g. the two sides of a
    # sharp edge), use the side of the anchor's tangent plane g_A . (y - q_A) = 0 through its
    # closest surface point q_A = x_A - d_A g_A:  g_A . (x_i - q_A) = d_A + g_A . (x_i - x_A)
    corner_dot = (CUBE_CORNERS * h) @ g_anchor  # (8, C): g_A . x_i relative to the cube origin
    plane = D[rows, anchor][:, None] + corner_dot.T - corner_dot[anchor, rows][:, None]
    side = np.where(np.abs(dots) > _CONFIDENT_DOT, dots, plane)
    return np.where(side >= 0, 1.0, -1.0)


_CONFIDENT_DOT = 0.5


def meshudf_marching_cubes(udf: np.ndarray, grad: np.ndarray, *,
                           udf_at: Callable[[np.ndarray], np.ndarray] | None = None, mean_factor: float = 1.05,
                           max_factor: float = 1.74, face_factor: float = 1.0 / 6.0,
                           sign_rule: str = "hybrid") -> Extraction:
    """MeshUDF-style mesh of the zero set of a UDF sampled on the grid (see module docstring).

    Parameters
    ----------
    udf : (N, N, N) unsigned distances d >= 0 on the grid, canonical units (NaN = unknown, treated
        as far).
    grad : (N, N, N, 3) unit gradients of d on the grid (needed only where d < 2h; NaN -> 0).
    udf_at : optional callable mapping canonical points (n, 3) float64 to their UDF (n,), used for
        the face filter (the network or the exact field); default: first-order estimate.
    mean_factor, max_factor : candidate cubes have mean corner d < mean_factor h and max corner
        d <= max_factor h (1.05, 1.74).
    face_factor : faces whose largest vertex UDF is >= face_factor h are removed (1/6).
    sign_rule : ``'hybrid'`` (default) or ``'anchor'`` (the simple rule); see module docstring.

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (n, 3) float64, canonical frame; faces (m, 3) int64,
    unoriented; no info. The steps are timed as the stages ``candidates``, ``pseudo_signs``,
    ``triangulation`` and ``filter`` (:mod:`foundation.timing`).
    """
    udf = np.asarray(udf)
    grad = np.asarray(grad)
    if udf.ndim != 3 or len(set(udf.shape)) != 1 or udf.shape[0] < 2:
        raise ValueError(f"udf must have shape (N, N, N) with N >= 2, got {udf.shape}")
    N = udf.shape[0]
    if grad.shape != (N, N, N, 3):
        raise ValueError(f"grad must have shape ({N}, {N}, {N}, 3), got {grad.shape}")
    if sign_rule not in ("anchor", "hybrid"):
        raise ValueError(f"sign_rule must be 'anchor' or 'hybrid', got {sign_rule!r}")
    h = spacing(N)
    with stage("candidates"):
        ijk = candidate_cubes(udf, mean_factor, max_factor)  # NaN corners are never candidates
        corner_ids = _corner_ids(N, ijk)
        D = udf.reshape(-1)[corner_ids].astype(np.float64, copy=False)  # (C, 8)
        flat_grad = grad.reshape(-1)
        G = np.empty((3,) + corner_ids.shape)  # (3, C, 8) corner gradients, component-major
        for a in range(3):
            G[a] = flat_grad[corner_ids * 3 + a]
        np.nan_to_num(G, copy=False)

    with stage("pseudo_signs"):
        S = _pseudo_signs(D, G, sign_rule, h) if len(D) else np.zeros((0, 8))
        F = S * D  # pseudo-signed distances
        negative = F < 0
        case = np.packbits(negative, axis=1, bitorder="little")[:, 0].astype(np.int64)

    with stage("triangulation"):
        active = np.flatnonzero(mc_case_table()[1][case])
        if len(active):
            verts, faces, crossings = _triangulate(N, ijk[active], F[active], negative[active], case[active])
    if len(active) == 0:
        record("filter", 0.0)
        return Extraction(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))

    with stage("filter"):
        if udf_at is not None:
            vd = np.asarray(udf_at(verts), dtype=np.float64).reshape(-1)
            if vd.shape != (len(verts),):
                raise ValueError(f"udf_at returned shape {vd.shape} for {len(verts)} points")
        else:
            vd = _first_order_udf(len(verts), crossings, D[active], G[:, active], h)
        keep = vd[faces].max(axis=1) < face_factor * h
        keep &= (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
        verts, faces = drop_unreferenced_vertices(verts, faces[keep])
    return Extraction(verts, faces)


def _triangulate(N: int, ijk: np.ndarray, F: np.ndarray, negative: np.ndarray, case: np.ndarray):
    """Step 3 on the cubes ``ijk`` (C, 3) with a triangle: pseudo-signed corner distances ``F`` (C, 8),
    their signs ``negative`` and sign cases ``case`` (C,).

    Returns (vertices (n, 3) canonical frame, merged by grid edge or grid point; faces (T, 3);
    crossings (vertex id, cube, lower corner, upper corner, axis, t) per cube-edge crossing)."""
    h = spacing(N)
    table, counts = mc_case_table()
    ntri = counts[case]
    C = len(ijk)
    # crossings: cube edges whose corners have opposite pseudo-signs
    cc, ee = np.nonzero(negative[:, CUBE_EDGES[:, 0]] != negative[:, CUBE_EDGES[:, 1]])
    c0, c1 = CUBE_EDGES[ee, 0], CUBE_EDGES[ee, 1]
    f0, f1 = F[cc, c0], F[cc, c1]
    t = f0 / (f0 - f1)  # t = d0 / (d0 + d1), the same for every cube sharing the grid edge
    axis = _EDGE_AXIS[ee]
    start = ijk[cc] + CUBE_CORNERS[c0]  # grid index of the edge's lower endpoint
    # merge key: the grid edge, or the grid point when the crossing is at an endpoint
    key = ijk_axis_to_edge_index(N, start, axis)
    at0, at1 = t <= 0.0, t >= 1.0
    if at0.any() or at1.any():
        point = (start[:, 0] * N + start[:, 1]) * N + start[:, 2]
        step = np.array([N * N, N, 1])[axis]
        key = np.where(at0, num_edges(N) + point, key)
        key = np.where(at1, num_edges(N) + point + step, key)
    present = np.zeros(num_edges(N) + N**3, dtype=bool)
    present[key] = True
    uniq = np.flatnonzero(present)
    slot_of_key = np.empty(len(present), dtype=np.int64)
    slot_of_key[uniq] = np.arange(len(uniq))
    vid = slot_of_key[key]
    pos_index = start.astype(np.float64)
    pos_index[np.arange(len(t)), axis] += t
    verts = np.empty((len(uniq), 3))
    verts[vid] = LOWER + pos_index * h  # duplicates write the same point
    vid_of = np.full((C, 12), -1, dtype=np.int64)
    vid_of[cc, ee] = vid
    cube = np.repeat(np.arange(C), ntri)
    slot = np.arange(len(cube)) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    faces = vid_of[cube[:, None], table[case[cube], slot]]  # (T, 3)
    return verts, faces, (vid, cc, c0, c1, axis, t)


def _first_order_udf(n: int, crossings, D: np.ndarray, G: np.ndarray, h: float) -> np.ndarray:
    """(n,) UDF estimates at the vertices: from both endpoints of each crossing's cube edge,
    ``d_i + g_i . (p - x_i)`` with ``p - x_i`` along the edge; the smaller in magnitude (the endpoint
    whose linear model still holds at p). ``D`` (C, 8) and ``G`` (3, C, 8): the corner distances and
    gradients of the cubes of :func:`_triangulate`."""
    vid, cc, c0, c1, axis, t = crossings
    step = t * h
    est0 = np.abs(D[cc, c0] + G[axis, cc, c0] * step)
    est1 = np.abs(D[cc, c1] - G[axis, cc, c1] * (h - step))
    vd = np.empty(n)
    vd[vid] = np.minimum(est0, est1)
    return vd
