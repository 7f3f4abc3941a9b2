"""Euler characteristic, genus (foundation.metrics.validity) and self-intersecting face pairs
(foundation.metrics.self_intersections) of meshes whose counts are worked out by hand."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import trimesh

from foundation import metrics as M
from tests.test_metrics import box

SI = importlib.import_module("foundation.metrics.self_intersections")  # the module (the package's name is the function)


def hand_cube(origin=(0.0, 0.0, 0.0)):
    """The unit cube [0, 1]^3 + origin, corner (x, y, z) in {0, 1}^3 at index x + 2y + 4z, every
    square split along the diagonal from its (min, min) to its (max, max) corner in its two in-plane
    axes (u < v): triangles (00, 10, 11) and (00, 11, 01); outward orientation."""
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float) + origin
    faces = []
    for k in range(3):
        u, v = [a for a in range(3) if a != k]
        for side in (0, 1):
            def corner(a, b):
                c = [0, 0, 0]
                c[k], c[u], c[v] = side, a, b
                return c[0] + 2 * c[1] + 4 * c[2]
            tris = [[corner(0, 0), corner(1, 0), corner(1, 1)], [corner(0, 0), corner(1, 1), corner(0, 1)]]
            along_k = 1 if k != 1 else -1  # e_u x e_v: +x for (y, z), -y for (x, z), +z for (x, y)
            if along_k != (1 if side else -1):
                tris = [t[::-1] for t in tris]
            faces += tris
    return corners, np.array(faces, dtype=np.int64)


def grid_torus(n: int, m: int):
    """An n x m grid on the torus, vertex (i, j) at index i * m + j, each quad (i, j)..(i+1, j+1)
    (indices mod n, m) split by its diagonal (i, j)-(i+1, j+1)."""
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    a, t = 2 * np.pi * i.ravel() / n, 2 * np.pi * j.ravel() / m
    vertices = np.stack([(2 + np.cos(t)) * np.cos(a), (2 + np.cos(t)) * np.sin(a), np.sin(t)], axis=1)
    idx = lambda p, q: (p % n) * m + (q % m)  # noqa: E731
    i, j = i.ravel(), j.ravel()
    faces = np.concatenate([np.stack([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)], axis=1),
                            np.stack([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)], axis=1)])
    return vertices, faces


# ---------------------------------------------------------------- Euler characteristic and genus


def test_euler_and_genus_of_a_closed_cube_and_of_a_cube_with_one_side_open():
    """Closed cube (12 triangles): V = 8, E = 12 sides + 6 diagonals = 18, F = 12: 8 - 18 + 12 = 2,
    one component, genus (2 * 1 - 2) / 2 = 0.

    Without one side's two triangles: the 8 corners are all still used (each lies on a side face
    that remains); of the 18 edges only the removed square's diagonal is gone (its 4 sides are
    still used by the neighbouring faces) -> E = 17; F = 10: 8 - 17 + 10 = 1 (a disc, as it
    should be: not 8 - 18 + 10 = 0). 4 boundary edges: not closed, genus NaN."""
    v, f = hand_cube()
    got = M.mesh_validity(v, f)
    assert (got["euler_characteristic"], got["genus"], got["components"], got["watertight"]) == (2, 0.0, 1, True)
    open_top = f[np.all(v[f][:, :, 2] == 1.0, axis=1)]
    assert len(open_top) == 2  # the side z = 1
    keep = ~np.all(v[f][:, :, 2] == 1.0, axis=1)
    got = M.mesh_validity(v, f[keep])
    assert (got["n_faces"], got["boundary_edges"], got["euler_characteristic"]) == (10, 4, 1)
    assert np.isnan(got["genus"])
    # trimesh's box (another triangulation of the same cube): the same numbers
    tv, tf = box(1.0)
    assert (M.mesh_validity(tv, tf)["euler_characteristic"], M.mesh_validity(tv, tf)["genus"]) == (2, 0.0)


def test_a_torus_has_euler_0_and_genus_1():
    """An n x m grid torus: V = nm; each vertex owns 3 edges (to (i+1, j), (i, j+1), (i+1, j+1)):
    E = 3nm; 2 triangles per quad: F = 2nm. 8 x 6: 48 - 144 + 96 = 0, genus (2 - 0) / 2 = 1.
    trimesh's torus (another grid) too."""
    v, f = grid_torus(8, 6)
    got = M.mesh_validity(v, f)
    assert (got["n_faces"], got["watertight"], got["components"]) == (96, True, 1)
    assert (got["euler_characteristic"], got["genus"]) == (0, 1.0)
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    got = M.mesh_validity(torus.vertices, torus.faces)
    assert (got["euler_characteristic"], got["genus"]) == (0, 1.0)


