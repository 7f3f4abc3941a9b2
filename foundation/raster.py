"""Exact line-triangle rasterisation: every grid line (or -x ray) against every triangle, in float64.

The core of the exact grid fields of :mod:`foundation.fields`: instead of one ray per grid edge, each triangle is projected
onto the plane across an axis and tested against the lines through the grid points inside its
projected bounding box, all (triangle, line) pairs of a batch at once.

Inputs are numpy arrays in the canonical frame: vertices float64 (n, 3), faces int64 (m, 3).

Exactness
---------
The test uses 2D edge functions ``e x (q - P0)`` of each triangle edge evaluated in a canonical
order (lower vertex id first), so a line through an edge shared by two triangles gets exactly
negated values in both: no crossing is lost or counted twice by rounding. Two rules for a line
that passes exactly through a triangle's edge or vertex:

* ``'closed'``: it hits the triangle (triangles are closed sets; the segment-field convention).
* ``'watertight'``: the line is moved by ``(+eps, +eps^2)`` in the two projected coordinates
  (symbolic perturbation), so a surface crossed through a shared edge or vertex is counted once
  (winding numbers by crossing counts).

A triangle whose projection has zero area (parallel to the line) is never hit.

The grid lines of :func:`grid_line_hits` are tested in vectorised batches of about
:data:`RASTER_BATCH` (triangle, line) pairs (to bound memory); the rays from arbitrary points of
:func:`closed_chain_winding_number` in a compiled loop (numba) over triangles, bucket cells and
points, with the same arithmetic.
"""

from __future__ import annotations

import numba
import numpy as np

from foundation.grid import axis_coords, spacing

#: Candidate (triangle, line) pairs per rasterisation batch (bounds peak memory).
RASTER_BATCH = 2_000_000


def _line_triangle_test(vertices, faces, V2, f, q, axis, rule, elo, ehi, edir, orient):
    """Test lines {q + x e_axis} (H, 2 projected coords) against triangles f (H,).

    2D edge functions in canonical order (see :func:`grid_line_hits`). Returns (ok (H,) bool, x (H,)
    coordinate along ``axis`` of the intersection, meaningful where ok).
    """
    E = np.empty((len(f), 3))
    tie_in = np.empty((len(f), 3), dtype=bool)
    for i in range(3):  # the three edges of each triangle
        P0 = V2[elo[f, i]]
        e = V2[ehi[f, i]] - P0
        canon = e[:, 0] * (q[:, 1] - P0[:, 1]) - e[:, 1] * (q[:, 0] - P0[:, 0])
        side = edir[f, i] * orient[f]  # oriented so that the interior is positive
        E[:, i] = side * canon
        # symbolic perturbation q + eps (1, delta): d canon = -e_1 (or e_0 if e_1 == 0)
        pert = np.where(e[:, 1] != 0, -np.sign(e[:, 1]), np.sign(e[:, 0]))
        tie_in[:, i] = side * pert > 0
    if rule == "closed":
        ok = (E >= 0).all(axis=1)
    else:
        ok = ((E > 0) | ((E == 0) & tie_in)).all(axis=1)
    total = E.sum(axis=1, keepdims=True)
    lam = np.divide(E, total, out=np.zeros_like(E), where=total != 0)  # lam[:, i]: vertex (i + 2) % 3
    xa = vertices[faces[f], axis]
    x = lam[:, 0] * xa[:, 2] + lam[:, 1] * xa[:, 0] + lam[:, 2] * xa[:, 1]
    return ok, x


def _triangle_projection(vertices, faces, axis):
    """Projected coords, 2D doubled areas, canonical edges (lo, hi, dir) and orientation signs."""
    b_ax, c_ax = [a for a in range(3) if a != axis]
    V2 = vertices[:, [b_ax, c_ax]]
    tri2 = V2[faces]
    area2 = ((tri2[:, 1, 0] - tri2[:, 0, 0]) * (tri2[:, 2, 1] - tri2[:, 0, 1])
             - (tri2[:, 1, 1] - tri2[:, 0, 1]) * (tri2[:, 2, 0] - tri2[:, 0, 0]))
    ea, eb = faces, np.roll(faces, -1, axis=1)  # edges (v0 v1), (v1 v2), (v2 v0)
    elo, ehi = np.minimum(ea, eb), np.maximum(ea, eb)
    edir = np.where(ea < eb, 1, -1)  # +1 if the directed edge runs lo -> hi
    return V2, tri2, area2, elo, ehi, edir, np.sign(area2).astype(np.int64)


