"""Grid queries of the K-NN reconstruction networks (methods/pointcloud/knn/query.py) and the occupancy fill of
occ-knn, checked against brute force and hand-made volumes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from benchmark.grid import spacing
from methods.pointcloud.knn.network import make_knn_network
from methods.pointcloud.knn.query import band_edges, band_points, evaluate_knn, nearest_distance
from methods.extractors.marching_cubes import far_occupancy
from benchmark.grid import edge_inputs, point_inputs

N = 24


def cloud(n=400, seed=0):
    x = np.random.default_rng(seed).normal(size=(n, 3))
    return 0.6 * x / np.linalg.norm(x, axis=1, keepdims=True)


def brute_distance(points, queries):
    return np.sqrt(((queries[:, None, :] - points[None, :, :]) ** 2).sum(-1)).min(axis=1)


def test_band_points_and_edges_are_exactly_the_grid_queries_within_the_radius():
    pts, r = cloud(), 2.0 * spacing(N)
    every = np.argwhere(np.ones((N, N, N), bool))
    inside = brute_distance(pts, point_inputs(N, every).astype(np.float64)) <= r
    assert {tuple(p) for p in band_points(pts, N, r)} == {tuple(p) for p in every[inside]}
    mids = edge_inputs(N).reshape(-1, 2, 3).mean(axis=1)
    expected = np.flatnonzero(brute_distance(pts, mids.astype(np.float64)) <= r)
    assert np.array_equal(np.sort(band_edges(pts, N, r)), expected)
    assert np.allclose(nearest_distance(pts, mids[:5]), brute_distance(pts, mids[:5].astype(np.float64)))


def test_far_region_enclosed_by_the_band_is_inside():
    known = np.zeros((N, N, N), bool)
    known[4:20, 4:20, 4:20] = True
    known[6:18, 6:18, 6:18] = False  # a hollow box: the band of a closed surface
    occ = far_occupancy(known)
    assert occ[12, 12, 12] == 1 and occ[0, 0, 0] == 0 and occ[5, 5, 5] == 0  # inside, outside, band
    assert occ[6:18, 6:18, 6:18].all() and occ.sum() == 12 ** 3


def test_evaluate_knn_gradient_matches_finite_differences():
    torch.manual_seed(0)
    net = make_knn_network("segment", out_dim=2, encoder_width=16, encoder_depth=1, head_width=16,
                           head_depth=1).eval()
    pts = cloud(200)
    seg = np.array([[[0.6, 0.0, 0.0], [0.62, 0.01, 0.0]], [[0.0, 0.59, 0.0], [0.0, 0.61, 0.02]]], np.float32)
    out, grad = evaluate_knn(net, seg, pts, k=8, grad_output=1)
    assert out.shape == (2, 2) and grad.shape == (2, 2, 3)
    eps = 1e-3
    moved = seg.copy()
    moved[0, 0, 0] += eps  # u_x of the first segment (its neighbourhood stays the same for so small a step)
    out2, _ = evaluate_knn(net, moved, pts, k=8)
    assert abs((out2[0, 1] - out[0, 1]) / eps - grad[0, 0, 0]) < 2e-2 * max(1.0, abs(grad[0, 0, 0]))


@pytest.mark.slow
def test_evaluate_knn_is_independent_of_the_chunk_size(monkeypatch):
    """Eval-mode batch norm uses running statistics, so a query's output is its own: 1,000 queries in
    chunks of 7 give what one pass gives (to float32 rounding), gradients included."""
    import methods.pointcloud.knn.query as knn_query

    torch.manual_seed(0)
    net = make_knn_network("point", out_dim=1, encoder_width=16, encoder_depth=1, head_width=16,
                           head_depth=1).eval()
    pts = cloud(300)
    queries = np.random.default_rng(1).uniform(-0.7, 0.7, size=(1000, 3)).astype(np.float32)
    monkeypatch.setitem(knn_query.CHUNK, "cpu", 10_000)
    whole, whole_grad = evaluate_knn(net, queries, pts, k=8, grad_output=0)
    monkeypatch.setitem(knn_query.CHUNK, "cpu", 7)
    chunked, chunked_grad = evaluate_knn(net, queries, pts, k=8, grad_output=0)
    assert np.allclose(whole, chunked, atol=1e-6) and np.allclose(whole_grad, chunked_grad, atol=1e-5)
