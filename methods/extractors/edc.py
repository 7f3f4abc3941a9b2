"""E-DC: the edge-based dual contouring of SALS, as pure array functions.

Input: the intersected grid edges of the grid of :mod:`foundation.grid` (flat edge ids, flat edge
order), their hit parameters ``s`` and (optionally) unit normals. Output: an unoriented triangle
mesh in the canonical frame [-1, 1]^3. No signs and no orientation are used, so open and
non-manifold surfaces come out naturally.

Steps (numbered as in the paper's E-DC; step 1, the network query ``o_hat > 0.1``, and step 3, the
normals by autograd, belong to the caller):

2. Edge points. Edge ``e`` along axis ``a`` starting at grid index ``(i, j, k)`` has lower endpoint
   ``u = -1 + (i, j, k) h`` and upper endpoint ``v = u + h e_a``; its hit point is
   ``p_e = s u + (1 - s) v = u + (1 - s) h e_a``.
4. Vertices. Every cell with at least one intersected edge among its 12 gets one vertex, the
   minimiser of the QEF ``sum_i (n_i . (x - p_i))^2`` over its intersected edges, solved around
   the mass point ``c = mean(p_i)``::

       x = c + pinv(A^T A) (A^T b - A^T A c),   A = rows n_i,  b_i = n_i . p_i

   ``pinv`` is the pseudo-inverse from the eigen-decomposition of the symmetric 3x3 ``A^T A``,
   dropping eigenvalues ``< qef_cutoff`` (0.1, *paper*; with unit normals a dropped direction has
   little support and falls back to the mass point). Without normals the vertex is ``c``.
   ``clamp_to_cell`` (off in the paper) clips each vertex to its cell.
5. Faces. For every intersected *interior* edge (all 4 cells around it exist in the grid):
   ``'fan4'`` (paper) adds the edge point as a vertex and 4 triangles joining it to the vertices of
   the 4 surrounding cells in cyclic order; ``'quad2'`` adds 2 triangles over the 4 cell vertices;
   ``'fan4-adaptive'`` keeps the fan where the edge point lies on the plane of the 4 cell vertices
   (within :data:`FAN_PLANE_TOLERANCE` h) and elsewhere adds 2 triangles split along the flatter
   diagonal (see :func:`edge_dual_contouring`). Every one of these cells has a vertex (this very
   edge is one of its intersected edges). All three rules work per intersected edge on the same
   ring of 4 cells, so they have the same mesh edges between cell vertices: the same boundary and
   non-manifold edges (open and non-manifold surfaces survive alike).

Everything is batched: per-cell sums with ``np.bincount``, the 3x3 pseudo-inverses in closed form
(trigonometric eigenvalues, spectral projectors by Cayley-Hamilton), no Python loop over edges or cells.
Cell ``(i, j, k)`` has flat id ``(i (N-1) + j) (N-1) + k``.
"""

from __future__ import annotations

import numpy as np

from foundation.grid import LOWER, edge_index_to_ijk_axis, num_edges, spacing
from foundation.timing import record, stage
from methods.base import Extraction
from methods.extractors.mesh_ops import drop_unreferenced_vertices

__all__ = [
    "edge_dual_contouring",
    "edc_cell_vertices",
    "edge_points",
    "intersected_edges",
    "qef_solve",
    "DEFAULT_QEF_CUTOFF",
    "PAPER_HIT_THRESHOLD",
    "FACE_RULES",
    "FAN_PLANE_TOLERANCE",
]