def test_two_disjoint_spheres_have_two_components_euler_4_genus_0():
    """An icosphere of subdivision 1: V = 42, E = 120, F = 80, 42 - 120 + 80 = 2. Two of them apart:
    4, components 2, genus (2 * 2 - 4) / 2 = 0 (the genera summed)."""
    s = trimesh.creation.icosphere(subdivisions=1)
    assert (len(s.vertices), len(s.edges_unique), len(s.faces)) == (42, 120, 80)
    v = np.vstack([s.vertices, s.vertices + 3.0])
    f = np.vstack([s.faces, s.faces + len(s.vertices)])
    got = M.mesh_validity(v, f)
    assert (got["components"], got["euler_characteristic"], got["genus"]) == (2, 4, 0.0)


def test_a_vertex_shared_by_two_closed_sheets_makes_the_genus_a_half():
    """Two cubes sharing one corner (one index): V = 8 + 8 - 1 = 15, E = 36, F = 24: 3; edge-manifold
    and closed, 2 (edge-connected) components: genus (4 - 3) / 2 = 1/2, as documented."""
    v, f = hand_cube()
    second = f + 7  # second cube's corner c -> index c + 7, so its corner 0 is the first's corner 7 = (1, 1, 1)
    v2 = np.vstack([v, v[1:] + 1.0])
    got = M.mesh_validity(v2, np.vstack([f, second]))
    assert (got["watertight"], got["components"], got["euler_characteristic"], got["genus"]) == (True, 2, 3, 0.5)


