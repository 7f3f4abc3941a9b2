"""DualMesh-UDF (Zhang et al., ICCV 2023): dual contouring of an unsigned distance field.

No signs are needed: every cell near the surface gets a dual vertex from a QEF of tangent planes
sampled in it, and every grid edge whose four cells all have a vertex gets a quad. Steps, with the
constants of the authors' ``extract_mesh.py`` / ``octree.cpp`` / ``qef_eigen.cpp`` / ``mesh_utils.cpp``:

1. **Leaves**: the cells (of the grid of :mod:`foundation.grid`) whose centroid has
   ``d < sqrt(3) h / 2 + 0.002``. The authors reach them by an octree refined with the same test
   at every level; for a 1-Lipschitz field the leaves at the finest level are exactly these cells.
2. **Samples**: each leaf's 3 x 3 x 3 lattice (corners, edge and face midpoints, centroid; spacing
   h / 2), with the UDF d and its unit gradient g. A sample is *valid* when ``d > 0.002`` and its
   projection ``p - d g`` has ``d < 0.002`` (a second query).
3. **QEF per leaf**: one row ``g . x = g . p - d`` per valid sample (the tangent plane through the
   projection), in coordinates centred on the mean of the projections that fall in the cell
   (grown by 1 %; else the centroid). Solved by a truncated SVD: singular values below 0.08 of the
   largest are dropped. Rank 3: a corner, kept if inside the cell grown by 100 %. Rank 2: a sharp
   edge, the line meets the six face planes; the mean of the meeting points inside the cell (else
   inside the cell grown by 100 %). Rank 1: a plane, it meets the twelve cell edges; the mean of
   those inside the cell (else grown by 15 %). Without a vertex (or with <= 2 valid samples) the
   samples whose projections lie in the cell (grown by 0.01 %, then 2 %, 7 %, ... < 30 % until more
   than 2) are solved again, and the result kept if it lies in the cell.
4. **Faces**: a quad per interior grid edge whose four cells all have a vertex.
5. **Triangulation with validation** (``triangulate_faces``): a planar quad (smallest singular value
   of its centred corners < 0.25 of the largest) is kept when every plane-type vertex's normal is
   within ~30 degrees of the quad's normal (|cos| >= 0.85) and every edge-type vertex's direction is
   at more than ~60 degrees from it (|cos| <= 0.5); a non-planar quad is split along the diagonal
   through its plane-type vertices when their triangles pass the same test, else along 0-2 (two
   edge-type vertices there) or 1-3; other quads are dropped.

The output is unoriented (a UDF has no inside) and may have holes where a quad was dropped.
Triangles of no area (collinear corners: whether their quad passes step 5 is decided by rounding, as
its normal is any direction across the line) are dropped, and after the authors' merge of vertices
closer than 1e-7 so are triangles with a repeated corner and repeated triangles (two layers of leaves
that place the same vertices); the surface they cover is the same.
"""

from __future__ import annotations

import itertools
from typing import Callable

import numpy as np

from foundation.grid import LOWER, spacing
from foundation.timing import stage
from methods.base import Extraction
from methods.extractors.mesh_ops import drop_unreferenced_vertices

#: d of a reliable sample, of a valid projection, and the leaf test's margin (canonical units).
RELIABLE_UDF = 0.002
#: Singular values below this fraction of the largest are dropped.
SINGULAR_CUTOFF = 0.08
#: Growth of the cell (fraction of its size per side) a corner, edge or plane vertex may lie in.
CORNER_GROWTH, EDGE_GROWTH, PLANE_GROWTH = 1.0, 1.0, 0.15
#: Projections in the cell grown by this much set the QEF's centre.
CENTRE_GROWTH = 0.01
#: Growths of the cell the fallback QEF's samples are taken from, tried in order.
FALLBACK_GROWTHS = (1e-4, 0.02, 0.07, 0.12, 0.17, 0.22, 0.27)
#: Quad validation: coplanarity ratio, and |cos| bounds for plane- and edge-type vertices.
COPLANAR_RATIO, PLANE_ALIGNMENT, EDGE_ALIGNMENT = 0.25, 0.85, 0.5
#: Triangles below this area (x h^2) have collinear corners and are dropped.
ZERO_AREA = 1e-9
#: Vertex types.
CORNER, EDGE, PLANE = 0, 1, 2
#: The 27 lattice offsets of a leaf (in half-cells).
_LATTICE = np.array(list(itertools.product(range(3), repeat=3)), dtype=np.int64)
#: Per axis, the four cells around a grid edge starting at point (i, j, k), in the quad's cyclic
#: order (the order of the authors' edge recursion).
_QUAD_CELLS = {
    0: np.array([[0, -1, -1], [0, -1, 0], [0, 0, 0], [0, 0, -1]]),
    1: np.array([[-1, 0, -1], [0, 0, -1], [0, 0, 0], [-1, 0, 0]]),
    2: np.array([[-1, -1, 0], [-1, 0, 0], [0, 0, 0], [0, -1, 0]]),
}


