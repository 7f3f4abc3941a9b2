"""Test-only methods for the run-layer tests: marching cubes on the exact SDF / occupancy, one whose
extractor raises and one whose loss is NaN. Registered by :func:`register_fakes`, which workers
import with ``--plugin tests.fake_methods:register_fakes``; tests use the ``fakes`` fixture of
conftest, which removes them again."""

from __future__ import annotations

import numpy as np

from methods.base import FieldMethod, register_method
from foundation.params import Param

PLUGIN = "tests.fake_methods:register_fakes"


class _FakeGridMethod(FieldMethod):
    input_kind = "points"
    output_dim = 1
    extractor = "marching cubes"
    kind = "sdf"

    def training_targets(self, fields, samples):
        target = np.asarray(getattr(fields, self.kind)(samples.points), dtype=np.float32)
        return {"target": target + np.float32(self.params.get("offset", 0.0))}

    def loss(self, prediction, targets):
        import torch

        target = targets["target"].reshape(prediction.shape)
        if self.kind == "sdf":
            return torch.abs(prediction.clamp(-0.1, 0.1) - target.clamp(-0.1, 0.1)).mean()
        return torch.nn.functional.binary_cross_entropy_with_logits(prediction, target)

    def neural_grid(self, model, N, device):
        from methods.core import query

        values = query.dense_grid_points(model, N, device)[..., 0]
        if self.kind == "occupancy":
            values = 1.0 / (1.0 + np.exp(-values))
        return values, {}

    def oracle_grid(self, fields, N, cache):
        return cache.get(fields, N, self.kind), {}

    def extract(self, grid_field, N):
        from methods.extractors.marching_cubes import marching_cubes_grid

        if self.kind == "sdf":
            return marching_cubes_grid(grid_field, self.params["level"], inside="low")
        return marching_cubes_grid(np.asarray(grid_field, dtype=np.float32), 0.5, inside="high")


class FakeSDF(_FakeGridMethod):
    name = "test_sdf"
    description = "test-only: marching cubes on the exact SDF"
    parameters = {"level": Param(0.0, "iso level", gt=-0.1, lt=0.1),
                  "offset": Param(0.0, "added to the training targets (a setting the fit reads)", ge=-0.05, le=0.05,
                                  neural_only=True, fit=True)}


class FakeOcc(_FakeGridMethod):
    name = "test_occ"
    description = "test-only: marching cubes on the exact occupancy"
    kind = "occupancy"


class FakeBroken(_FakeGridMethod):
    name = "test_broken"
    description = "test-only: its extractor always raises"

    def extract(self, grid_field, N):
        raise RuntimeError("boom: extractor failed\nsecond line")


class FakeNaN(FakeSDF):
    name = "test_nan"
    description = "test-only: its training loss is NaN"

    def loss(self, prediction, targets):
        return super().loss(prediction, targets) * float("nan")


#: The test-only methods, each with its display order.
FAKES = ((FakeSDF, 1), (FakeOcc, 2), (FakeBroken, 3), (FakeNaN, 4))


def register_fakes() -> None:
    """Register the test-only methods (idempotent; also called in worker processes)."""
    for cls, order in FAKES:
        register_method(cls, order=order)
