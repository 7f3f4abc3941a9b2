"""Grid queries of the K-NN reconstruction networks (methods/pointcloud/knn/query.py),
checked against finite differences and chunking."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from methods.pointcloud.knn.network import make_knn_network
from methods.pointcloud.knn.query import evaluate_knn

N = 24


def cloud(n=400, seed=0):
    x = np.random.default_rng(seed).normal(size=(n, 3))
    return 0.6 * x / np.linalg.norm(x, axis=1, keepdims=True)


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
