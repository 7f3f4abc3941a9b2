"""GIFS (methods/pointcloud/gifs/method.py, methods/pointcloud/gifs/network.py, methods/pointcloud/gifs/extraction.py): the extraction on exact
flags (no network), its tables and a hand-worked cube, the balanced pair draw, the weights' round
trip, determinism, and a ``tiny`` training that reconstructs a sphere.

* One cube, the plane x + y + z = h / 2 through it (corner 0 alone on one side): the flags of the 7
  pairs (0, b) are 1, the others 0; the UDFs are the plane distances. The mesh is one triangle with
  vertices at h / 2 along the three edges from corner 0.
* Sphere, radius 0.6, grid 48 (h = 0.043): exact flags (the segment crosses the sphere) and UDFs
  (| |x| - r |) on the cubes within 2 h. Every vertex lies on a grid edge at the zero of the linear
  interpolant of -d_a, +d_b, within 0.01 h of the sphere (the chord error of linear interpolation,
  about h^2 / (8 r) / h = 0.009 h at most); the cubes agree, so the mesh is closed (no boundary edge)
  and its area is within 1 % of 4 pi r^2 (the measured margins: docs/PERFORMANCE.md, section 7).
* Open square z = 0.1, |x|, |y| <= 0.5 (two triangles), grid 40: flags from ``ExactFields.segments``,
  UDFs from ``ExactFields.udf``. The vertices lie on the plane (UDF < 1e-6 h), the mesh has a
  boundary and every point of the square is within 0.5 h of it (the gap: the strips of the rim's
  cut cubes whose edges the square does not cross; measured as above).
* ``tiny`` training (200 steps) on the 4 training parts, then a sphere cloud
  (radius 0.7, 10,000 points) at grid 32 (h = 0.065): measured mean vertex radius error / CD-L1
  0.024 / 0.018 at seed 0, at most 0.039 / 0.029 over seeds 0-3; bounds 0.05 (0.77 h) and 0.035.
  After 1 step (every candidate cube meshed) 0.12 / 0.075, after 20 steps 0.025 / 0.15 (most of the
  sphere missing), after 50 steps 0.048 / 0.036: each fails a bound.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from foundation.fields import ExactFields
from foundation.grid import LOWER, spacing
from foundation.surface import sample_surface
from methods.base import get_method
from methods.pointcloud.training_set import training_shapes
import methods.pointcloud.gifs.method as gifs
from methods.pointcloud.gifs.extraction import (CORNER_PAIRS, CORNERS, CUBE_EDGE_AXES, CUBE_EDGES, PARTITIONS, corner_signs,
                                     flag_split_marching_cubes)
from methods.pointcloud.gifs.network import make_gifs_network, voxelize_cloud
from tests.learned_checks import check_training_is_deterministic, check_weights_round_trip

pytestmark = pytest.mark.usefixtures("torch_threads")

TINY = gifs.GIFS_FAMILY.budgets.get("tiny")


def _cubes_near(udf_of_points, N: int, within: float) -> np.ndarray:
    """Lower grid points of the cubes whose centre has a UDF below ``within``."""
    h = spacing(N)
    ijk = np.argwhere(np.ones((N - 1,) * 3, dtype=bool))
    return ijk[udf_of_points(LOWER + (ijk + 0.5) * h) < within]


def _corner_points(cubes: np.ndarray, N: int) -> np.ndarray:
    return LOWER + (cubes[:, None, :] + CORNERS[None]) * spacing(N)  # (C, 8, 3)


def _boundary_edges(faces: np.ndarray) -> int:
    edges = trimesh.Trimesh(np.zeros((faces.max() + 1, 3)), faces, process=False).edges_sorted
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum())


def test_tables():
    assert CORNER_PAIRS.shape == (28, 2) and len({tuple(p) for p in CORNER_PAIRS}) == 28
    assert PARTITIONS.shape == (128, 8) and np.all(PARTITIONS[:, 0] == -1) and np.all(PARTITIONS[0] == -1)
    assert len({tuple(p) for p in PARTITIONS}) == 128  # with corner 0 fixed: every partition once
    steps = CORNERS[CUBE_EDGES[:, 1]] - CORNERS[CUBE_EDGES[:, 0]]
    assert CUBE_EDGES.shape == (12, 2) and np.all(steps.sum(axis=1) == 1)
    np.testing.assert_array_equal(np.bincount(CUBE_EDGE_AXES), [4, 4, 4])


def test_one_cube_cut_off_corner_is_one_hand_worked_triangle():
    N = 11
    h = spacing(N)
    cube = np.array([[3, 4, 5]])
    flags = (CORNER_PAIRS[:, 0] == 0).astype(np.float32)[None]  # pairs (0, b): separated
    local = CORNERS.astype(float)
    udf = np.abs(local.sum(axis=1) - 0.5)[None] * h / np.sqrt(3.0)  # plane x + y + z = h / 2 (local)
    mesh = flag_split_marching_cubes(cube, flags, udf, N)
    V, F, info = mesh.vertices, mesh.faces, mesh.info
    expected = LOWER + (cube + 0.5 * np.eye(3)) * h
    assert info["surface_cubes"] == 1 and F.shape == (1, 3)
    np.testing.assert_allclose(np.sort(V, axis=0), np.sort(expected, axis=0), atol=1e-12)


def test_corner_signs_pick_the_cheapest_partition():
    rng = np.random.default_rng(0)
    sides = np.where(rng.random((50, 8)) < 0.5, -1, 1)
    consistent = (sides[:, CORNER_PAIRS[:, 0]] != sides[:, CORNER_PAIRS[:, 1]]).astype(np.float32)
    found = corner_signs(consistent)
    same = (found == sides).all(axis=1) | (found == -sides).all(axis=1)
    assert same.all()
    lone = np.zeros((1, 28), dtype=np.float32)
    lone[0, 27] = 0.6  # only pair (6, 7) > 0.5: separating it costs more than "no surface" (0.6)
    np.testing.assert_array_equal(corner_signs(lone), -np.ones((1, 8)))
    np.testing.assert_array_equal(corner_signs(np.full((1, 28), 0.4, np.float32)), -np.ones((1, 8)))


def test_extraction_on_exact_sphere_flags_is_a_closed_mesh_on_the_sphere():
    N, r = 48, 0.6
    h = spacing(N)
    cubes = _cubes_near(lambda x: np.abs(np.linalg.norm(x, axis=1) - r), N, 2 * h)
    corners = _corner_points(cubes, N)
    u, v = corners[:, CORNER_PAIRS[:, 0]], corners[:, CORNER_PAIRS[:, 1]]
    inside_u, inside_v = np.linalg.norm(u, axis=-1) < r, np.linalg.norm(v, axis=-1) < r
    d = v - u
    t = np.clip(-(u * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
    grazes = np.linalg.norm(u + t[..., None] * d, axis=-1) < r  # both outside, the segment dips in
    flags = ((inside_u != inside_v) | (~inside_u & ~inside_v & grazes)).astype(np.float32)
    udf = np.abs(np.linalg.norm(corners, axis=-1) - r)
    mesh = flag_split_marching_cubes(cubes, flags, udf, N)
    V, F = mesh.vertices, mesh.faces
    assert len(F) > 1000
    assert np.abs(np.linalg.norm(V, axis=1) - r).max() < 0.01 * h
    assert _boundary_edges(F) == 0
    area = trimesh.Trimesh(V, F, process=False).area
    assert abs(area - 4 * np.pi * r * r) < 0.01 * 4 * np.pi * r * r


def test_extraction_on_exact_open_square_flags_lies_on_the_square():
    N = 40
    h = spacing(N)
    square = ExactFields(np.array([[-0.5, -0.5, 0.1], [0.5, -0.5, 0.1], [0.5, 0.5, 0.1], [-0.5, 0.5, 0.1]]),
                         np.array([[0, 1, 2], [0, 2, 3]]))
    cubes = _cubes_near(square.udf, N, 2 * h)
    corners = _corner_points(cubes, N)
    u, v = corners[:, CORNER_PAIRS[:, 0]].reshape(-1, 3), corners[:, CORNER_PAIRS[:, 1]].reshape(-1, 3)
    hit, _, _ = square.segments(u, v)
    mesh = flag_split_marching_cubes(cubes, hit.reshape(-1, 28), square.udf(corners.reshape(-1, 3)).reshape(-1, 8), N)
    V, F = mesh.vertices, mesh.faces
    assert len(F) > 500
    assert square.udf(V).max() < 1e-6 * h
    assert _boundary_edges(F) > 0
    patch, _ = sample_surface(square.vertices, square.faces, 2000, np.random.default_rng(0))
    assert ExactFields(V, F).udf(patch).max() < 0.5 * h


def test_voxelize_marks_the_nearest_grid_point():
    grid = voxelize_cloud(np.array([[-1.0, -1.0, -1.0], [0.01, 0.0, 0.49], [5.0, 0.0, 0.0]]), 5)
    assert grid.sum() == 3 and grid[0, 0, 0] == 1 and grid[2, 2, 3] == 1 and grid[4, 2, 2] == 1
    with pytest.raises(ValueError, match="no points"):
        voxelize_cloud(np.zeros((0, 3)), 5)


def test_draw_pairs_balances_each_group():
    rng = np.random.default_rng(0)
    group = np.repeat(np.arange(5), 400)
    flag = (rng.random(2000) < 0.1).astype(np.float32)
    rows = gifs.draw_pairs(flag, group, 1000, rng)
    assert len(rows) == 1000
    for g in range(5):
        picked = rows[group[rows] == g]
        assert abs(int((flag[picked] > 0.5).sum()) - len(picked) // 2) <= 1


def _small_network(seed: int = 0):
    torch.manual_seed(seed)
    return make_gifs_network(resolution=16, channels=(4, 8), hidden=8).eval()


def test_weights_round_trip_and_bad_weights_are_refused():
    check_weights_round_trip(get_method("gifs"), _small_network(), TINY, "GIFS weights", "poco")


def test_reconstruct_is_deterministic_and_refuses_an_empty_cloud():
    method = get_method("gifs", udf_threshold=50.0, refine_steps=2)
    net = _small_network()
    with torch.no_grad():  # a flag head that fires: every cube is meshed by its own partition
        net.flag_decoder.fc_out.bias.fill_(0.6)
    sphere = trimesh.creation.icosphere(3, radius=0.6)
    points, _ = sample_surface(np.asarray(sphere.vertices), np.asarray(sphere.faces), 2000, np.random.default_rng(0))
    a = method.reconstruct(points, 20, seed=3, model=net)
    b = method.reconstruct(points, 20, seed=3, model=net)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert a.info["queried_cubes"] == a.info["candidate_cubes"] > 0 and len(a.faces) > 0
    with pytest.raises(ValueError, match="no points"):
        method.reconstruct(np.zeros((0, 3)), 20, model=net)
    with pytest.raises(ValueError, match="none given"):
        method.reconstruct(points, 20)


def test_training_is_deterministic():
    check_training_is_deterministic(get_method("gifs"), dataclasses.replace(TINY, steps=3, log_every=1))


@pytest.mark.slow
@pytest.mark.learned
def test_tiny_training_reconstructs_a_sphere(measured):
    from foundation.metrics import evaluate

    radius = 0.7
    method = get_method("gifs")
    trained = method.train_network(training_shapes(TINY.training_shapes), TINY, seed=0)
    sphere = trimesh.creation.icosphere(5, radius=radius)
    points, _ = sample_surface(np.asarray(sphere.vertices), np.asarray(sphere.faces), 10_000, np.random.default_rng(0))
    out = method.reconstruct(points, 32, model=trained.model)
    assert len(out.faces) > 0
    cd = evaluate(np.asarray(sphere.vertices), np.asarray(sphere.faces), out.vertices, out.faces, n_points=20_000)["cd"]
    radius_error = float(np.abs(np.linalg.norm(out.vertices, axis=1) - radius).mean())
    measured(cd=cd, radius_error=radius_error, final_loss=trained.final_loss)
    assert radius_error <= 0.05, f"mean radius error {radius_error:.4f} > 0.05"
    assert cd <= 0.035, f"CD {cd:.4f} > 0.035"
