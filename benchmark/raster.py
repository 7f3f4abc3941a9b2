"""Exact line-triangle rasterisation: every grid line (or -x ray) against every triangle, in float64.

The core of the exact grid fields of :mod:`benchmark.fields`: instead of one ray per grid edge, each triangle is projected
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

Work is split into batches of about :data:`RASTER_BATCH` (triangle, line) pairs to bound memory.
"""

from __future__ import annotations

import numpy as np

from benchmark.grid import axis_coords, spacing

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


def closed_chain_winding_number(vertices, faces, points, cells: int | None = None):
    """Exact integer winding number of a *closed chain* at arbitrary points, by crossing counts.

    w(p) = sum over crossings of the ray p - t e_x (t > 0) of -sign(n_x), with the watertight tie rule
    of :func:`grid_line_hits`. Rays and triangles are joined through a cells x cells bucket grid on
    the (y, z) bounding square (default cells = clip(sqrt(P / 8), 4, 128)); each triangle is
    rasterised conservatively into the cells its projection overlaps. Only valid for closed chains
    (see :attr:`benchmark.fields.ExactFields.is_closed_chain`); points exactly on the surface get one side.
    Returns (P,) int64.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must have shape (P, 3), got {P.shape}")
    w = np.zeros(len(P), dtype=np.int64)
    if len(P) == 0:
        return w
    if cells is None:
        cells = int(np.clip(np.sqrt(len(P) / 8), 4, 128))
    V2, tri2, area2, elo, ehi, edir, orient = _triangle_projection(vertices, faces, 0)
    lo = np.minimum(V2.min(axis=0), P[:, 1:].min(axis=0))
    size = max(float(np.max(np.maximum(V2.max(axis=0), P[:, 1:].max(axis=0)) - lo)), 1e-300) * (1 + 1e-9)
    cell = size / cells
    pc = np.clip(((P[:, 1:] - lo) / cell).astype(np.int64), 0, cells - 1)
    pid = pc[:, 0] * cells + pc[:, 1]
    order = np.argsort(pid, kind="stable")
    start = np.searchsorted(pid[order], np.arange(cells * cells + 1))
    per_cell = np.diff(start)
    cmin = np.clip(((tri2.min(axis=1) - lo) / cell).astype(np.int64), 0, cells - 1)
    cmax = np.clip(((tri2.max(axis=1) - lo) / cell).astype(np.int64), 0, cells - 1)
    nc = cmax[:, 1] - cmin[:, 1] + 1
    count = np.where(area2 != 0, (cmax[:, 0] - cmin[:, 0] + 1) * nc, 0)
    live = np.flatnonzero(count)
    if len(live) == 0:
        return w
    # oriented 2D edge lines n . q + c >= 0 inside (for the conservative cell cover only)
    t0, t1, t2 = tri2[:, 0], tri2[:, 1], tri2[:, 2]
    edge_n = np.stack([np.stack([-(b - a)[:, 1], (b - a)[:, 0]], axis=1) for a, b in ((t0, t1), (t1, t2), (t2, t0))],
                      axis=1) * orient[:, None, None]  # (m, 3, 2)
    edge_c = -np.einsum("mij,mij->mi", edge_n, np.stack([t0, t1, t2], axis=1))
    bounds = _batch_bounds(count[live])
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b <= a:
            continue
        fl = live[a:b]
        cnt = count[fl]
        rep = np.repeat(fl, cnt)
        local = np.arange(len(rep)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        ci, cj = cmin[rep, 0] + local // nc[rep], cmin[rep, 1] + local % nc[rep]
        cid = ci * cells + cj
        keep = per_cell[cid] > 0
        rep, ci, cj, cid = rep[keep], ci[keep], cj[keep], cid[keep]
        # drop cells entirely outside one edge line (max of the linear edge function over the square)
        n = edge_n[rep]  # (K, 3, 2)
        corner = lo + cell * np.stack([ci, cj], axis=1)[:, None, :] + cell * (n > 0)  # maximising corner
        slack = 1e-9 * cell * np.abs(n).sum(axis=2)
        keep = ((n * corner).sum(axis=2) + edge_c[rep] >= -slack).all(axis=1)
        rep, cid = rep[keep], cid[keep]
        npair = per_cell[cid]
        sub = _batch_bounds(npair)
        for s0, s1 in zip(sub[:-1], sub[1:]):
            if s1 <= s0:
                continue
            c = npair[s0:s1]
            f = np.repeat(rep[s0:s1], c)
            k = np.arange(len(f)) - np.repeat(np.cumsum(c) - c, c)
            pts = order[start[np.repeat(cid[s0:s1], c)] + k]
            ok, x = _line_triangle_test(vertices, faces, V2, f, P[pts, 1:], 0, "watertight", elo, ehi, edir, orient)
            ok &= x < P[pts, 0]
            np.add.at(w, pts[ok], -orient[f[ok]])  # n_x = area2 of the (y, z) projection
    return w


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