def _inside(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, growth: float) -> np.ndarray:
    """Strictly inside the box [lo, hi] grown by ``growth`` x its size per side (broadcast over
    leading axes; the last axis is xyz)."""
    pad = (hi - lo) * growth
    return np.all((points > lo - pad) & (points < hi + pad), axis=-1)


def leaf_cells(udf_grid: np.ndarray, udf_at: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Cells (M, 3) whose centroid has ``d < sqrt(3) h / 2 + RELIABLE_UDF``, in C order.

    Only cells with a corner below ``sqrt(3) h + RELIABLE_UDF`` on ``udf_grid`` (N, N, N) can pass
    (a 1-Lipschitz field), so ``udf_at`` is asked for their centroids only."""
    N = udf_grid.shape[0]
    h = spacing(N)
    half = 0.5 * np.sqrt(3.0) * h
    low = udf_grid < 2.0 * half + RELIABLE_UDF
    near = np.zeros((N - 1,) * 3, dtype=bool)
    for a, b, c in itertools.product((0, 1), repeat=3):
        near |= low[a:N - 1 + a, b:N - 1 + b, c:N - 1 + c]
    cells = np.argwhere(near)
    if len(cells) == 0:
        return cells
    centroids = LOWER + (cells + 0.5) * h
    return cells[np.asarray(udf_at(centroids)) < half + RELIABLE_UDF]


def _truncated_solve(A_rows: np.ndarray, b: np.ndarray, mask: np.ndarray):
    """Least squares ``A x = b`` per leaf with a truncated SVD (rows where ``mask`` holds).

    Returns (x (M, 3), rank (M,) in 1..3, direction (M, 3): the normal for rank 1, the line's
    direction for rank 2)."""
    w = mask[..., None].astype(np.float64)
    ata = np.einsum("mri,mrj->mij", A_rows * w, A_rows)
    atb = np.einsum("mri,mr->mi", A_rows * w, b)
    lam, vec = np.linalg.eigh(ata)  # ascending: the singular values of A are sqrt(lam)
    s = np.sqrt(np.clip(lam, 0.0, None))[:, ::-1]  # descending
    vec = vec[:, :, ::-1]
    keep = s > s[:, :1] * SINGULAR_CUTOFF
    inv = np.where(keep, 1.0 / np.where(keep, s * s, 1.0), 0.0)
    x = np.einsum("mij,mj,mkj,mk->mi", vec, inv, vec, atb)
    rank = keep.sum(axis=1)
    direction = np.where((rank == 1)[:, None], vec[:, :, 0], vec[:, :, 2])
    return x, rank, direction


def _line_candidates(point, direction, lo, hi):
    """Where the lines (point, direction) meet the six face planes of the boxes: (M, 6, 3), far
    away (100) where a line is parallel to a plane."""
    out = np.full(point.shape[:1] + (6, 3), 100.0)
    for n, (axis, bound) in enumerate(itertools.product(range(3), (0, 1))):
        value = (lo if bound == 0 else hi)[:, axis]
        d = direction[:, axis]
        ok = np.abs(d) >= 1e-4
        t = np.where(ok, (value - point[:, axis]) / np.where(ok, d, 1.0), 0.0)
        out[:, n] = np.where(ok[:, None], point + t[:, None] * direction, 100.0)
    return out


def _plane_candidates(point, normal, lo, hi):
    """Where the planes (point, normal) meet the twelve cell edges: (M, 12, 3), far away (100)
    where an edge is parallel to the plane."""
    out = np.full(point.shape[:1] + (12, 3), 100.0)
    n = 0
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for b0, b1 in itertools.product((0, 1), repeat=2):
            start = lo.copy()
            start[:, others[0]] = (lo, hi)[b0][:, others[0]]
            start[:, others[1]] = (lo, hi)[b1][:, others[1]]
            na = normal[:, axis]
            ok = np.abs(na) >= 1e-4
            t = np.where(ok, np.einsum("mi,mi->m", normal, point - start) / np.where(ok, na, 1.0), 0.0)
            hit = start.copy()
            hit[:, axis] += t
            out[:, n] = np.where(ok[:, None], hit, 100.0)
            n += 1
    return out


def _mean_of(candidates, ok):
    count = ok.sum(axis=1)
    total = np.einsum("mc,mci->mi", ok.astype(np.float64), np.where(ok[..., None], candidates, 0.0))
    return total / np.maximum(count, 1)[:, None], count > 0


def _dual_points(coords, grads, udfs, mask, lo, hi):
    """The authors' ``solve_point`` for every leaf: QEF, then corner / edge / plane placement.

    Returns (point (M, 3), found (M,), type (M,), direction (M, 3), inside (M,))."""
    b = np.einsum("mri,mri->mr", coords, grads) - udfs
    x, rank, direction = _truncated_solve(grads, b, mask)
    M = len(x)
    point, found = np.zeros((M, 3)), np.zeros(M, dtype=bool)
    kind = np.where(rank >= 3, CORNER, np.where(rank == 2, EDGE, PLANE))
    inside = np.zeros(M, dtype=bool)

    corner = kind == CORNER
    point[corner] = x[corner]
    found[corner] = _inside(x[corner], lo[corner], hi[corner], CORNER_GROWTH)
    inside[corner] = _inside(x[corner], lo[corner], hi[corner], 1e-5)

    for k, candidates_of, growth in ((EDGE, _line_candidates, EDGE_GROWTH), (PLANE, _plane_candidates, PLANE_GROWTH)):
        sel = kind == k
        if not sel.any():
            continue
        c = candidates_of(x[sel], direction[sel], lo[sel], hi[sel])
        ok = _inside(c, lo[sel][:, None], hi[sel][:, None], 1e-5)
        grown = _inside(c, lo[sel][:, None], hi[sel][:, None], growth)
        ok = np.where(ok.any(axis=1)[:, None], ok, grown)
        p, has = _mean_of(c, ok)
        point[sel], found[sel] = p, has
        inside[sel] = has & _inside(p, lo[sel], hi[sel], 1e-4)
    return point, found, kind, direction, inside


def dual_vertices(cells: np.ndarray, N: int, udf_grad_at, udf_at):
    """Step 2 and 3 for the leaves ``cells`` (M, 3) of the N^3 grid.

    ``udf_grad_at(points (P, 3)) -> (d (P,), unit gradient (P, 3))``, ``udf_at(points) -> d``.
    Returns (has_vertex (M,), vertices (M, 3) canonical frame, type (M,), direction (M, 3))."""
    h = spacing(N)
    M = len(cells)
    lattice = 2 * cells[:, None, :] + _LATTICE[None]  # (M, 27, 3) on the half-spacing lattice
    L = 2 * N - 1
    flat = np.ravel_multi_index(lattice.reshape(-1, 3).T, (L, L, L))
    unique, where = np.unique(flat, return_inverse=True)
    points = LOWER + np.stack(np.unravel_index(unique, (L, L, L)), axis=1) * (h / 2)
    d, g = udf_grad_at(points)
    d, g = np.asarray(d, dtype=np.float64), np.asarray(g, dtype=np.float64)
    projections = points - g * d[:, None]
    reliable = d > RELIABLE_UDF
    valid = np.zeros(len(points), dtype=bool)
    if reliable.any():
        valid[reliable] = np.asarray(udf_at(projections[reliable])) < RELIABLE_UDF

    coords = points[where].reshape(M, 27, 3)
    grads = g[where].reshape(M, 27, 3)
    udfs = d[where].reshape(M, 27)
    mask = valid[where].reshape(M, 27)
    proj = projections[where].reshape(M, 27, 3)
    lo = LOWER + cells * h
    hi = lo + h

    in_cell = mask & _inside(proj, lo[:, None], hi[:, None], CENTRE_GROWTH)
    centre = np.where((in_cell.sum(1) > 0)[:, None],
                      np.einsum("mr,mri->mi", in_cell.astype(np.float64), proj) / np.maximum(in_cell.sum(1), 1)[:, None],
                      lo + h / 2)
    coords = coords - centre[:, None]
    proj = proj - centre[:, None]
    lo_c, hi_c = lo - centre, hi - centre

    count = mask.sum(axis=1)
    point, found, kind, direction, _ = _dual_points(coords, grads, udfs, mask, lo_c, hi_c)
    found &= count > 2
    retry = ~found & (count > 0)
    if retry.any():
        r = np.flatnonzero(retry)
        chosen = np.zeros((len(r), 27), dtype=bool)
        settled = np.zeros(len(r), dtype=bool)
        for growth in FALLBACK_GROWTHS:
            sub = mask[r] & _inside(proj[r], lo_c[r][:, None], hi_c[r][:, None], growth)
            take = ~settled
            chosen[take] = sub[take]
            settled |= sub.sum(axis=1) > 2
        solvable = chosen.sum(axis=1) > 2
        r, chosen = r[solvable], chosen[solvable]
        if len(r):
            p2, f2, k2, d2, in2 = _dual_points(coords[r], grads[r], udfs[r], chosen, lo_c[r], hi_c[r])
            accept = f2 & in2
            r, accept_idx = r[accept], np.flatnonzero(accept)
            point[r], found[r], kind[r], direction[r] = p2[accept_idx], True, k2[accept_idx], d2[accept_idx]
    return found, point + centre, kind, direction


def quads(cells: np.ndarray, has_vertex: np.ndarray, N: int) -> np.ndarray:
    """Step 4: (Q, 4) vertex indices (into ``cells``) of the quads, one per interior grid edge whose
    four cells all have a vertex, in the cyclic order of :data:`_QUAD_CELLS`; by axis, then C order."""
    vertex_of = np.full((N - 1,) * 3, -1, dtype=np.int64)
    vertex_of[tuple(cells[has_vertex].T)] = np.flatnonzero(has_vertex)
    out = []
    for axis in range(3):
        lo = [1, 1, 1]
        lo[axis] = 0
        # each quad has a vertex cell as its first cell: the edges those cells start, in C order
        starts = cells[has_vertex] - _QUAD_CELLS[axis][0]
        starts = starts[np.all((starts >= lo) & (starts <= N - 2), axis=1)]
        around = vertex_of[tuple(np.moveaxis(starts[:, None, :] + _QUAD_CELLS[axis][None], -1, 0))]
        out.append(around[np.all(around >= 0, axis=1)])
    return np.concatenate(out) if out else np.zeros((0, 4), dtype=np.int64)


def _smallest_singular_vector(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values (K, 3) and the unit normal (K, 3) of centred point sets (K, n, 3)."""
    centred = points - points.mean(axis=1, keepdims=True)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    return s, vt[:, -1, :]


def triangulate(vertices, kinds, directions, quad_ids) -> np.ndarray:
    """Step 5: two triangles per kept quad (F, 3), the authors' validation rules."""
    if len(quad_ids) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    fv, ft, fd = vertices[quad_ids], kinds[quad_ids], directions[quad_ids]
    s, normal = _smallest_singular_vector(fv)
    planar = s[:, 2] < s[:, 0] * COPLANAR_RATIO
    cos = np.abs(np.einsum("qci,qi->qc", fd, normal))
    planar_ok = np.all(np.where(ft == PLANE, cos >= PLANE_ALIGNMENT, np.where(ft == EDGE, cos <= EDGE_ALIGNMENT, True)), axis=1)

    # non-planar: each plane-type corner's triangle (j, j+1, j+3) must face along its normal
    tri_ok = np.ones(ft.shape, dtype=bool)
    for j in range(4):
        corners = fv[:, [j, (j + 1) % 4, (j + 3) % 4]]
        _, n = _smallest_singular_vector(corners)
        tri_ok[:, j] = np.abs(np.einsum("qi,qi->q", fd[:, j], n)) >= PLANE_ALIGNMENT
    is_plane = ft == PLANE
    pairs_ok = ~((is_plane[:, 0] | is_plane[:, 2]) & (is_plane[:, 1] | is_plane[:, 3]))
    bent_ok = np.all(~is_plane | tri_ok, axis=1) & pairs_ok
    t = np.where(is_plane[:, 3], 3, np.where(is_plane[:, 2], 2, np.where(is_plane[:, 1], 1, np.where(is_plane[:, 0], 0, -1))))

    q = np.arange(len(quad_ids))
    split_02 = np.stack([quad_ids[:, [0, 1, 2]], quad_ids[:, [2, 3, 0]]], axis=1)
    split_13 = np.stack([quad_ids[:, [0, 1, 3]], quad_ids[:, [1, 2, 3]]], axis=1)
    tt = np.maximum(t, 0)
    around_t = np.stack([quad_ids[q, tt], quad_ids[q, (tt + 1) % 4], quad_ids[q, (tt + 3) % 4],
                         quad_ids[q, (tt + 1) % 4], quad_ids[q, (tt + 2) % 4], quad_ids[q, (tt + 3) % 4]], axis=1).reshape(-1, 2, 3)
    both_edges = (ft[:, 0] == EDGE) & (ft[:, 2] == EDGE)
    bent = np.where((t >= 0)[:, None, None], around_t, np.where(both_edges[:, None, None], split_02, split_13))
    tris = np.where(planar[:, None, None], split_02, bent)
    keep = np.where(planar, planar_ok, bent_ok)
    return tris[keep].reshape(-1, 3)


def dualmesh_udf(udf_grid: np.ndarray, udf_grad_at, udf_at) -> Extraction:
    """DualMesh-UDF on the grid of :mod:`foundation.grid`, timed as the stage ``dualmesh``
    (:mod:`foundation.timing`).

    Parameters
    ----------
    udf_grid : (N, N, N) UDF on the grid points (canonical units); it only bounds which cells are
        asked for their centroid's UDF (values above sqrt(3) h + 0.002 may be clamped).
    udf_grad_at : callable, points (P, 3) -> (UDF (P,), unit gradient (P, 3)).
    udf_at : callable, points (P, 3) -> UDF (P,).

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (n, 3) float64, canonical frame; faces (m, 3) int64,
    unoriented; info: ``leaves``, ``dual_vertices``, ``corner_vertices``, ``edge_vertices``,
    ``quads`` and, when a face is left, ``repeated_faces``.
    """
    with stage("dualmesh"):
        return _dualmesh_udf(udf_grid, udf_grad_at, udf_at)


def _dualmesh_udf(udf_grid, udf_grad_at, udf_at) -> Extraction:
    import igl

    N = udf_grid.shape[0]
    cells = leaf_cells(np.asarray(udf_grid), udf_at)
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    if len(cells) == 0:
        return Extraction(*empty, {"leaves": 0, "dual_vertices": 0, "quads": 0})
    has_vertex, vertices, kinds, directions = dual_vertices(cells, N, udf_grad_at, udf_at)
    quad_ids = quads(cells, has_vertex, N)
    faces = triangulate(vertices, kinds, directions, quad_ids)
    # a quad whose corners are collinear gives triangles of no area, and whether they pass the quad
    # test depends on rounding (its normal is any direction across the line): they cover nothing
    h = spacing(N)
    corners = vertices[faces]
    area2 = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    flat = area2 <= 2.0 * ZERO_AREA * h * h
    faces = faces[~flat]
    facts = {"leaves": int(len(cells)), "dual_vertices": int(has_vertex.sum()),
             "corner_vertices": int((has_vertex & (kinds == CORNER)).sum()),
             "edge_vertices": int((has_vertex & (kinds == EDGE)).sum()),
             "quads": int(len(quad_ids))}
    if len(faces) == 0:
        return Extraction(*empty, facts)
    V, _, _, F = igl.remove_duplicate_vertices(vertices, faces.astype(np.int64), 1e-7)
    # two layers of leaves can place the same vertices and so the same triangles twice; a triangle
    # whose merged corners repeat has no area: the surface is the set of the others, once each
    F = np.asarray(F, dtype=np.int64)
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    _, first = np.unique(np.sort(F, axis=1), axis=0, return_index=True)
    facts["repeated_faces"] = int(len(F) - len(first))
    V, F = drop_unreferenced_vertices(np.asarray(V, dtype=np.float64), F[np.sort(first)])
    return Extraction(V, F, facts)