def _batch_bounds(counts: np.ndarray) -> list[int]:
    """Split items with ``counts`` work units each into consecutive batches of ~RASTER_BATCH units:
    returns the batch boundaries (indices into ``counts``), first 0 or more, last ``len(counts)``."""
    cum = np.cumsum(counts)
    total = int(cum[-1]) if len(cum) else 0
    return list(np.searchsorted(cum, np.arange(0, total, RASTER_BATCH), side="right")) + [len(counts)]


def _bucket_grid(V2, P2, cells):
    """The cells x cells bucket grid on the bounding square of projected triangles and points:
    (lower corner (2,), cell size, each point's cell id (P,))."""
    lo = np.minimum(V2.min(axis=0), P2.min(axis=0))
    size = max(float(np.max(np.maximum(V2.max(axis=0), P2.max(axis=0)) - lo)), 1e-300) * (1 + 1e-9)
    cell = size / cells
    pc = np.clip(((P2 - lo) / cell).astype(np.int64), 0, cells - 1)
    return lo, cell, pc[:, 0] * cells + pc[:, 1]


def _triangle_cells(tri2, lo, cell, cells):
    """Per triangle, the first and last bucket cell (m, 2) of its projected bounding box."""
    cmin = np.clip(((tri2.min(axis=1) - lo) / cell).astype(np.int64), 0, cells - 1)
    cmax = np.clip(((tri2.max(axis=1) - lo) / cell).astype(np.int64), 0, cells - 1)
    return cmin, cmax


def _candidate_pairs(vertices, faces, P, cells, axis):
    """How many (triangle, point) pairs the crossing count along ``axis`` tests, before the edge-line
    cull: per triangle, the points in the bucket cells of its projected bounding box (a summed-area
    table of the points per cell)."""
    others = [a for a in range(3) if a != axis]
    V2, tri2, area2, *_ = _triangle_projection(vertices, faces, axis)
    lo, cell, pid = _bucket_grid(V2, P[:, others], cells)
    per_cell = np.bincount(pid, minlength=cells * cells).reshape(cells, cells)
    table = np.pad(per_cell.cumsum(axis=0).cumsum(axis=1), ((1, 0), (1, 0)))
    cmin, cmax = _triangle_cells(tri2, lo, cell, cells)
    cmax = cmax + 1
    pairs = (table[cmax[:, 0], cmax[:, 1]] - table[cmin[:, 0], cmax[:, 1]] - table[cmax[:, 0], cmin[:, 1]]
             + table[cmin[:, 0], cmin[:, 1]])
    return int(pairs[area2 != 0].sum())


