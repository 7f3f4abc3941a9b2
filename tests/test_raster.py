"""Exact line-triangle rasterisation (foundation/raster.py) on hand-countable cases.

Grid N = 5: lines at -1, -0.5, 0, 0.5, 1 (h = 0.5). The square [-0.75, 0.75]^2 x {0.1} is split by
its diagonal x = y into two triangles; the 9 z-lines through it are (x, y) in {-0.5, 0, 0.5}^2,
and 3 of them run exactly through the shared diagonal.
"""

import numpy as np
import pytest
import trimesh

from foundation import raster
from foundation.raster import closed_chain_winding_number, grid_line_hits

SQUARE_V = np.array([[-0.75, -0.75, 0.1], [0.75, -0.75, 0.1], [0.75, 0.75, 0.1], [-0.75, 0.75, 0.1]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])  # both with normal +z; shared edge 0-2 on x = y


def hits_as_rows(hits):
    j, k, x, face, sign = hits
    return sorted(zip(j.tolist(), k.tolist(), x.tolist(), face.tolist(), sign.tolist()))


def test_closed_rule_hits_both_triangles_on_a_shared_edge():
    j, k, x, face, sign = grid_line_hits(SQUARE_V, SQUARE_F, 5, axis=2, rule="closed")
    assert len(x) == 6 + 2 * 3  # 6 lines inside one triangle, 3 on the diagonal hit both
    assert np.allclose(x, 0.1, rtol=0, atol=1e-15) and np.all(sign == 1)
    on_diagonal = j == k
    assert sorted(j[on_diagonal].tolist()) == [1, 1, 2, 2, 3, 3]
    assert set(face[on_diagonal & (j == 2)].tolist()) == {0, 1}
    assert set(zip(j.tolist(), k.tolist())) == {(a, b) for a in (1, 2, 3) for b in (1, 2, 3)}


def test_watertight_rule_counts_each_crossing_once():
    j, k, x, face, sign = grid_line_hits(SQUARE_V, SQUARE_F, 5, axis=2, rule="watertight")
    assert sorted(zip(j.tolist(), k.tolist())) == [(a, b) for a in (1, 2, 3) for b in (1, 2, 3)]
    assert np.allclose(x, 0.1, rtol=0, atol=1e-15)


def test_lines_parallel_to_a_triangle_never_hit_it():
    for axis in (0, 1):  # x- and y-lines lie parallel to the plane z = 0.1
        j, k, x, face, sign = grid_line_hits(SQUARE_V, SQUARE_F, 5, axis=axis)
        assert len(x) == 0 and x.dtype == np.float64
    with pytest.raises(ValueError, match="unknown rule"):
        grid_line_hits(SQUARE_V, SQUARE_F, 5, axis=2, rule="open")


def test_normal_sign_follows_the_face_orientation_on_every_axis():
    """sign = sign(n_axis), n = (b - a) x (c - a): rotate the square so its normal is +x, -y, -z."""
    for axis, perm, flip in ((0, [2, 0, 1], False), (1, [1, 2, 0], True), (2, [0, 1, 2], True)):
        V = SQUARE_V[:, perm]
        F = SQUARE_F[:, ::-1] if flip else SQUARE_F
        n = np.cross(V[F[0, 1]] - V[F[0, 0]], V[F[0, 2]] - V[F[0, 0]])
        *_, sign = grid_line_hits(V, F, 5, axis=axis, rule="watertight")
        assert len(sign) == 9 and np.all(sign == np.sign(n[axis]))


def test_unit_cube_winding_numbers_with_rays_along_edges_and_diagonals():
    """Cube [-0.5, 0.5]^3: w = 1 inside, 0 outside. Rays (along -x) through the face diagonals
    (y = z = 0), along a cube edge (y = z = 0.5) or inside a face plane follow the tie rule
    (the ray is moved to y + eps, z + eps^2), so each is counted once or not at all."""
    box = trimesh.creation.box()
    V, F = np.asarray(box.vertices, dtype=np.float64), np.asarray(box.faces, dtype=np.int64)
    P = np.array([[0, 0, 0],       # ray through the centres (diagonals) of both x faces: crosses x = -0.5
                  [0.9, 0, 0],     # crosses both x faces: +1 - 1
                  [-0.9, 0, 0],    # no crossing at x < -0.9
                  [0.2, 0.1, -0.3],
                  [0, 0.5, 0.5],   # along the cube edge: moved outside (y > 0.5)
                  [0, -0.5, 0],    # in the face plane y = -0.5: moved inside
                  [0, 0.5, 0],     # in the face plane y = 0.5: moved outside
                  [0, 0.3, -0.5]])  # in z = -0.5: moved inside (z + eps^2)
    assert closed_chain_winding_number(V, F, P, axis=0).tolist() == [1, 0, 0, 1, 0, 1, 0, 1]
    with pytest.raises(ValueError, match=r"shape \(P, 3\)"):
        closed_chain_winding_number(V, F, np.zeros((2, 2)))


