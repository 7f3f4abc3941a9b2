"""E-DC on analytic edge fields: planes, a cube, an open sheet, crossing planes.

The edge fields are built exactly with numpy (no mesh library): an edge along axis a from u to
v = u + h e_a meets the plane n . x = c at t = (c - n . u) / (n_a h); it is a hit when 0 <= t <= 1
and the hit point lies in the plane's (optional) rectangle; each edge keeps the hit nearest its
lower endpoint (like the oracle LSF), with s = 1 - t and the plane's normal.
"""

import numpy as np
import pytest

from foundation.grid import EdgeField, edge_axes, edge_endpoints, num_edges, spacing
from foundation.timing import StageTimer, stage
from methods.extractors.edc import (
    FAN_PLANE_TOLERANCE,
    _adaptive_split,
    edc_cell_vertices,
    edge_dual_contouring,
    edge_points,
    intersected_edges,
    qef_solve,
)


def planes_edge_field(N, planes):
    """EdgeField of a set of planes. ``planes``: list of (normal (3,), offset c, bounds (3, 2) or None)."""
    u, v = edge_endpoints(N, dtype=np.float64)
    axis = edge_axes(N).astype(np.int64)
    h = spacing(N)
    E = num_edges(N)
    best_t = np.full(E, np.inf)
    normal = np.zeros((E, 3))
    for n, c, bounds in planes:  # loop over a handful of planes, vectorised over edges
        n = np.asarray(n, dtype=np.float64)
        n = n / np.linalg.norm(n)
        denom = n[axis] * h
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (c - u @ n) / denom
        ok = (denom != 0) & (t >= 0) & (t <= 1)
        if bounds is not None:
            p = u + np.nan_to_num(t)[:, None] * (v - u)
            b = np.asarray(bounds, dtype=np.float64)
            ok &= ((p >= b[:, 0] - 1e-12) & (p <= b[:, 1] + 1e-12)).all(axis=1)
        better = ok & (t < best_t)
        best_t[better] = t[better]
        normal[better] = n
    hit = np.isfinite(best_t)
    s = np.where(hit, 1.0 - best_t, 0.0)
    return EdgeField(N, hit, s.astype(np.float32), normal.astype(np.float32)), s, normal


def edc(*args, **options):
    """(vertices, faces) of :func:`edge_dual_contouring`."""
    mesh = edge_dual_contouring(*args, **options)
    return mesh.vertices, mesh.faces


def field_arrays(N, planes):
    """(ids, s float64, normals float64) of the intersected edges (float64 for exact checks)."""
    field, s, normal = planes_edge_field(N, planes)
    ids = np.flatnonzero(field.hit)
    return ids, s[ids], normal[ids]


