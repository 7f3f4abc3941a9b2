"""CAP-UDF (methods/pointcloud/cap_udf/: method.py, network.py, extraction.py): the network's
geometric initialisation, the schedule, the extraction on a hand-made plane UDF, and the whole
per-shape optimisation on a sphere cloud at the ``tiny`` budget."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from foundation.grid import grid_points, spacing
from methods.base import get_method
from methods.core.device import flush_denormals
from methods.pointcloud.cap_udf.method import (CAP_UDF_FAMILY, authors_frame, field_consistency_loss, learning_rate,
                                               nearest_indices, voxel_downsample)
from methods.pointcloud.cap_udf.extraction import gradient_sign_marching_cubes, gradient_signs, remove_far_faces
from methods.pointcloud.cap_udf.network import CAPUDFNetwork, pull

R = 0.5


TINY = CAP_UDF_FAMILY.budgets.get("tiny")

def sphere_points(n: int, seed: int = 0) -> np.ndarray:
    x = np.random.default_rng(seed).normal(size=(n, 3))
    return x * (R / np.linalg.norm(x, axis=1, keepdims=True))


def boundary_edge_count(faces: np.ndarray) -> int:
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum())


def test_geometric_init_starts_near_the_sphere_of_radius_one_half():
    torch.manual_seed(0)
    model = CAPUDFNetwork(width=64, hidden_layers=4, skip=2)
    directions = torch.nn.functional.normalize(torch.randn(500, 3), dim=1)
    with torch.no_grad():
        assert float(model(torch.zeros(1, 3))) == pytest.approx(0.5)  # zero input: |bias| of the last layer
    moved, d = pull(model, 0.9 * directions)
    # the pull moves points outside the sphere inward, towards radius 0.5
    assert float(moved.detach().norm(dim=1).mean()) < 0.9 and float(d.detach().mean()) > 0


def test_learning_rate_warms_up_then_decays_to_zero():
    c = CAP_UDF_FAMILY.budgets.get("paper")
    assert learning_rate(0, c) == 0.0 and learning_rate(500, c) == pytest.approx(5e-4)
    assert learning_rate(1000, c) == pytest.approx(1e-3) and learning_rate(c.steps, c) == pytest.approx(0.0)
    assert learning_rate(30_500, c) == pytest.approx(5e-4)  # half way through the cosine


def test_field_consistency_loss_is_the_l1_chamfer_distance():
    a = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    b = torch.tensor([[0.0, 0.3, 0.0], [1.0, 0.0, 0.4], [5.0, 0.0, 0.0]])
    # a -> b: 0.3, 0.4 (mean 0.35); b -> a: 0.3, 0.4, 4 (mean 1.5667)
    assert float(field_consistency_loss(a, b)) == pytest.approx(0.5 * (0.35 + 4.7 / 3))


def test_nearest_indices_inside_the_denormal_flush_on_coplanar_repeated_points():
    # 500 targets of one CAP-UDF batch (ABC part 00013858, cpu budget, seed 0): 159 share one z, 3 repeat.
    # With the fit's flush on, scipy's cKDTree recursed without end on them (a segmentation fault).
    data = np.load(Path(__file__).parent / "data" / "cap_udf_coplanar_targets.npz")
    queries, points = torch.from_numpy(data["queries"]), torch.from_numpy(data["points"])
    with flush_denormals():
        idx = nearest_indices(queries, points).numpy()
    q, p = data["queries"].astype(np.float64), data["points"].astype(np.float64)
    distances = np.linalg.norm(q[:, None] - p[None], axis=2)
    assert idx.shape == (len(q),)
    np.testing.assert_array_equal(distances[np.arange(len(q)), idx], distances.min(axis=1))


def test_authors_frame_maps_the_bounding_box_to_unit_largest_side():
    points = np.array([[-1.0, 0.0, 0.0], [0.99, 0.5, 0.2]])
    centre, scale = authors_frame(points)
    assert scale == pytest.approx(1.99) and np.allclose(centre, [-0.005, 0.25, 0.1])


def test_voxel_downsample_keeps_at_least_the_count_spread_out():
    points = np.random.default_rng(0).random((20_000, 3))
    rows = voxel_downsample(points, 1000)
    assert 1000 <= len(rows) < 1300 and len(np.unique(rows)) == len(rows)
    assert np.array_equal(voxel_downsample(points[:10], 50), np.arange(10))


def test_gradient_signs_by_hand():
    G = np.zeros((1, 8, 3))
    G[0, :, 2] = [1, 1, 1, 1, -1, -1, -1, -1]  # corners 4..7 (z = 1) point the other way
    assert gradient_signs(G).tolist() == [[1, 1, 1, 1, -1, -1, -1, -1]]


def test_extraction_of_a_plane_udf_is_the_plane():
    N, z0 = 17, 0.05  # h = 0.125: the plane z = z0 lies 0.4 h above the grid layer z = 0
    x = grid_points(N).reshape(N, N, N, 3)
    udf = np.abs(x[..., 2] - z0)
    grad = np.zeros((N, N, N, 3))
    grad[..., 2] = np.sign(x[..., 2] - z0)
    mesh = gradient_sign_marching_cubes(udf, grad, 1.16 * spacing(N))
    V, F = mesh.vertices, mesh.faces
    assert np.allclose(V[:, 2], z0)  # linear interpolation of |z - z0| with the gradient signs is exact
    assert len(F) == 2 * (N - 1) ** 2 and boundary_edge_count(F) == 4 * (N - 1)  # one square sheet
    # the authors skip cells whose nearest corner is farther than the threshold: at 0.3 h all of them
    assert len(gradient_sign_marching_cubes(udf, grad, 0.3 * spacing(N)).faces) == 0


def test_remove_far_faces_by_hand():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [6, 5, 5]])
    F = np.array([[0, 1, 2], [1, 3, 4]])
    V2, F2 = remove_far_faces(V, F, cloud=np.zeros((1, 3)), far=2.0)
    assert F2.tolist() == [[0, 1, 2]] and len(V2) == 3


def test_sphere_cloud_reconstructs_near_the_sphere_at_the_tiny_budget():
    N = 32
    mesh = get_method("cap-udf").reconstruct(sphere_points(3000), N=N, seed=0, budget=TINY)
    radial = np.abs(np.linalg.norm(mesh.vertices, axis=1) - R)
    area = 0.5 * np.linalg.norm(np.cross(mesh.vertices[mesh.faces[:, 1]] - mesh.vertices[mesh.faces[:, 0]],
                                         mesh.vertices[mesh.faces[:, 2]] - mesh.vertices[mesh.faces[:, 0]]),
                                axis=1).sum()
    h = spacing(N)  # 0.065
    assert radial.mean() < 0.1 * h and radial.max() < 0.5 * h
    assert abs(area / (4 * np.pi * R**2) - 1) < 0.05  # one sheet covering the sphere


def test_same_seed_same_mesh():
    points = sphere_points(600, seed=1)
    method = get_method("cap-udf")
    a = method.reconstruct(points, N=16, seed=3, budget=TINY)
    b = method.reconstruct(points, N=16, seed=3, budget=TINY)
    assert len(a.faces) > 0
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


def test_bad_clouds_are_refused_in_one_line():
    method = get_method("cap-udf")
    with pytest.raises(ValueError, match="no points") as info:
        method.reconstruct(np.zeros((0, 3)), N=16, budget=TINY)
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="more than 50"):
        method.reconstruct(sphere_points(20), N=16, budget=TINY)