def test_euler_and_genus_are_nan_without_faces_and_counted_as_given_otherwise():
    got = M.mesh_validity(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert np.isnan(got["euler_characteristic"]) and np.isnan(got["genus"])
    # a soup of the closed cube (each triangle its own 3 vertices): 36 - 36 + 12 = 12, 12 components, open
    v, f = hand_cube()
    got = M.mesh_validity(v[f].reshape(-1, 3), np.arange(36).reshape(12, 3))
    assert (got["euler_characteristic"], got["components"], got["watertight"]) == (12, 12, False)
    assert np.isnan(got["genus"])


# ---------------------------------------------------------------- self-intersections


def test_a_closed_cube_a_soup_of_it_and_a_single_triangle_do_not_self_intersect():
    """Faces that meet only at shared vertices or edges do not count; the soup's neighbours share
    positions, not indices, and count as sharing them."""
    v, f = hand_cube()
    assert SI.self_intersections(v, f) == {"self_intersecting_pairs": 0, "self_intersecting_faces": 0,
                                           "self_intersections_skipped": ""}
    soup = SI.self_intersections(v[f].reshape(-1, 3), np.arange(36).reshape(12, 3))
    assert (soup["self_intersecting_pairs"], soup["self_intersecting_faces"]) == (0, 0)
    one = SI.self_intersections(v, f[:1])
    assert (one["self_intersecting_pairs"], one["self_intersecting_faces"]) == (0, 0)


def test_two_unit_cubes_shifted_by_half_a_side_make_18_pairs_of_12_faces():
    """A = [0, 1]^3 and B = A + (0.5, 0.5, 0.5), both :func:`hand_cube` (one soup, no shared vertex).

    The surfaces cross where a max side of A (x = 1, y = 1, z = 1) meets a min side of B of another
    axis (x = 0.5, ...): 3 x 2 = 6 pairs of squares, all alike under a permutation of the axes
    (the diagonals are permuted into diagonals). Take A's side x = 1 and B's side y = 0.5: they meet
    on the segment x = 1, y = 0.5, z in [0.5, 1]. On A's square (coordinates y, z in [0, 1]) the
    diagonal z = y cuts it at z = 0.5: A's lower triangle (z <= y) holds only its end z = 0.5,
    its upper one (z >= y) all of it. On B's square (x, z in [0.5, 1.5]) the diagonal z = x cuts
    the line x = 1 at z = 1: B's lower triangle (z <= x) holds all of it, its upper one only z = 1.
    Pairs: lower-A x lower-B meet at the point (1, 0.5, 0.5), upper-A x lower-B along the segment,
    upper-A x upper-B at the point (1, 0.5, 1), lower-A x upper-B not at all: 3 pairs (touching
    at a point counts: exact predicates). 6 x 3 = 18 pairs; every triangle of the 3 + 3 squares is
    in one: 12 faces. A cube alone: 0."""
    a_v, a_f = hand_cube()
    b_v, b_f = hand_cube((0.5, 0.5, 0.5))
    got = SI.self_intersections(np.vstack([a_v, b_v]), np.vstack([a_f, b_f + 8]))
    counts = (got["self_intersecting_pairs"], got["self_intersecting_faces"], got["self_intersections_skipped"])
    assert counts == (18, 12, "")


def test_a_plane_through_a_cube_crosses_its_8_side_triangles():
    """The unit cube and one large triangle in the plane z = 0.5 covering the cube's cross-section
    ((-1, -1), (4, -1), (-1, 4): x + y <= 3 holds at (1, 1)): the plane crosses the 4 vertical
    sides along their mid-line, which each side's diagonal cuts at its centre, so both triangles
    of each side hold a piece of it: 8 pairs; faces: those 8 and the large triangle, 9. The top
    and bottom sides are not reached."""
    v, f = hand_cube()
    sheet = np.array([[-1, -1, 0.5], [4, -1, 0.5], [-1, 4, 0.5]])
    got = SI.self_intersections(np.vstack([v, sheet]), np.vstack([f, [[8, 9, 10]]]))
    assert (got["self_intersecting_pairs"], got["self_intersecting_faces"]) == (8, 9)


def test_a_fold_over_across_a_shared_edge_counts_and_a_fan_does_not():
    """Triangles (0, 1, 2) and (1, 0, 3) share the edge (0, 1). With vertex 3 at (0.25, 0.25, 0),
    inside the first triangle, the second folds back over it (coplanar overlap): 1 pair, 2 faces
    (pymeshlab's per-face test skips pairs with a common vertex and would report 0). With vertex 3
    at (0.5, -1, 0), across the edge: a flat fan, 0."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 0]], dtype=float)
    f = np.array([[0, 1, 2], [1, 0, 3]])
    got = SI.self_intersections(v, f)
    assert (got["self_intersecting_pairs"], got["self_intersecting_faces"]) == (1, 2)
    v[3] = (0.5, -1, 0)
    got = SI.self_intersections(v, f)
    assert (got["self_intersecting_pairs"], got["self_intersecting_faces"]) == (0, 0)


def test_faces_counted_by_their_indices_as_given_and_bad_faces_left_out():
    """The fold-over of the test above at face positions 1 and 3 of a list holding an out-of-range
    face (0) and a face with a NaN vertex (2): those two are left out, the pair is found, the faces
    involved are {1, 3}; none usable: NaN; never raises."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 0], [np.nan, 0, 0]], dtype=float)
    f = np.array([[0, 1, 9], [0, 1, 2], [0, 1, 4], [1, 0, 3]])
    got = SI.self_intersections(v, f)
    assert (got["self_intersecting_pairs"], got["self_intersecting_faces"]) == (1, 2)
    none = SI.self_intersections(v, f[[0, 2]])
    assert np.isnan(none["self_intersecting_pairs"]) and np.isnan(none["self_intersecting_faces"])


def test_the_search_is_refused_with_a_reason_beyond_its_face_and_pair_limits(monkeypatch):
    """Limits lowered to the test's size: 12 faces over a limit of 11; 60 random triangles through the
    origin cross each other (~1,800 pairs) over a limit of 100 predicted pairs. NaN with the reason."""
    v, f = hand_cube()
    monkeypatch.setattr(SI, "MAX_SELF_INTERSECTION_FACES", 11)
    got = SI.self_intersections(v, f)
    assert np.isnan(got["self_intersecting_pairs"])
    assert "12 faces, over the limit of 11" in got["self_intersections_skipped"]
    monkeypatch.undo()
    spikes = np.random.default_rng(0).normal(size=(180, 3))
    spikes -= np.repeat(spikes.reshape(60, 3, 3).mean(axis=1), 3, axis=0)  # every triangle's centroid at the origin
    faces = np.arange(180).reshape(60, 3)
    full = SI.self_intersections(spikes, faces)
    assert full["self_intersecting_pairs"] > 1000 and full["self_intersections_skipped"] == ""
    monkeypatch.setattr(SI, "MAX_SELF_INTERSECTION_PAIRS", 100)
    got = SI.self_intersections(spikes, faces)
    assert np.isnan(got["self_intersecting_pairs"]) and np.isnan(got["self_intersecting_faces"])
    assert "predicted from 32 probed faces, over the limit of 100" in got["self_intersections_skipped"]


def test_evaluate_reports_topology_and_self_intersections_and_nan_for_an_empty_prediction():
    """Two overlapping cubes as the prediction: Euler 2 + 2 = 4, 2 components, closed, genus 0, 18
    pairs of 12 faces; the same in evaluate_without_gt. An empty prediction: NaN, no exception."""
    a_v, a_f = hand_cube()
    b_v, b_f = hand_cube((0.5, 0.5, 0.5))
    pv, pf = np.vstack([a_v, b_v]), np.vstack([a_f, b_f + 8])
    for r in (M.evaluate(a_v, a_f, pv, pf, n_points=2000), M.evaluate_without_gt(pv, pf)):
        assert (r["euler_characteristic"], r["components"], r["genus"]) == (4, 2, 0.0)
        counts = (r["self_intersecting_pairs"], r["self_intersecting_faces"], r["self_intersections_skipped"])
        assert counts == (18, 12, "")
    for r in (M.evaluate(a_v, a_f, np.zeros((0, 3)), np.zeros((0, 3)), n_points=500),
              M.evaluate_without_gt(np.zeros((0, 3)), np.zeros((0, 3)))):
        assert all(np.isnan(r[k]) for k in ("euler_characteristic", "genus", "self_intersecting_pairs",
                                               "self_intersecting_faces"))
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float)  # faces on a line: empty, counted as given
    r = M.evaluate(a_v, a_f, line, [[0, 1, 2]], n_points=500)
    assert r["empty_prediction"] and r["euler_characteristic"] == 3 - 3 + 1 and np.isnan(r["self_intersecting_pairs"])


@pytest.mark.parametrize("pred", [
    (np.full((3, 3), np.nan), [[0, 1, 2]]),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float), [[0, 1, 7], [0, 1, 2]]),
    (np.array([[0, 0, 0], [1e300, 0, 0], [0, 1e300, 0], [0, 0, 1e300]]), [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float), [[0, 0, 0], [0, 1, 2], [0, 1, 2]]),
])
def test_evaluate_never_raises_on_a_bad_prediction(pred):
    v, f = box(1.0)
    r = M.evaluate(v, f, *pred, n_points=500)
    assert {"euler_characteristic", "genus", "self_intersecting_pairs", "iou", "hausdorff"} <= set(r)
