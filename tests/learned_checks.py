"""Checks every learned point-cloud method with its own network passes (shared by their tests): its
network bytes round-trip and bad bytes are refused in one line; two trainings at one seed are equal.
Also their test input: a point cloud on a sphere."""

import numpy as np
import pytest
import torch
import trimesh

from benchmark.surface import sample_surface

from methods.core.weights import weights_to_bytes
from methods.pointcloud.knn.training import KNNTrainResult, training_shapes


def sphere_cloud(n: int, radius: float, seed: int = 0) -> np.ndarray:
    """``n`` area-uniform points (float64) on a level-4 icosphere of ``radius`` about the origin."""
    sphere = trimesh.creation.icosphere(4, radius=radius)
    points, _ = sample_surface(np.asarray(sphere.vertices), np.asarray(sphere.faces), n, np.random.default_rng(seed))
    return points


def check_weights_round_trip(method, net: torch.nn.Module, budget, what: str, foreign_method: str) -> None:
    """``method.network_from_bytes(method.network_to_bytes(net))`` equals ``net``; truncated bytes are
    refused as "<what> refused", and ``foreign_method``'s bytes name both methods."""
    data = method.network_to_bytes(KNNTrainResult(model=net, losses=np.zeros(1), seconds=1.0, steps=1,
                                                  samples_per_s=1.0, final_loss=0.5), budget)
    loaded = method.network_from_bytes(data, device="cpu")
    assert loaded.config == net.config
    for key, value in net.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[key], value)
    with pytest.raises(ValueError, match=f"{what} refused"):
        method.network_from_bytes(data[: len(data) // 2], device="cpu")
    with pytest.raises(ValueError, match=f"of method '{foreign_method}', expected '{method.name}'"):
        method.network_from_bytes(weights_to_bytes(net, {}, foreign_method, 0.5), device="cpu")


def check_training_is_deterministic(method, budget, seed: int = 5) -> None:
    """Two trainings of ``method`` on the same 2 shapes at ``seed`` give the same losses and the same
    weights, bit for bit (CPU)."""
    shapes = training_shapes(2)
    a = method.train_network(shapes, budget, seed=seed)
    b = method.train_network(shapes, budget, seed=seed)
    np.testing.assert_array_equal(a.losses, b.losses)
    for key, value in a.model.state_dict().items():
        torch.testing.assert_close(b.model.state_dict()[key], value, rtol=0, atol=0)