def test_every_ray_axis_gives_the_same_winding_numbers_off_the_surface():
    """Two nested spheres, the inner one reversed, and a third one beside them: w = 1 in the shell
    and in the third sphere, 0 in the hole and outside; each ray axis counts the same."""
    outer = trimesh.creation.icosphere(subdivisions=3, radius=0.6)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    inner.invert()
    beside = trimesh.creation.icosphere(subdivisions=1, radius=0.2)
    beside.apply_translation([0, 0.75, 0])
    mesh = trimesh.util.concatenate([outer, inner, beside])
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    P = np.random.default_rng(1).uniform(-1, 1, (3000, 3))
    r, rb = np.linalg.norm(P, axis=1), np.linalg.norm(P - [0, 0.75, 0], axis=1)
    clear = (np.abs(r - 0.6) > 0.03) & (np.abs(r - 0.3) > 0.03) & (np.abs(rb - 0.2) > 0.03)
    expected = ((r < 0.6) & (r > 0.3)) | (rb < 0.2)
    per_axis = [closed_chain_winding_number(V, F, P, axis=a) for a in range(3)]
    for w in per_axis:
        assert np.array_equal(w[clear], expected[clear].astype(np.int64))
        assert np.array_equal(w, per_axis[0])  # no point lies on the surface


def test_default_ray_axis_has_the_fewest_candidate_pairs():
    """A coin across x (radius 0.8, thickness 0.1): rays along x meet its two fan-triangulated caps,
    whose thin triangles' bounding boxes hold many points each; along y or z the caps project to
    segments (never hit) and the side strips are small. The default axis avoids x."""
    coin = trimesh.creation.cylinder(radius=0.8, height=0.1, sections=64,
                                     transform=trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    V, F = np.asarray(coin.vertices), np.asarray(coin.faces, dtype=np.int64)
    P = np.random.default_rng(1).uniform(-1, 1, (3000, 3))
    pairs = [raster._candidate_pairs(V, F, P, 19, a) for a in range(3)]  # 19 cells: the default for 3,000 points
    assert pairs[0] > 3 * max(pairs[1], pairs[2])
    best = int(np.argmin(pairs))
    assert best != 0
    w = closed_chain_winding_number(V, F, P)
    assert np.array_equal(w, closed_chain_winding_number(V, F, P, axis=best))
    r = np.linalg.norm(P[:, 1:], axis=1)
    clear = (r < 0.79) | (r > 0.8)  # the 64-gon lies between r = 0.799 and 0.8
    inside = (np.abs(P[:, 0]) < 0.05) & (r < 0.79)
    assert clear.sum() > 2900 and inside.sum() > 50
    assert np.array_equal(w[clear], inside[clear].astype(np.int64))


def test_results_do_not_depend_on_the_batch_size(monkeypatch):
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    P = np.random.default_rng(0).uniform(-0.9, 0.9, (500, 3))
    big = [hits_as_rows(grid_line_hits(V, F, 17, axis, rule)) for axis in range(3) for rule in ("closed", "watertight")]
    w_big = closed_chain_winding_number(V, F, P)
    monkeypatch.setattr(raster, "RASTER_BATCH", 7)  # dozens of batches
    small = [hits_as_rows(grid_line_hits(V, F, 17, axis, rule)) for axis in range(3) for rule in ("closed", "watertight")]
    assert small == big
    assert np.array_equal(closed_chain_winding_number(V, F, P), w_big)
    inside = np.linalg.norm(P, axis=1) < 0.55  # the polyhedron lies between r = 0.55 and 0.6
    assert np.all(w_big[inside] == 1) and np.all(w_big[np.linalg.norm(P, axis=1) > 0.6] == 0)