def closed_chain_winding_number(vertices, faces, points, cells: int | None = None, axis: int | None = None):
    """Exact integer winding number of a *closed chain* at arbitrary points, by crossing counts.

    w(p) = sum over crossings of the ray p - t e_axis (t > 0) of -sign(n_axis), with the watertight
    tie rule of :func:`grid_line_hits`. Rays and triangles are joined through a cells x cells bucket
    grid on the bounding square of the plane across ``axis`` (default cells = clip(sqrt(P / 8), 4,
    128)); each triangle visits the cells its projection's bounding box overlaps (skipping a cell
    outside one of its edge lines) and is tested against the rays of the cell's points, in a
    compiled loop with the arithmetic of :func:`_line_triangle_test`. ``axis`` None (default): the
    axis with the fewest candidate (triangle, point) pairs (:func:`_candidate_pairs`); off the
    surface every axis gives the same numbers. Only valid for closed chains (see
    :attr:`foundation.fields.ExactFields.is_closed_chain`); a point exactly on the surface gets one
    side, which may depend on the axis. Returns (P,) int64.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must have shape (P, 3), got {P.shape}")
    w = np.zeros(len(P), dtype=np.int64)
    if len(P) == 0:
        return w
    if cells is None:
        cells = int(np.clip(np.sqrt(len(P) / 8), 4, 128))
    if axis is None:
        axis = int(np.argmin([_candidate_pairs(vertices, faces, P, cells, a) for a in range(3)]))
    others = [a for a in range(3) if a != axis]
    V2, tri2, area2, elo, ehi, edir, orient = _triangle_projection(vertices, faces, axis)
    live = np.flatnonzero(area2 != 0)
    if len(live) == 0:
        return w
    lo, cell, pid = _bucket_grid(V2, P[:, others], cells)
    order = np.argsort(pid, kind="stable")
    start = np.searchsorted(pid[order], np.arange(cells * cells + 1))
    cmin, cmax = _triangle_cells(tri2, lo, cell, cells)
    # oriented 2D edge lines n . q + c >= 0 inside (for the conservative cell cover only)
    t0, t1, t2 = tri2[:, 0], tri2[:, 1], tri2[:, 2]
    edge_n = np.stack([np.stack([-(b - a)[:, 1], (b - a)[:, 0]], axis=1) for a, b in ((t0, t1), (t1, t2), (t2, t0))],
                      axis=1) * orient[:, None, None]  # (m, 3, 2)
    edge_c = -np.einsum("mij,mij->mi", edge_n, np.stack([t0, t1, t2], axis=1))
    normal_sign = orient * (-1 if axis == 1 else 1)  # sign(n_axis): area2 for x, z; -area2 for y
    sorted_w = np.zeros(len(P), dtype=np.int64)
    _count_crossings(live, cmin, cmax, edge_n, np.ascontiguousarray(edge_c), lo, cell, cells, np.ascontiguousarray(V2),
                     elo, ehi, edir * orient[:, None], normal_sign, np.ascontiguousarray(vertices[faces, axis]),
                     np.ascontiguousarray(P[order][:, others]), np.ascontiguousarray(P[order, axis]), start, sorted_w)
    w[order] = sorted_w
    return w


@numba.njit(cache=True, nogil=True)
def _count_crossings(live, cmin, cmax, edge_n, edge_c, lo, cell, cells, V2, elo, ehi, side, normal_sign, face_x,
                     q, x_point, start, w):  # pragma: no cover - compiled
    """For each triangle f of ``live``, each bucket cell c its bounding box overlaps and each point
    k of the cell (rows ``start[c]:start[c + 1]`` of ``q``, the points' projections, sorted by
    cell): subtract ``normal_sign[f]`` from ``w[k]`` where the ray from the point down the axis
    crosses f. ``side`` is edir * orient; ``face_x`` the face's vertex coordinates along the axis.
    The per-pair arithmetic is :func:`_line_triangle_test`'s (rule 'watertight') in the same
    operation order, so the counts are the vectorised test's."""
    for f in live:
        for ci in range(cmin[f, 0], cmax[f, 0] + 1):
            for cj in range(cmin[f, 1], cmax[f, 1] + 1):
                cid = ci * cells + cj
                if start[cid + 1] == start[cid]:
                    continue
                outside = False  # the cell lies outside one edge line (its maximum over the square < 0)
                for i in range(3):
                    n0, n1 = edge_n[f, i, 0], edge_n[f, i, 1]
                    c0 = lo[0] + cell * ci + (cell if n0 > 0 else 0.0)
                    c1 = lo[1] + cell * cj + (cell if n1 > 0 else 0.0)
                    if n0 * c0 + n1 * c1 + edge_c[f, i] < -(1e-9 * cell * (abs(n0) + abs(n1))):
                        outside = True
                if outside:
                    continue
                # per edge: start point, direction, orientation and the tie rule (q + eps (1, eps))
                a00, a01 = V2[elo[f, 0], 0], V2[elo[f, 0], 1]
                a10, a11 = V2[elo[f, 1], 0], V2[elo[f, 1], 1]
                a20, a21 = V2[elo[f, 2], 0], V2[elo[f, 2], 1]
                e00, e01 = V2[ehi[f, 0], 0] - a00, V2[ehi[f, 0], 1] - a01
                e10, e11 = V2[ehi[f, 1], 0] - a10, V2[ehi[f, 1], 1] - a11
                e20, e21 = V2[ehi[f, 2], 0] - a20, V2[ehi[f, 2], 1] - a21
                s0, s1, s2 = side[f, 0], side[f, 1], side[f, 2]
                tie0 = s0 * (-np.sign(e01) if e01 != 0 else np.sign(e00)) > 0
                tie1 = s1 * (-np.sign(e11) if e11 != 0 else np.sign(e10)) > 0
                tie2 = s2 * (-np.sign(e21) if e21 != 0 else np.sign(e20)) > 0
                for k in range(start[cid], start[cid + 1]):
                    q0, q1 = q[k, 0], q[k, 1]
                    E0 = s0 * (e00 * (q1 - a01) - e01 * (q0 - a00))
                    if not (E0 > 0 or (E0 == 0 and tie0)):
                        continue
                    E1 = s1 * (e10 * (q1 - a11) - e11 * (q0 - a10))
                    if not (E1 > 0 or (E1 == 0 and tie1)):
                        continue
                    E2 = s2 * (e20 * (q1 - a21) - e21 * (q0 - a20))
                    if not (E2 > 0 or (E2 == 0 and tie2)):
                        continue
                    total = E0 + E1 + E2
                    x = 0.0
                    if total != 0:
                        x = E0 / total * face_x[f, 2] + E1 / total * face_x[f, 0] + E2 / total * face_x[f, 1]
                    if x < x_point[k]:
                        w[k] -= normal_sign[f]


