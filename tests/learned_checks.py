"""Checks every learned point-cloud method with its own network passes (shared by their tests): its
network bytes round-trip and bad bytes are refused in one line; two trainings at one seed are equal.
Also their test input (a point cloud on a sphere) and two test-only learned methods whose labels are
the exact fields (:class:`PointUDF`, :class:`SegmentOS`)."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F
import trimesh

from foundation.surface import sample_surface

from methods.base import LearnedPointCloudMethod
from methods.core.weights import weights_to_bytes
from methods.pointcloud.training_set import TrainResult, training_shapes


def sphere_cloud(n: int, radius: float, seed: int = 0) -> np.ndarray:
    """``n`` area-uniform points (float64) on a level-4 icosphere of ``radius`` about the origin."""
    sphere = trimesh.creation.icosphere(4, radius=radius)
    points, _ = sample_surface(np.asarray(sphere.vertices), np.asarray(sphere.faces), n, np.random.default_rng(seed))
    return points


def check_weights_round_trip(method, net: torch.nn.Module, budget, what: str, foreign_method: str) -> None:
    """``method.network_from_bytes(method.network_to_bytes(net))`` equals ``net``; truncated bytes are
    refused as "<what> refused", and ``foreign_method``'s bytes name both methods."""
    data = method.network_to_bytes(TrainResult(model=net, losses=np.zeros(1), seconds=1.0, steps=1,
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


class PointUDF(LearnedPointCloudMethod):
    """Test-only 'point' method: the exact UDF clamped to 0.1, L1."""

    name = "test-udf-knn"
    network_kind = "point"
    output_dim = 1

    def training_targets(self, fields, samples):
        return {"udf": np.minimum(fields.udf(samples.points), 0.1).astype(np.float32)}

    def loss(self, prediction, targets):
        return F.l1_loss(prediction[:, 0].clamp(max=0.1), targets["udf"])


class SegmentOS(LearnedPointCloudMethod):
    """Test-only 'segment' method: SALS's o/s targets, 10 L1(s | o = 1) + BCE(o)."""

    name = "test-sals-knn"
    network_kind = "segment"
    output_dim = 2

    def training_targets(self, fields, samples):
        hit, s, _ = fields.segments(samples.segments[:, 0], samples.segments[:, 1])
        return {"o": hit.astype(np.float32), "s": s.astype(np.float32)}

    def loss(self, prediction, targets):
        o = targets["o"]
        s_err = ((torch.sigmoid(prediction[:, 1]) - targets["s"]).abs() * o).sum() / o.sum().clamp(min=1.0)
        return 10.0 * s_err + F.binary_cross_entropy_with_logits(prediction[:, 0], o)