#: Eigenvalues of A^T A below this are dropped in the QEF pseudo-inverse (*paper*, unit normals).
DEFAULT_QEF_CUTOFF = 0.1
#: The paper's hit threshold: an edge is intersected when the predicted occupancy o_hat exceeds it
#: (each method names its own threshold, e.g. ``sals``' ``o_threshold``).
PAPER_HIT_THRESHOLD = 0.1
#: The face rules of :func:`edge_dual_contouring` (``'fan4'`` is the paper's).
FACE_RULES = ("fan4", "quad2", "fan4-adaptive")
#: ``'fan4-adaptive'`` keeps the fan of an edge when its edge point lies within this many grid
#: spacings h of the plane of its 4 cell vertices (the choice: docs/PROTOCOL.md, "E-DC face rules").
FAN_PLANE_TOLERANCE = 0.05

# ----------------------------------------------------------------------------------------------
# step 1 helper and step 2
# ----------------------------------------------------------------------------------------------
def intersected_edges(o_hat: np.ndarray, threshold: float = PAPER_HIT_THRESHOLD) -> np.ndarray:
    """Flat ids (int64, increasing) of the edges with predicted occupancy ``o_hat > threshold``."""
    return np.flatnonzero(np.asarray(o_hat) > threshold)


def edge_points(N: int, edge_ids: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Hit points ``p = s u + (1 - s) v = u + (1 - s) h e_axis`` of edges (K, 3) float64, canonical frame."""
    edge_ids, s, _ = _check_inputs(N, edge_ids, s, None)
    ijk, axis = edge_index_to_ijk_axis(N, edge_ids)
    return _points_from_decoded(N, ijk, axis, s)


def _points_from_decoded(N, ijk, axis, s):
    h = spacing(N)
    p = LOWER + ijk * h
    p[np.arange(len(p)), axis] += (1.0 - s) * h
    return p


# ----------------------------------------------------------------------------------------------
# step 4: batched QEF
# ----------------------------------------------------------------------------------------------
def _sym_eigvals(a00, a11, a22, a01, a02, a12):
    """Eigenvalues l1 >= l2 >= l3 of symmetric 3x3 matrices (trigonometric closed form, Smith 1961)."""
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe = p > 0
    inv_p = np.divide(1.0, p, out=np.zeros_like(p), where=safe)
    # det(B) / 2 with B = (A - q I) / p
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02))
    r = np.clip(det * inv_p**3 / 2.0, -1.0, 1.0)
    phi = np.arccos(r) / 3.0
    l1 = q + 2.0 * p * np.cos(phi)
    l3 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    l2 = 3.0 * q - l1 - l3
    return l1, l2, l3


def _matvec(m, r):
    """Symmetric 3x3 matrices (6 arrays) times vectors (3 arrays)."""
    m00, m11, m22, m01, m02, m12 = m
    return [m00 * r[0] + m01 * r[1] + m02 * r[2],
            m01 * r[0] + m11 * r[1] + m12 * r[2],
            m02 * r[0] + m12 * r[1] + m22 * r[2]]


def _shifted_matvec(m, lam, r):
    """(M - lam I) r for symmetric M (6 arrays), per-matrix shifts lam, vectors r (3 arrays)."""
    y = _matvec(m, r)
    return [y[i] - lam * r[i] for i in range(3)]


def _solve_sym(a00, a11, a22, a01, a02, a12, r0, r1, r2):
    """Solve symmetric 3x3 systems A y = r with the adjugate (A well conditioned here), as 3 arrays."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    inv_det = 1.0 / (a00 * c00 + a01 * c01 + a02 * c02)
    return [(c00 * r0 + c01 * r1 + c02 * r2) * inv_det,
            (c01 * r0 + c11 * r1 + c12 * r2) * inv_det,
            (c02 * r0 + c12 * r1 + c22 * r2) * inv_det]


def _qef_solve_columns(m, r, cutoff):
    """:func:`qef_solve` on column arrays: m = 6 arrays (m00, m11, m22, m01, m02, m12), r = 3 arrays.

    With eigenvalues l1 >= l2 >= l3 and spectral projectors P_k (Cayley-Hamilton, no eigenvectors):
    3 kept: M^-1 r (adjugate); 2 kept: P3 r = (M - l1)(M - l2) r / ((l3 - l1)(l3 - l2)),
    s = r - P3 r, result ((l1 + l2) s - M s) / (l1 l2) (the inverse on the 2-D kept subspace);
    1 kept: P1 r / l1 = (M - l2)(M - l3) r / ((l1 - l2)(l1 - l3) l1); 0 kept: 0. Every division is
    by a gap between a kept and a dropped eigenvalue (>= cutoff - l_dropped > 0) or by kept ones.
    """
    l1, l2, l3 = _sym_eigvals(*m)
    kept = (l1 >= cutoff).view(np.int8) + (l2 >= cutoff).view(np.int8) + (l3 >= cutoff).view(np.int8)
    out = [np.zeros_like(r[0]) for _ in range(3)]

    def scatter(sel, y):
        for i in range(3):
            out[i][sel] = y[i]

    sel = np.flatnonzero(kept == 3)
    if len(sel):
        scatter(sel, _solve_sym(*(x[sel] for x in m), *(x[sel] for x in r)))

    sel = np.flatnonzero(kept == 2)
    if len(sel):
        ms = [x[sel] for x in m]
        rs = [x[sel] for x in r]
        a, b, c = l1[sel], l2[sel], l3[sel]
        p3 = _shifted_matvec(ms, a, _shifted_matvec(ms, b, rs))
        inv = 1.0 / ((c - a) * (c - b))
        s_ = [rs[i] - p3[i] * inv for i in range(3)]
        ms_ = _matvec(ms, s_)
        inv_ab = 1.0 / (a * b)
        scatter(sel, [((a + b) * s_[i] - ms_[i]) * inv_ab for i in range(3)])

    sel = np.flatnonzero(kept == 1)
    if len(sel):
        ms = [x[sel] for x in m]
        rs = [x[sel] for x in r]
        a, b, c = l1[sel], l2[sel], l3[sel]
        y = _shifted_matvec(ms, b, _shifted_matvec(ms, c, rs))
        inv = 1.0 / ((a - b) * (a - c) * a)
        scatter(sel, [y[i] * inv for i in range(3)])
    return out


def qef_solve(ata: np.ndarray, rhs: np.ndarray, cutoff: float = DEFAULT_QEF_CUTOFF) -> np.ndarray:
    """Truncated pseudo-inverse solve ``pinv(M) r`` for symmetric 3x3 matrices, batched.

    Parameters
    ----------
    ata : (K, 6) the symmetric matrices M = A^T A as (m00, m11, m22, m01, m02, m12).
    rhs : (K, 3) the right-hand sides r = A^T b - A^T A c.
    cutoff : eigenvalues of M below this are dropped (their directions get 0).

    Returns ``sum over eigenpairs (l_k >= cutoff) of (v_k . r) / l_k v_k``, (K, 3) float64, in closed
    form by the number of kept eigenvalues (eigenvalues by the trigonometric formula, spectral
    projectors by Cayley-Hamilton, see ``_qef_solve_columns``): the same as ``V diag(1/l or 0) V^T r``
    from ``np.linalg.eigh``, without its per-matrix LAPACK calls. A kept/dropped split always has a
    gap (l_kept >= cutoff > l_dropped), so the projectors are well defined.
    """
    ata = np.asarray(ata, dtype=np.float64)
    rhs = np.asarray(rhs, dtype=np.float64)
    out = _qef_solve_columns([np.ascontiguousarray(c) for c in ata.T],
                             [np.ascontiguousarray(c) for c in rhs.T], cutoff)
    return np.stack(out, axis=1)


def _cells_around(N: int, ijk: np.ndarray, axis: np.ndarray):
    """Flat ids (4, K) of the 4 cells around each edge in cyclic order, and whether each exists (4, K).

    Cell (i, j, k) has flat id (i M + j) M + k, M = N - 1; the cells around an edge starting at
    ``ijk`` along ``a`` are ``ijk - db e_b - dc e_c``, (b, c) = (a + 1, a + 2) mod 3, for (db, dc)
    in the cyclic ring (0, 0), (1, 0), (1, 1), (0, 1) (quadrants (+,+), (-,+), (-,-), (+,-) of the
    edge's normal plane).
    """
    M = N - 1
    rows = np.arange(len(ijk))
    b = (axis + 1) % 3
    c = (axis + 2) % 3
    stride = np.array([M * M, M, 1], dtype=np.int64)
    base = (ijk[:, 0] * M + ijk[:, 1]) * M + ijk[:, 2]
    sb, sc = stride[b], stride[c]
    flat = np.stack([base, base - sb, base - sb - sc, base - sc])
    ib = ijk[rows, b]
    ic = ijk[rows, c]
    b0, b1 = ib < M, ib >= 1  # ring offset 0 needs index <= M - 1, offset 1 needs index >= 1
    c0, c1 = ic < M, ic >= 1
    valid = np.stack([b0 & c0, b1 & c0, b1 & c1, b0 & c1])
    return flat, valid


def _check_inputs(N, edge_ids, s, normals):
    if not isinstance(N, (int, np.integer)) or N < 2:
        raise ValueError(f"grid resolution N must be an integer >= 2, got {N!r}")
    edge_ids = np.asarray(edge_ids)
    if edge_ids.ndim != 1 or (len(edge_ids) and not np.issubdtype(edge_ids.dtype, np.integer)):
        raise ValueError(f"edge_ids must be a 1-D integer array, got shape {edge_ids.shape} dtype {edge_ids.dtype}")
    edge_ids = edge_ids.astype(np.int64, copy=False)
    K = len(edge_ids)
    if K and (edge_ids.min() < 0 or edge_ids.max() >= num_edges(N)):
        raise ValueError(f"edge_ids must lie in [0, {num_edges(N)}) for N={N}, got [{edge_ids.min()}, {edge_ids.max()}]")
    if K > 1 and not (np.diff(edge_ids) > 0).all():
        if len(np.unique(edge_ids)) != K:
            raise ValueError(f"edge_ids has {K - len(np.unique(edge_ids))} duplicate edges")
    s = np.asarray(s, dtype=np.float64).reshape(-1)
    if s.shape != (K,):
        raise ValueError(f"s must have one value per edge ({K},), got {s.shape}")
    if not np.isfinite(s).all():
        raise ValueError(f"s has {int((~np.isfinite(s)).sum())} non-finite values")
    if K and (s.min() < -1e-6 or s.max() > 1 + 1e-6):
        raise ValueError(f"s must lie in [0, 1], got [{s.min():.6g}, {s.max():.6g}]")
    s = np.clip(s, 0.0, 1.0)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != (K, 3):
            raise ValueError(f"normals must have shape ({K}, 3), got {normals.shape}")
        if not np.isfinite(normals).all():
            raise ValueError(f"normals have {int((~np.isfinite(normals)).any(axis=1).sum())} non-finite rows")
    return edge_ids, s, normals


class _Decoded:
    """Per-edge geometry shared by the vertex and face stages."""

    def __init__(self, N, edge_ids, s):
        self.N = N
        self.ijk, self.axis = edge_index_to_ijk_axis(N, edge_ids)
        self.points = _points_from_decoded(N, self.ijk, self.axis, s)


def _cell_vertices(dec: _Decoded, normals, qef_cutoff, clamp_to_cell):
    """Step 4 on decoded edges.

    Returns (cells (C,) increasing flat ids, vertices (C, 3), rows (4, K) int: vertex row of each
    of the 4 cells around each edge, C where that cell does not exist).
    """
    N = dec.N
    M = N - 1
    cell4, valid4 = _cells_around(N, dec.ijk, dec.axis)  # (4, K)
    all_valid = bool(valid4.all())
    if not all_valid:
        cell4 = np.where(valid4, cell4, 0)
    # compact the touched cells through a dense marker (cheaper than a sort)
    present = np.zeros(M**3, dtype=bool)
    present[cell4[valid4] if not all_valid else cell4.ravel()] = True
    cells = np.flatnonzero(present)
    C = len(cells)
    row_of_cell = np.empty(M**3, dtype=np.intp)
    row_of_cell[cells] = np.arange(C)
    rows = row_of_cell[cell4]
    if not all_valid:
        rows[~valid4] = C  # a discard bin
    rows_flat = rows.ravel()

    def cell_sum(w):  # sum of a per-edge quantity over the edges of each cell: (C,)
        return np.bincount(rows_flat, weights=np.tile(w, 4), minlength=C + 1)[:C]

    px, py, pz = (np.ascontiguousarray(dec.points[:, a]) for a in range(3))
    count = np.bincount(rows_flat, minlength=C + 1)[:C].astype(np.float64)
    inv_count = 1.0 / count
    cx, cy, cz = cell_sum(px) * inv_count, cell_sum(py) * inv_count, cell_sum(pz) * inv_count
    if normals is None:
        vx, vy, vz = cx, cy, cz
    else:
        nx, ny, nz = (np.ascontiguousarray(normals[:, a]) for a in range(3))
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        inv_len = 1.0 / np.where(length > 0, length, 1.0)  # zero rows stay zero: no constraint
        nx, ny, nz = nx * inv_len, ny * inv_len, nz * inv_len
        nb = nx * px + ny * py + nz * pz  # b_i = n_i . p_i
        m = [cell_sum(nx * nx), cell_sum(ny * ny), cell_sum(nz * nz),
             cell_sum(nx * ny), cell_sum(nx * nz), cell_sum(ny * nz)]
        m00, m11, m22, m01, m02, m12 = m
        # r = A^T b - A^T A c
        r = [cell_sum(nx * nb) - (m00 * cx + m01 * cy + m02 * cz),
             cell_sum(ny * nb) - (m01 * cx + m11 * cy + m12 * cz),
             cell_sum(nz * nb) - (m02 * cx + m12 * cy + m22 * cz)]
        dx, dy, dz = _qef_solve_columns(m, r, qef_cutoff)
        vx, vy, vz = cx + dx, cy + dy, cz + dz
    verts = np.stack([vx, vy, vz], axis=1)
    if clamp_to_cell:
        h = spacing(N)
        lo = LOWER + np.stack(np.unravel_index(cells, (M, M, M)), axis=1) * h
        verts = np.clip(verts, lo, lo + h)
    return cells, verts, rows


def edc_cell_vertices(N: int, edge_ids: np.ndarray, s: np.ndarray, normals: np.ndarray | None = None, *,
                      qef_cutoff: float = DEFAULT_QEF_CUTOFF, clamp_to_cell: bool = False):
    """Step 4 alone: the dual vertex of every cell with an intersected edge.

    Returns ``(cells, vertices)``: flat cell ids (C,) int64 in increasing order and their vertices
    (C, 3) float64 in the canonical frame (QEF minimisers, or mass points when ``normals`` is None).
    """
    edge_ids, s, normals = _check_inputs(N, edge_ids, s, normals)
    dec = _Decoded(N, edge_ids, s)
    cells, verts, _ = _cell_vertices(dec, normals, qef_cutoff, clamp_to_cell)
    return cells, verts


def edge_dual_contouring(N: int, edge_ids: np.ndarray, s: np.ndarray, normals: np.ndarray | None = None, *,
                         qef_cutoff: float = DEFAULT_QEF_CUTOFF, clamp_to_cell: bool = False,
                         faces: str = "fan4") -> Extraction:
    """E-DC mesh from the intersected edges of the N^3 grid (steps 2, 4 and 5).

    Parameters
    ----------
    N : grid resolution (points per axis), grid of :mod:`foundation.grid`.
    edge_ids : (K,) flat ids of the intersected edges (flat edge order of foundation.grid), no duplicates.
    s : (K,) hit parameters in [0, 1]: hit point ``p = s u + (1 - s) v``, ``u`` the lower endpoint.
    normals : (K, 3) normals at the hits (normalised here, sign irrelevant), or None for the
        'no normals' ablation (every vertex is the mass point of its cell's edge points).
    qef_cutoff : eigenvalues of A^T A below this are dropped in the pseudo-inverse (0.1, *paper*).
    clamp_to_cell : clip every vertex to its cell (not in the paper; an option to report).
    faces : ``'fan4'`` (paper: edge point + 4 triangles per interior intersected edge),
        ``'quad2'`` (2 triangles over the 4 cell vertices, split along the diagonal of ring
        positions 0-2) or ``'fan4-adaptive'`` (below).

    Face rules and thin walls. Where a cell holds two sheets closer than about one cell
    (a thin wall: its edges carry normals +n and -n from both sides), the QEF has rank 1 and puts
    the cell's vertex between the sheets, so the 4 vertices around an edge are coplanar on a middle
    plane while the edge point lies on one sheet, off that plane. The ``'fan4'`` fan around it is a
    tent; neighbouring tents lean opposite ways, and NDC's sharp-edge test flags them all over the
    wall. The cause is where the fan's centre lies, not the QEF options (docs/PROTOCOL.md, "E-DC
    face rules").

    ``'fan4-adaptive'``: the fan where the edge point lies within :data:`FAN_PLANE_TOLERANCE` h of
    the plane of its 4 cell vertices (the plane through their mean, normal to the quad's vector
    area ``(q2 - q0) x (q3 - q1)``), i.e. where it adds no fold; else the 2 triangles of the quad
    split along the diagonal whose two triangles have the more parallel normals (a degenerate quad,
    zero vector area, is split too). On one flat or smooth sheet every edge keeps its fan.

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (n, 3) float64, canonical frame; cell vertices first
    (increasing cell id), then (fan4) the edge points of the interior intersected edges in input
    order (fan4-adaptive: those of its fan edges); cell vertices no face uses (cells touched only by
    boundary edges) are removed. Faces (m, 3) int64, unoriented: 4 per interior intersected edge
    (fan4) or 2 (quad2); fan4-adaptive: 4 per fan edge (input order), then 2 per split edge (input
    order). Info: ``intersected_edges`` (K). The steps are timed as the stages ``edge_points``,
    ``qef`` and ``faces`` (:mod:`foundation.timing`).
    """
    if faces not in FACE_RULES:
        raise ValueError(f"faces must be one of {', '.join(map(repr, FACE_RULES))}, got {faces!r}")
    with stage("edge_points"):
        edge_ids, s, normals = _check_inputs(N, edge_ids, s, normals)
        dec = _Decoded(N, edge_ids, s)
    info = {"intersected_edges": int(len(edge_ids))}
    if len(edge_ids) == 0:
        record("qef", 0.0)
        record("faces", 0.0)
        return Extraction(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), info)
    with stage("qef"):
        _, cell_verts, rows = _cell_vertices(dec, normals, qef_cutoff, clamp_to_cell)
    with stage("faces"):
        verts, tri = _faces(dec, cell_verts, rows, faces)
    return Extraction(verts, tri, info)


