"""The storage and inference preamble shared by the learned point-cloud methods with their own
architecture (POCO, GIFS, GeoUDF), as :class:`methods.pointcloud.knn.method.KNNTrainedMethod` is for the
methods on the shared K-NN network."""

from __future__ import annotations

from typing import Callable, ClassVar

import torch

from methods.base import LearnedPointCloudMethod
from methods.core.budgets import budget_values
from methods.core.weights import refused_weights_from_bytes, weights_to_bytes
from methods.pointcloud.training_set import TrainResult

__all__ = ["OwnNetworkMethod"]


class OwnNetworkMethod(LearnedPointCloudMethod):
    """A learned point-cloud method whose network and trainer are its own.

    Subclasses set ``network_label`` (the name in messages, ``"POCO"``), ``build_network`` (a
    ``staticmethod``: the network from the config it stores, ``make_poco_network``) and
    ``budget_family`` (their own budget record: architecture, schedule and training set), and
    implement :meth:`train_network` and ``reconstruct``. The stored bytes hold the budget's values."""

    network_label: ClassVar[str] = ""
    build_network: ClassVar[Callable[..., torch.nn.Module]]

    def network_to_bytes(self, trained: TrainResult, budget) -> bytes:
        return weights_to_bytes(trained.model, budget_values(budget), self.name, trained.final_loss)

    def network_from_bytes(self, data: bytes, device=None) -> torch.nn.Module:
        return refused_weights_from_bytes(data, self.build_network, device, self.name,
                                          what=f"{self.network_label} weights")