def edge_use_counts(faces):
    """Number of faces on each undirected mesh edge."""
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def adjacent_abs_cos(v, f):
    """|cos| of the angle between the normals of every two faces that share a mesh edge (faces of
    zero area left out): below 0.2 is a crease NDC's sharp-edge test would flag (> 78.5 degrees)."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(n, axis=1)
    keep = length > 1e-14
    n = n / np.where(keep, length, 1.0)[:, None]
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    face = np.repeat(np.arange(len(f)), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, face = e[order], face[order]
    same = (e[1:] == e[:-1]).all(axis=1)
    a, b = face[:-1][same], face[1:][same]
    ok = keep[a] & keep[b]
    return np.abs(np.einsum("ij,ij->i", n[a[ok]], n[b[ok]]))


def box_faces(a):
    """The 6 faces of the cube [-a, a]^3 as bounded planes."""
    planes = []
    for ax in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[ax] = 1.0
            bounds = np.array([[-a, a]] * 3)
            bounds[ax] = [sign * a, sign * a]
            planes.append((n, sign * a, bounds))
    return planes


N = 16
H = spacing(N)


def test_edge_points_formula():
    # edge 0 starts at grid (0, 0, 0) along x: p = u + (1 - s) h e_x
    p = edge_points(N, np.array([0]), np.array([0.25]))
    assert np.allclose(p, [[-1 + 0.75 * H, -1, -1]])
    assert np.array_equal(intersected_edges(np.array([0.05, 0.2, 0.1, 0.9])), [1, 3])


def test_edge_points_match_the_grid_hit_points():
    field, _, _ = planes_edge_field(N, [((0.2, 0.3, 1.0), 0.1, None)])
    hit_ids, p_ref = field.hit_points()
    assert np.allclose(edge_points(N, hit_ids, field.s[hit_ids]), p_ref)


def test_plane_vertices_lie_on_the_plane():
    c = 0.123  # not on a grid plane
    ids, s, nrm = field_arrays(N, [((0, 0, 1), c, None)])
    assert len(ids) == N * N  # one z-edge per grid column
    with StageTimer().active() as timer, stage("extract"):
        mesh = edge_dual_contouring(N, ids, s, nrm)
    v, f = mesh.vertices, mesh.faces
    assert np.abs(v[:, 2] - c).max() < 1e-12
    assert set(timer.seconds) == {"extract_s", "extract_edge_points_s", "extract_qef_s", "extract_faces_s"}
    assert mesh.info == {"intersected_edges": len(ids)} and v.dtype == np.float64 and f.dtype == np.int64
    # fan4: 4 triangles per interior z-edge, (N - 2)^2 of them
    assert len(f) == 4 * (N - 2) ** 2
    # an open sheet with a boundary and no non-manifold edge
    counts = edge_use_counts(f)
    assert (counts == 1).sum() > 0 and counts.max() == 2


def test_cube_corners_and_edges_are_sharp_with_normals():
    a = 0.4567
    ids, s, nrm = field_arrays(N, box_faces(a))
    v, f = edc(N, ids, s, nrm)
    corners = np.array(np.meshgrid([-a, a], [-a, a], [-a, a], indexing="ij")).reshape(3, -1).T
    dist = np.linalg.norm(v[None, :, :] - corners[:, None, :], axis=-1).min(axis=1)
    assert dist.max() < 1e-6  # all 8 corners reproduced
    # every vertex lies on the cube surface; vertices with two coordinates at +-a lie on edge lines
    on_face = np.abs(np.abs(v) - a) < 1e-9
    assert on_face.any(axis=1).all()
    # the 12 edge lines: the vertex of every cell that a cube edge line crosses is exactly on it
    M = N - 1
    cells, cv = edc_cell_vertices(N, ids, s, nrm)
    lo = -1 + np.stack(np.unravel_index(cells, (M, M, M)), axis=1) * H
    holds_plane = ((lo <= a) & (lo + H >= a)) | ((lo <= -a) & (lo + H >= -a))  # (C, 3)
    on_edge_line = holds_plane.sum(axis=1) >= 2
    assert on_edge_line.sum() >= 12 * 4
    assert (np.abs(np.abs(cv[on_edge_line]) - a) < 1e-9).sum(axis=1).min() >= 2
    # closed surface: every mesh edge used by exactly two faces
    assert (edge_use_counts(f) == 2).all()


def test_cube_without_normals_cuts_corners():
    a = 0.4567
    ids, s, _ = field_arrays(N, box_faces(a))
    v, f = edc(N, ids, s, None)
    corners = np.array(np.meshgrid([-a, a], [-a, a], [-a, a], indexing="ij")).reshape(3, -1).T
    dist = np.linalg.norm(v[None, :, :] - corners[:, None, :], axis=-1).min(axis=1)
    assert dist.min() > 0.05 * H  # mass points cannot reach the corners


def test_open_square_sheet_stays_open():
    b = 0.5321
    bounds = np.array([[-b, b], [-b, b], [0.0123, 0.0123]])
    ids, s, nrm = field_arrays(N, [((0, 0, 1), 0.0123, bounds)])
    v, f = edc(N, ids, s, nrm)
    counts = edge_use_counts(f)
    assert (counts == 1).sum() > 0  # a boundary loop
    assert counts.max() == 2  # manifold
    assert np.abs(v[:, 2] - 0.0123).max() < 1e-12
    # the sheet does not grow past its border by more than one cell
    assert np.abs(v[:, :2]).max() <= b + H


def test_crossing_planes_give_non_manifold_crossing_line():
    c1, c2 = 0.0711, -0.1234
    ids, s, nrm = field_arrays(N, [((1, 0, 0), c1, None), ((0, 1, 0), c2, None)])
    v, f = edc(N, ids, s, nrm)
    counts = edge_use_counts(f)
    assert (counts > 2).sum() >= N - 3  # non-manifold edges all along the crossing line
    # vertices of the cells on the crossing line are exactly on it
    on_line = (np.abs(v[:, 0] - c1) < 1e-12) & (np.abs(v[:, 1] - c2) < 1e-12)
    assert on_line.sum() == N - 1  # one per cell of the column that holds the line
    # every vertex lies on one of the two planes
    assert ((np.abs(v[:, 0] - c1) < 1e-12) | (np.abs(v[:, 1] - c2) < 1e-12)).all()


def test_quad2_vs_fan4_counts():
    a = 0.4567
    ids, s, nrm = field_arrays(N, box_faces(a))
    v4, f4 = edc(N, ids, s, nrm, faces="fan4")
    v2, f2 = edc(N, ids, s, nrm, faces="quad2")
    # the cube lies inside the grid: every intersected edge is interior
    K = len(ids)
    assert len(f4) == 4 * K and len(f2) == 2 * K
    assert len(v4) == len(v2) + K
    assert np.allclose(v4[: len(v2)], v2)


def test_fan4_adaptive_is_fan4_on_a_plane():
    # one tilted plane: QEF vertices and edge points all lie on it, so every edge keeps its fan
    n = np.array([0.2, 0.3, 1.0]) / np.linalg.norm([0.2, 0.3, 1.0])
    ids, s, nrm = field_arrays(N, [(n, 0.1, None)])
    v4, f4 = edc(N, ids, s, nrm, faces="fan4")
    va, fa = edc(N, ids, s, nrm, faces="fan4-adaptive")
    assert np.array_equal(fa, f4) and np.array_equal(va, v4)
    assert np.abs(va @ n - 0.1).max() < 1e-12
    assert adjacent_abs_cos(va, fa).min() > 1 - 1e-9  # coplanar faces


def test_fan4_adaptive_removes_thin_wall_creases():
    # a tilted wall 0.5 h thick: cells holding both sheets get a rank-1 QEF vertex between them,
    # the edge point lies on a sheet, and the paper's fan folds
    n = np.array([0.8, 0.41, 0.43]) / np.linalg.norm([0.8, 0.41, 0.43])
    c0, c1 = 0.0123, 0.0123 + 0.5 * H
    ids, s, nrm = field_arrays(N, [(n, c0, None), (n, c1, None)])
    v4, f4 = edc(N, ids, s, nrm, faces="fan4")
    va, fa = edc(N, ids, s, nrm, faces="fan4-adaptive")
    assert (adjacent_abs_cos(v4, f4) < 0.2).sum() > 50  # fan4: creases > 78.5 degrees in a flat wall
    assert adjacent_abs_cos(va, fa).min() >= 0.2  # fan4-adaptive: none
    assert ((va @ n >= c0 - 1e-12) & (va @ n <= c1 + 1e-12)).all()  # every vertex inside the wall
    assert len(f4) > len(fa) > len(f4) // 2  # some edges keep their fan, some are split
    # the same ring edges: the same boundary and non-manifold edges
    c4, ca = edge_use_counts(f4), edge_use_counts(fa)
    assert (ca == 1).sum() == (c4 == 1).sum() and (ca > 2).sum() == (c4 > 2).sum() > 0


def test_fan4_adaptive_keeps_open_and_non_manifold_surfaces():
    b = 0.5321
    bounds = np.array([[-b, b], [-b, b], [0.0123, 0.0123]])
    ids, s, nrm = field_arrays(N, [((0, 0, 1), 0.0123, bounds)])
    v4, f4 = edc(N, ids, s, nrm, faces="fan4")
    va, fa = edc(N, ids, s, nrm, faces="fan4-adaptive")
    assert np.array_equal(fa, f4) and np.array_equal(va, v4)  # the open square: all fans
    # 8 x 8 intersected z-edges (grid coordinates -1 + k h, k = 4..11, within b): an 8 x 8 grid of
    # quads whose boundary loop has 4 x 8 edges
    side = int((np.abs(-1 + np.arange(N) * H) <= b).sum())
    assert side == 8 and len(fa) == 4 * side * side
    counts = edge_use_counts(fa)
    assert (counts == 1).sum() == 4 * side and counts.max() == 2
    c1, c2 = 0.0711, -0.1234
    ids, s, nrm = field_arrays(N, [((1, 0, 0), c1, None), ((0, 1, 0), c2, None)])
    v4, f4 = edc(N, ids, s, nrm, faces="fan4")
    va, fa = edc(N, ids, s, nrm, faces="fan4-adaptive")
    c4, ca = edge_use_counts(f4), edge_use_counts(fa)
    assert (ca > 2).sum() == (c4 > 2).sum() >= N - 3  # the crossing line stays non-manifold
    assert (ca == 1).sum() == (c4 == 1).sum()
    assert ((np.abs(va[:, 0] - c1) < 1e-12) | (np.abs(va[:, 1] - c2) < 1e-12)).all()


def test_fan4_adaptive_choice_by_hand():
    # unit square in z = 0 (h = 1): the fan when the edge point is within the tolerance of its plane
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    t = FAN_PLANE_TOLERANCE
    points = np.array([[0.5, 0.5, 0.0], [0.3, 0.6, 0.9 * t], [0.5, 0.5, -1.1 * t]])
    is_fan, _ = _adaptive_split(np.repeat(square[None], 3, axis=0), points, 1.0)
    assert is_fan.tolist() == [True, True, False]
    # skew quad, corner 2 lifted: split 0-2 gives normals (0, -1, 1), (-1, 0, 1) (|cos| 1/2), split
    # 1-3 gives (-1, -1, 1), (0, 0, 1) (|cos| 1/sqrt 3): the flatter split is 1-3
    skew = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 1], [0, 1, 0]]], dtype=float)
    is_fan, flip = _adaptive_split(skew, np.array([[0.5, 0.5, 0.0]]), 1.0)
    assert flip.tolist() == [True] and is_fan.tolist() == [False]  # 0.25 off the mean plane
    # a degenerate quad (all 4 vertices at one point) is split
    is_fan, _ = _adaptive_split(np.zeros((1, 4, 3)), np.zeros((1, 3)), 1.0)
    assert is_fan.tolist() == [False]


def test_clamp_keeps_vertices_in_their_cells():
    rng = np.random.default_rng(0)
    ids, s, _ = field_arrays(N, [((0.3, 0.2, 1.0), 0.1, None)])
    s = rng.uniform(0, 1, len(ids))
    nrm = rng.normal(size=(len(ids), 3))  # inconsistent normals push QEF vertices out of cells
    M = N - 1
    cells, free = edc_cell_vertices(N, ids, s, nrm)
    cells2, clamped = edc_cell_vertices(N, ids, s, nrm, clamp_to_cell=True)
    assert np.array_equal(cells, cells2)
    lo = -1 + np.stack(np.unravel_index(cells, (M, M, M)), axis=1) * H
    outside = ((free < lo - 1e-12) | (free > lo + H + 1e-12)).any(axis=1)
    assert outside.sum() > 0
    assert ((clamped >= lo - 1e-12) & (clamped <= lo + H + 1e-12)).all()
    assert np.allclose(clamped[~outside], free[~outside])


def test_qef_solve_matches_numpy_pinv():
    rng = np.random.default_rng(1)
    n = rng.normal(size=(500, 4, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[:100, 1:] = n[:100, :1]  # rank 1
    n[100:200, 2:] = n[100:200, 1:2]  # rank 2
    n[200:250, 1:] = n[200:250, :1] + 1e-3 * rng.normal(size=(50, 3, 3))  # near rank 1
    A = np.einsum("kni,knj->kij", n, n)
    r = rng.normal(size=(500, 3))
    w, V = np.linalg.eigh(A)
    inv = np.where(w >= 0.1, 1.0 / np.where(w >= 0.1, w, 1.0), 0.0)
    expected = np.einsum("kij,kj,klj,kl->ki", V, inv, V, r)
    packed = A[:, [0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]
    assert np.allclose(qef_solve(packed, r, 0.1), expected, atol=1e-8)


def test_float32_edge_field_and_empty_and_errors():
    field, _, _ = planes_edge_field(N, [((0, 0, 1), 0.123, None)])
    ids = np.flatnonzero(field.hit)
    v, f = edc(N, ids, field.s[ids], field.normal[ids])
    assert np.abs(v[:, 2] - 0.123).max() < 1e-6  # float32 storage
    v0, f0 = edc(N, ids, field.s[ids], None)
    assert len(f0) == len(f)
    with StageTimer().active() as timer, stage("extract"):
        empty = edge_dual_contouring(N, np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 3)))
    assert empty.vertices.shape == (0, 3) and empty.faces.shape == (0, 3) and empty.info == {"intersected_edges": 0}
    assert timer.seconds["extract_qef_s"] == timer.seconds["extract_faces_s"] == 0.0
    with pytest.raises(ValueError, match="edge_ids"):
        edge_dual_contouring(N, np.array([num_edges(N)]), np.array([0.5]))
    with pytest.raises(ValueError, match="duplicate"):
        edge_dual_contouring(N, np.array([5, 3, 5]), np.array([0.5, 0.5, 0.5]))
    with pytest.raises(ValueError, match="s must"):
        edge_dual_contouring(N, np.array([3]), np.array([1.5]))
    with pytest.raises(ValueError, match="normals"):
        edge_dual_contouring(N, np.array([3]), np.array([0.5]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="faces"):
        edge_dual_contouring(N, np.array([3]), np.array([0.5]), faces="hex")
