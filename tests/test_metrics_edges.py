"""Sharp-edge points (foundation.metrics.edges): exact against brute force, the twelve edges of a
cube, none on a sphere, dense samples of few normals decided exactly, and the refusal of searches
that would take minutes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.distance import cdist

from foundation import metrics as M
from foundation.surface import sample_surface
from tests.test_metrics import box, sphere


def brute_force_edge_points(points, normals, radius, dot_threshold=0.2):
    close = cdist(points, points) <= radius
    perpendicular = np.abs(normals @ normals.T) < dot_threshold
    return np.any(close & perpendicular, axis=1)


@pytest.mark.parametrize("case", ["random", "two_planes", "noisy_plane"])
def test_sharp_edge_points_equal_brute_force(case):
    rng = np.random.default_rng(7)
    n = 2000
    if case == "random":
        points = rng.random((n, 3))
        normals = rng.normal(size=(n, 3))
    elif case == "two_planes":  # an L: z = 0 (normal z) and x = 0 (normal x), both [0, 1]^2
        u = rng.random((n, 2))
        half = n // 2
        points = np.c_[u[:, 0], u[:, 1], np.zeros(n)]
        points[half:] = np.c_[np.zeros(n - half), u[half:, 1], u[half:, 0]]
        normals = np.tile([0.0, 0.0, 1.0], (n, 1))
        normals[half:] = [1.0, 0.0, 0.0]
    else:  # a plane with normals tilted by up to ~50 degrees: the cell filter cannot clear much
        points = np.c_[rng.random((n, 2)), np.zeros(n)]
        normals = np.c_[rng.normal(scale=0.6, size=(n, 2)), np.ones(n)]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for radius in (0.02, 0.05, 0.15):
        expected = brute_force_edge_points(points, normals, radius)
        assert np.array_equal(M.sharp_edge_points(points, normals, radius), expected)
    if case == "two_planes":  # exactly the points within r of the shared line x = z = 0
        got = M.sharp_edge_points(points, normals, 0.05)
        assert got.sum() > 0 and np.all(points[got][:, [0, 2]].max(axis=1) <= 0.05)


def test_edge_points_find_the_twelve_edges_of_a_cube():
    """Cube [-1, 1]^3: D = 2 sqrt 3, r = 0.004 D. A sample p on face x = 1 is an edge point only via
    a sample q within r on an adjacent face y = +-1 or z = +-1 (opposite faces are 2 away; equal
    normals have |dot| = 1); then 1 - |p_y| <= |p - q| <= r, so p lies within r of a cube edge."""
    v, f = box(2.0)
    r = M.evaluate(v, f, v, f, n_points=200_000, seed=0)
    radius = r["edge_radius"]
    assert radius == pytest.approx(0.004 * 2 * math.sqrt(3))
    points, normals = sample_surface(v, f, 200_000, np.random.default_rng(0))
    edge = M.sharp_edge_points(points, normals, radius)
    p = points[edge]
    # distance of a surface point to the nearest cube edge: among its two coordinates that are
    # not +-1 (the face's own axis), the smaller gap 1 - |x_i|
    gaps = np.sort(1 - np.abs(p), axis=1)  # gaps[:, 0] = 0 (own face), gaps[:, 1] = edge distance
    assert np.all(gaps[:, 0] < 1e-12) and np.all(gaps[:, 1] <= radius + 1e-12)
    # every edge covered: each of the 12 edges, cut in 10 pieces, holds edge points in every piece
    axis_along = np.argmax(1 - np.abs(p), axis=1)  # the coordinate that runs along the edge
    covered = set()
    for along in range(3):
        sel = p[axis_along == along]
        others = [a for a in range(3) if a != along]
        signs = np.sign(sel[:, others]).astype(int)
        piece = np.minimum(((sel[:, along] + 1) / 2 * 10).astype(int), 9)
        covered |= {(along, s0, s1, k) for (s0, s1), k in zip(map(tuple, signs), piece)}
    assert len(covered) == 12 * 10
    assert r["gt_edge_points"] > 1000 and r["ef1"] > 0.9


def test_no_edge_points_on_a_sphere_and_gt_without_edges_gives_ecd_0_ef1_1():
    v, f = sphere()
    points, normals = sample_surface(v, f, 100_000, np.random.default_rng(0))
    assert not M.sharp_edge_points(points, normals, 0.004 * 1.8 * math.sqrt(3)).any()
    cube_v, cube_f = box(1.6)
    r = M.evaluate(v, f, cube_v, cube_f, n_points=50_000)  # GT sphere, prediction with edges
    assert r["gt_edge_points"] == 0 and r["pred_edge_points"] > 0
    assert r["ecd"] == 0.0 and r["ef1"] == 1.0 and r["ecd_flag"] is False


def test_dense_samples_of_few_normals_are_decided_exactly():
    """Samples far denser than the radius with few distinct normals are decided per normal group:
    the same mask as brute force past the pair limit. A cube 100x smaller than r: every sample has
    a perpendicular face within r (all edge points). A regular octahedron: adjacent and opposite
    faces meet at |n.n| = 1/3 >= 0.2, so none. Zero normals pair with any other sample, not themselves."""
    rng = np.random.default_rng(3)
    v, f = box(2.0)
    points, normals = sample_surface(v * 1e-3, f, 3000, rng)
    got = M.sharp_edge_points(points, normals, 0.2, max_pairs=10)
    assert got.all() and np.array_equal(got, brute_force_edge_points(points, normals, 0.2))
    octahedron_v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    octahedron_f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    points, normals = sample_surface(octahedron_v * 1e-3, octahedron_f, 3000, rng)
    assert len(np.unique(np.abs(normals @ normals.T).round(9))) == 2  # 1/3 and 1
    assert not M.sharp_edge_points(points, normals, 0.2, max_pairs=10).any()
    coarse = trimesh.creation.icosphere(subdivisions=2)  # 320 faces, normals all distinct: groups in general
    points, normals = sample_surface(np.asarray(coarse.vertices), np.asarray(coarse.faces), 4000, rng)
    for radius in (0.05, 0.3):
        got = M.sharp_edge_points(points, normals, radius, max_pairs=10)
        assert np.array_equal(got, brute_force_edge_points(points, normals, radius))
        assert np.array_equal(got, M.sharp_edge_points(points, normals, radius))
    points = rng.random((500, 3)) * 1e-3
    normals = np.zeros((500, 3))
    normals[:250] = [0.0, 0.0, 1.0]
    points[-1] = [5.0, 5.0, 5.0]  # a zero-normal sample with no other sample within r
    got = M.sharp_edge_points(points, normals, 0.01, max_pairs=10)
    assert np.array_equal(got, M.sharp_edge_points(points, normals, 0.01))
    assert got[:-1].all() and not got[-1]


def test_edge_points_of_a_tiny_prediction_give_its_ef1():
    """A cube 1000x smaller than its GT cube: every sample is an edge point, decided exactly (its
    search bound ~1e10 pairs passes the default limit); EF1 is a number, near 0 (all far from the GT's
    edges)."""
    v, f = box(2.0)
    r = M.evaluate(v, f, v * 1e-3, f, n_points=100_000)
    assert r["edge_search_skipped"] == "" and r["pred_edge_points"] == 100_000
    assert np.isfinite(r["ecd"]) and r["ef1"] < 0.01 and np.isfinite(r["cd"])


def test_too_dense_edge_search_of_many_normals_is_refused_not_crashed():
    """A smooth sphere 1000x smaller than the GT: all its samples lie within one edge radius and its
    normals take as many values as there are samples, so the exact search would test n^2 pairs. It is
    refused with a one-line reason; ECD/EF1 are NaN."""
    v, f = box(2.0)
    sv, sf = sphere()
    points, normals = sample_surface(sv * 1e-3, sf, 20_000, np.random.default_rng(0))
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)  # a smooth surface's normals
    with pytest.raises(M.EdgeSearchTooDense, match="too dense"):
        M.sharp_edge_points(points, normals, 0.01, max_pairs=1e6)
    assert len(sf) > M.MAX_NORMAL_GROUPS  # as a mesh: more face orientations than are decided by groups
    r = M.evaluate(v, f, sv * 1e-3, sf, n_points=100_000)  # bound ~1e10 > the 1e9 default
    assert r["edge_search_skipped"].startswith("prediction edge-point search too dense")
    assert r["pred_edge_points"] == -1 and math.isnan(r["ecd"]) and math.isnan(r["ef1"]) and np.isfinite(r["cd"])
