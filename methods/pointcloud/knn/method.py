"""The base of the K-NN reconstruction methods (``sals-knn``, ``udf-knn``, ``occ-knn``): a learned
method whose network is the shared K-NN local network (:mod:`methods.pointcloud.knn.network`),
trained across shapes by :mod:`methods.pointcloud.knn.training`."""

from __future__ import annotations

from methods.base import LearnedPointCloudMethod
from methods.pointcloud.knn.training import knn_model_from_bytes, knn_model_to_bytes, train
from methods.pointcloud.training_set import TrainResult


class KNNTrainedMethod(LearnedPointCloudMethod):
    """A learned reconstruction method whose network is the shared K-NN local network, trained by
    :func:`methods.pointcloud.knn.training.train` (subclasses set ``network_kind`` and ``output_dim``
    and implement ``training_targets``, ``loss`` and ``reconstruct``)."""

    budget_family = "knn"
    training_modules = ("methods.pointcloud.knn.training",)

    def train_network(self, shapes, budget, seed, device=None, progress=None) -> TrainResult:
        return train(self, shapes, budget, seed=seed, device=device, progress=progress)

    def network_to_bytes(self, trained: TrainResult, budget) -> bytes:
        return knn_model_to_bytes(trained.model, budget, self.name, trained.final_loss)

    def network_from_bytes(self, data: bytes, device=None):
        return knn_model_from_bytes(data, device=device, method_name=self.name)[0]
