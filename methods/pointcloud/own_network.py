"""The storage and inference preamble shared by the learned point-cloud methods with their own
architecture (POCO, GIFS, GeoUDF), as :class:`methods.pointcloud.knn.training.KNNTrainedMethod` is for the
methods on the shared K-NN network."""

from __future__ import annotations

import dataclasses
from typing import Callable, ClassVar

import torch

from methods.base import LearnedPointCloudMethod
from methods.core.device import get_device
from methods.core.weights import refused_weights_from_bytes, weights_to_bytes
from methods.pointcloud.knn.training import KNNTrainResult, get_knn_budget

__all__ = ["OwnNetworkMethod"]


class OwnNetworkMethod(LearnedPointCloudMethod):
    """A learned point-cloud method whose network and trainer are its own.

    Subclasses set ``network_label`` (the name in messages, ``"POCO"``), ``build_network`` (a
    ``staticmethod``: the network from the config it stores, ``make_poco_network``) and implement
    :meth:`architecture` (the method's config dataclass at a budget) besides
    :meth:`train_network` and ``reconstruct``. The stored bytes hold the K-NN budget (the training
    set and its pools) and the architecture under the method's name."""

    network_label: ClassVar[str] = ""
    build_network: ClassVar[Callable[..., torch.nn.Module]]

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.network_label and "table_note" not in cls.__dict__:
            cls.table_note = (f"{cls.name} trains {cls.network_label}'s own network at the budget's scale (its "
                              f"configuration is stored with its weights); the budget values of the protocol "
                              f"line describe the K-NN network of sals-knn, udf-knn and occ-knn.")

    def architecture(self, budget):
        """The method's own config dataclass at ``budget`` (a ``KNNBudget``)."""
        raise NotImplementedError

    def network_to_bytes(self, trained: KNNTrainResult, budget) -> bytes:
        budget = get_knn_budget(budget)
        return weights_to_bytes(trained.model, {"knn_budget": budget.to_dict(),
                                                self.name: dataclasses.asdict(self.architecture(budget))},
                                self.name, trained.final_loss)

    def network_from_bytes(self, data: bytes, device=None) -> torch.nn.Module:
        return refused_weights_from_bytes(data, self.build_network, device, self.name,
                                          what=f"{self.network_label} weights")

    def network_on_device(self, model: torch.nn.Module | None, device=None) -> tuple[torch.nn.Module, torch.device]:
        """(``model`` in eval mode on the chosen device, that device); a ValueError naming the method
        when no trained model is given."""
        if model is None:
            raise ValueError(f"{self.name} reconstructs with a trained network: none given")
        device = get_device(device)
        return model.to(device).eval(), device
