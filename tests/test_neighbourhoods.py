"""Nearest-neighbour searches over an input cloud (methods.pointcloud.neighbourhoods), checked
against brute force: K nearest points of points and segments, the distance to the cloud, and the
grid points and edges within a radius of it."""

from __future__ import annotations

import numpy as np
import pytest

from foundation.grid import edge_inputs, point_inputs, spacing
from methods.pointcloud.neighbourhoods import (band_edges, band_points, knn_neighbourhoods, nearest_distance,
                                               segment_neighbourhoods)

N = 24


def cloud(n=400, seed=0):
    x = np.random.default_rng(seed).normal(size=(n, 3))
    return 0.6 * x / np.linalg.norm(x, axis=1, keepdims=True)


def brute_distance(points, queries):
    return np.sqrt(((queries[:, None, :] - points[None, :, :]) ** 2).sum(-1)).min(axis=1)


def test_knn_neighbourhoods_match_brute_force_argsort():
    rng = np.random.default_rng(0)
    points, queries, k = rng.random((300, 3)), rng.random((50, 3)) * 1.2 - 0.1, 7
    idx = knn_neighbourhoods(points, queries, k)
    assert idx.shape == (50, k) and idx.dtype == np.int64
    d2 = ((queries[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    np.testing.assert_array_equal(idx, np.argsort(d2, axis=1)[:, :k])  # nearest first, exact
    # k = 1 is still (Q, 1); a segment's query is its midpoint; float32 input is fine
    np.testing.assert_array_equal(knn_neighbourhoods(points.astype(np.float32), queries, 1)[:, 0], d2.argmin(1))
    seg = np.stack([queries - 0.01, queries + 0.01], axis=1)
    np.testing.assert_array_equal(segment_neighbourhoods(points, seg, k), idx)
    np.testing.assert_array_equal(segment_neighbourhoods(points, seg.reshape(-1, 6), k), idx)
    assert knn_neighbourhoods(points, np.zeros((0, 3)), k).shape == (0, k)


def test_knn_neighbourhoods_refuse_fewer_points_than_k():
    with pytest.raises(ValueError, match="at least 20 input points, got 5"):
        knn_neighbourhoods(np.zeros((5, 3)), np.zeros((2, 3)), 20)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        knn_neighbourhoods(np.zeros((30, 2)), np.zeros((2, 3)), 3)


def test_band_points_and_edges_are_exactly_the_grid_queries_within_the_radius():
    pts, r = cloud(), 2.0 * spacing(N)
    every = np.argwhere(np.ones((N, N, N), bool))
    inside = brute_distance(pts, point_inputs(N, every).astype(np.float64)) <= r
    assert {tuple(p) for p in band_points(pts, N, r)} == {tuple(p) for p in every[inside]}
    mids = edge_inputs(N).reshape(-1, 2, 3).mean(axis=1)
    expected = np.flatnonzero(brute_distance(pts, mids.astype(np.float64)) <= r)
    assert np.array_equal(np.sort(band_edges(pts, N, r)), expected)
    assert np.allclose(nearest_distance(pts, mids[:5]), brute_distance(pts, mids[:5].astype(np.float64)))