def _faces(dec: _Decoded, cell_verts: np.ndarray, rows: np.ndarray, rule: str) -> tuple[np.ndarray, np.ndarray]:
    """Step 5: (vertices, faces) of the face rule ``rule`` over the interior intersected edges,
    without the cell vertices no face uses (see :func:`edge_dual_contouring`)."""
    C = len(cell_verts)
    interior_mask = (rows < C).all(axis=0)
    all_interior = bool(interior_mask.all())
    if all_interior:
        ring = rows.T  # (Ki, 4) vertex rows; each of these cells holds this edge, so has a vertex
    else:
        interior = np.flatnonzero(interior_mask)
        ring = rows[:, interior].T
    points = dec.points if all_interior else dec.points[interior]
    if rule == "fan4":
        tri = _fan_faces(ring, C)
        verts = np.concatenate([cell_verts, points], axis=0)
    elif rule == "quad2":
        tri = _quad_faces(ring)
        verts = cell_verts
    else:
        is_fan, flip = _adaptive_split(cell_verts[ring], points, spacing(dec.N))
        fan_rows = np.flatnonzero(is_fan)
        split = ~is_fan
        split_ring = ring[split]
        split_ring = np.where(flip[split][:, None], split_ring[:, [1, 2, 3, 0]], split_ring)
        tri = np.concatenate([_fan_faces(ring[fan_rows], C), _quad_faces(split_ring)], axis=0)
        verts = np.concatenate([cell_verts, points[fan_rows]], axis=0)
    return drop_unreferenced_vertices(verts, tri)


