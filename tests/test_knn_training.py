"""Training the K-NN network of a learned reconstruction method across shapes
(methods.pointcloud.knn.training): batches with exact K-NN neighbourhoods, a loss that drops,
bit-identical reruns, weights as bytes, one-line failures, and the K-NN budgets."""

import dataclasses

import numpy as np
import pytest
import torch

from methods.core.training_loop import FittingError
from methods.pointcloud.knn.training import (KNN_BUDGETS, KNNBudget, knn_batch, knn_model_from_bytes,
                                             knn_model_to_bytes, train)
from methods.pointcloud.training_set import TrainingPools, training_shapes
from tests.learned_checks import PointUDF, SegmentOS

TINY = KNN_BUDGETS.get("tiny")
pytestmark = pytest.mark.usefixtures("torch_threads")


class NaNTargets(PointUDF):
    name = "test-nan-knn"

    def training_targets(self, fields, samples):
        udf = super().training_targets(fields, samples)["udf"]
        udf[7] = np.nan
        return {"udf": udf}


class NaNLoss(PointUDF):
    name = "test-nan-loss-knn"

    def loss(self, prediction, targets):
        return super().loss(prediction, targets) * float("nan")


@pytest.fixture(scope="module")
def parts():
    return training_shapes(6)


def _budget(**changes) -> KNNBudget:
    return dataclasses.replace(TINY, **changes)


def test_a_batch_holds_each_samples_exact_neighbours_in_its_items_cloud(parts):
    """pool_points = points_per_item: an item's cloud is its whole pool (permuted), so the neighbours'
    distances to each segment's midpoint are the K smallest distances to the pool."""
    budget = _budget(pool_points=TINY.points_per_item, shapes_per_batch=1, samples_per_item=64)
    pools = TrainingPools(SegmentOS(), parts[:1], budget, seed=0)
    anchors, neighbours, targets = knn_batch(pools, budget, np.random.default_rng(0))
    assert anchors.shape == (64, 2, 3) and neighbours.shape == (64, budget.k, 3) and targets["s"].shape == (64,)
    mid = anchors.mean(axis=1)
    d_all = np.sort(np.linalg.norm(pools.pools[0].cloud[None] - mid[:, None], axis=-1), axis=1)[:, :budget.k]
    np.testing.assert_allclose(np.linalg.norm(neighbours - mid[:, None], axis=-1), d_all, rtol=0, atol=1e-6)
    two = _budget(shapes_per_batch=2)
    a2, q2, t2 = knn_batch(TrainingPools(PointUDF(), parts[:2], two, seed=0), two, np.random.default_rng(0))
    assert a2.shape == (2 * two.samples_per_item, 3) and q2.shape == (2 * two.samples_per_item, two.k, 3)


@pytest.mark.learned
@pytest.mark.slow
def test_tiny_budget_trains_the_point_method_and_its_loss_drops(parts, fit_seed, measured):
    """3 built-in parts (closed, open, non-manifold), the tiny budget (400 steps):
    the mean loss of the last 50 steps is below half that of the first 5 (outputs start near 0, so
    the first loss is the mean clamped UDF) and below 2/3 of the L1 loss of the best constant (the
    pools' median), so the network reads the neighbourhoods. Measured over seeds 0-4 x float paths x
    1-2 threads (docs/spread/learned.md): last / first 0.26-0.32, last / constant 0.25-0.29."""
    reports = []
    result = train(PointUDF(), parts[:3], TINY, seed=fit_seed,
                   progress=lambda step, loss, total: reports.append((step, loss, total)))
    assert [s for s, _, _ in reports] == list(range(50, TINY.steps + 1, 50))
    assert {total for _, _, total in reports} == {TINY.steps}
    assert result.steps == TINY.steps and result.losses.shape == (TINY.steps,) and result.seconds > 0 and result.samples_per_s > 0
    first, last = result.losses[:5].mean(), result.losses[-50:].mean()
    udf = np.concatenate([p.targets["udf"] for p in TrainingPools(PointUDF(), parts[:3], TINY, seed=fit_seed).pools])
    constant = np.abs(udf - np.median(udf)).mean()
    measured(first=first, last=last, last_over_first=last / first, last_over_constant=last / constant)
    assert last < first / 2 and last < constant * 2 / 3, (first, last, constant)
    assert result.final_loss == pytest.approx(last)
    assert not result.model.training and result.model.knn_k == TINY.k


def test_same_seed_gives_identical_weights_and_segment_training_runs(parts):
    budget = _budget(steps=12, log_every=4)
    pools = TrainingPools(SegmentOS(), parts[:2], budget, seed=5)
    a = train(SegmentOS(), parts[:2], budget, seed=5)
    b = train(SegmentOS(), None, budget, seed=5, pools=pools)  # the same pools, built beforehand
    c = train(SegmentOS(), parts[:2], budget, seed=6)
    np.testing.assert_array_equal(a.losses, b.losses)
    assert np.all(np.isfinite(a.losses)) and not np.array_equal(a.losses, c.losses)
    for (name, wa), wb in zip(a.model.state_dict().items(), b.model.state_dict().values()):
        assert torch.equal(wa, wb), name
    with pytest.raises(ValueError, match="pools of 'segment' samples for a 'point' method"):
        train(PointUDF(), None, budget, pools=pools)


def test_model_bytes_round_trip_gives_identical_outputs(parts):
    budget = _budget(steps=6, log_every=3)
    result = train(PointUDF(), parts[:2], budget, seed=0)
    data = knn_model_to_bytes(result.model, budget, PointUDF.name, result.final_loss)
    model, final = knn_model_from_bytes(data, method_name=PointUDF.name)
    assert final == pytest.approx(result.final_loss) and not model.training and model.knn_k == budget.k
    assert model.config == result.model.config
    anchors, neighbours, _ = knn_batch(TrainingPools(PointUDF(), parts[:1], budget), budget, np.random.default_rng(1))
    x, q = torch.from_numpy(anchors), torch.from_numpy(neighbours)
    with torch.no_grad():
        assert torch.equal(model(x, q), result.model(x, q))
    with pytest.raises(ValueError, match="K-NN weights of method 'test-udf-knn', expected 'udf-knn'"):
        knn_model_from_bytes(data, method_name="udf-knn")


def test_non_finite_targets_and_losses_raise_a_one_line_fitting_error(parts):
    with pytest.raises(FittingError, match="target 'udf' of training shape 'train1_builtin_000_bracket' "
                                           "contains NaN or infinite values") as info:
        train(NaNTargets(), parts[:1], TINY)
    assert "\n" not in str(info.value)
    with pytest.raises(FittingError, match=r"non-finite loss at step 0 of 4 \(method 'test-nan-loss-knn', "
                                           r"knn budget 'tiny', seed 0\)") as info:
        train(NaNLoss(), parts[:1], _budget(steps=4, log_every=2))
    assert "\n" not in str(info.value)


def test_budgets_carry_their_training_set_and_pools():
    paper, cpu = KNN_BUDGETS.get("paper"), KNN_BUDGETS.get("cpu")
    assert (paper.training_shapes, paper.pool_samples, paper.pool_points) == (100, 1_000_000, 1_000_000)
    assert cpu.training_shapes < paper.training_shapes and cpu.pool_points >= cpu.points_per_item
    assert TINY.training_shapes <= 4
    with pytest.raises(ValueError, match="pool_points 1000 < points_per_item 10000"):
        _budget(pool_points=1_000)
    with pytest.raises(ValueError, match="training_shapes=0: expected int in \\[1, inf\\)"):
        _budget(training_shapes=0)