def grid_line_hits(vertices: np.ndarray, faces: np.ndarray, N: int, axis: int, rule: str = "closed"):
    """All intersections of the N^2 grid lines along ``axis`` with the triangles (float64, exact tests).

    The line (j, k) is {x e_axis + c_j e_b + c_k e_c}, b < c the other two axes, c = axis_coords(N).
    Each triangle is projected onto the (b, c) plane and tested against the grid lines inside its
    bounding box with 2D edge functions evaluated in a canonical order (lower vertex id first), so a
    line through an edge shared by two triangles gets exactly negated values in both.

    rule 'closed': a line on a triangle's edge or vertex hits it (segment-field convention).
    rule 'watertight': a line on an edge or vertex is moved by (+eps, +eps^2) in (b, c) (symbolic
        perturbation), so each crossing of a surface through a shared edge/vertex is counted once.
    Triangles whose projection has zero area (parallel to the line) are never hit.

    Returns (j, k, x, face, sign): line indices (H,), hit coordinate along ``axis`` (H,) float64,
    face index (H,), and sign(n_axis) (H,) int64 of the face normal n = (b - a) x (c - a).
    """
    if rule not in ("closed", "watertight"):
        raise ValueError(f"unknown rule '{rule}'")
    coords = axis_coords(N)
    h = spacing(N)
    V2, tri2, area2, elo, ehi, edir, orient = _triangle_projection(vertices, faces, axis)
    lo2, hi2 = tri2.min(axis=1), tri2.max(axis=1)
    jk_min = np.clip(np.ceil((lo2 + 1.0) / h - 1e-7), 0, N - 1).astype(np.int64)
    jk_max = np.clip(np.floor((hi2 + 1.0) / h + 1e-7), 0, N - 1).astype(np.int64)
    inside_box = (hi2 >= -1.0 - 1e-12).all(axis=1) & (lo2 <= 1.0 + 1e-12).all(axis=1)
    n_b = jk_max[:, 0] - jk_min[:, 0] + 1
    n_c = jk_max[:, 1] - jk_min[:, 1] + 1
    count = np.where((area2 != 0) & inside_box & (n_b > 0) & (n_c > 0), n_b * n_c, 0)
    live = np.flatnonzero(count)
    out = [[] for _ in range(5)]
    if len(live) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, np.zeros(0), empty, empty
    normal_sign = orient * (-1 if axis == 1 else 1)  # n_axis = area2 for x, z; -area2 for y
    bounds = _batch_bounds(count[live])
    for lo_i, hi_i in zip(bounds[:-1], bounds[1:]):
        if hi_i <= lo_i:
            continue
        fl = live[lo_i:hi_i]
        cnt = count[fl]
        rep = np.repeat(np.arange(len(fl)), cnt)
        local = np.arange(len(rep)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        f = fl[rep]
        jj = jk_min[f, 0] + local // n_c[f]
        kk = jk_min[f, 1] + local % n_c[f]
        q = np.stack([coords[jj], coords[kk]], axis=1)
        ok, x = _line_triangle_test(vertices, faces, V2, f, q, axis, rule, elo, ehi, edir, orient)
        if not ok.any():
            continue
        f, jj, kk, x = f[ok], jj[ok], kk[ok], x[ok]
        for lst, val in zip(out, (jj, kk, x, f, normal_sign[f])):
            lst.append(val)
    if not out[0]:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, np.zeros(0), empty, empty
    return tuple(np.concatenate(lst) for lst in out)