def _fan_faces(ring: np.ndarray, first: int) -> np.ndarray:
    """4 triangles (centre, ring i, ring i+1) per row of ``ring`` (K, 4); centre k is vertex ``first + k``."""
    K = len(ring)
    tri = np.empty((K, 4, 3), dtype=np.int64)
    tri[:, :, 0] = (first + np.arange(K, dtype=np.int64))[:, None]
    tri[:, :, 1] = ring
    tri[:, :, 2] = ring[:, [1, 2, 3, 0]]
    return tri.reshape(-1, 3)


def _quad_faces(ring: np.ndarray) -> np.ndarray:
    """2 triangles (0, 1, 2), (0, 2, 3) per row of ``ring`` (K, 4): the split along diagonal 0-2."""
    tri = np.empty((len(ring), 2, 3), dtype=np.int64)
    tri[:, 0] = ring[:, [0, 1, 2]]
    tri[:, 1] = ring[:, [0, 2, 3]]
    return tri.reshape(-1, 3)


def _abs_cos(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|cos| of the angle between rows of a and b; 1 where either is zero (no crease)."""
    den = np.sqrt(np.einsum("ij,ij->i", a, a) * np.einsum("ij,ij->i", b, b))
    num = np.abs(np.einsum("ij,ij->i", a, b))
    return np.divide(num, den, out=np.ones_like(num), where=den > 0)


def _adaptive_split(quads: np.ndarray, points: np.ndarray, h: float):
    """The ``'fan4-adaptive'`` choice per edge: (is_fan (K,) bool, flip (K,) bool).

    ``quads`` (K, 4, 3): the 4 cell vertices in ring order; ``points`` (K, 3): the edge points.
    is_fan: the edge point lies within ``FAN_PLANE_TOLERANCE h`` of the plane through the mean of
    the 4 vertices with normal ``(q2 - q0) x (q3 - q1)`` (False for a zero normal). flip: split
    along diagonal 1-3 (triangles (1, 2, 3), (1, 3, 0)) rather than 0-2 (triangles (0, 1, 2),
    (0, 2, 3)), because its two triangle normals are more parallel.
    """
    q0, q1, q2, q3 = quads[:, 0], quads[:, 1], quads[:, 2], quads[:, 3]
    d02, d13 = q2 - q0, q3 - q1
    area = np.cross(d02, d13)  # twice the vector area of the (skew) quad
    length = np.sqrt(np.einsum("ij,ij->i", area, area))
    height = np.abs(np.einsum("ij,ij->i", points - quads.mean(axis=1), area))  # offset x length
    is_fan = (length > 0) & (height <= FAN_PLANE_TOLERANCE * h * length)
    cos02 = _abs_cos(np.cross(q1 - q0, d02), np.cross(d02, q3 - q0))
    cos13 = _abs_cos(np.cross(q2 - q1, d13), np.cross(d13, q0 - q1))
    return is_fan, cos13 > cos02
