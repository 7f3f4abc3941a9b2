"""Training a learned reconstruction method across shapes (methods.pointcloud.knn.training): a training
set disjoint from the built-in test shapes, seeded pools, batches with exact K-NN neighbourhoods,
a loss that drops, bit-identical reruns, weights as bytes and one-line failures."""

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from datasets import get_dataset
from datasets.builtin import VARIANTS
from methods.pointcloud.knn import training as knn_training
from methods.base import LearnedPointCloudMethod
from methods.core.training_loop import FittingError
from methods.pointcloud.knn.network import KNN_BUDGETS, KNNBudget
from methods.pointcloud.knn.training import (TrainingPools, TrainingSetError, knn_model_from_bytes, knn_model_to_bytes, train,
                                  training_set_digest, training_shapes)
from tests.conftest import requires_shared

TINY = KNN_BUDGETS.get("tiny")
pytestmark = pytest.mark.usefixtures("torch_threads")


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


def test_training_shapes_are_disjoint_from_the_builtin_test_shapes_and_cover_every_variant(parts):
    assert [s.kind for s in parts] == [VARIANTS[i % 3] for i in range(6)]
    assert all(s.name.startswith("train1_builtin_") and s.meta["seed"] == 1 for s in parts)
    test_set = get_dataset("builtin", count=6, seed=0)  # the test dataset, built the way a run builds it
    test_hashes = {s.content_hash for s in test_set}
    assert len({s.content_hash for s in parts}) == 6 and not test_hashes & {s.content_hash for s in parts}
    assert test_hashes <= set(knn_training.builtin_test_hashes(6))  # the check covers the test dataset
    again = training_shapes(6)  # cached per process: the same arrays, nothing generated again
    assert [s.name for s in again] == [s.name for s in parts] and again[5].vertices is parts[5].vertices
    with pytest.raises(TrainingSetError, match="training seed 0 is the built-in test dataset's seed"):
        training_shapes(2, seed=0)


def test_a_training_shape_equal_to_a_test_shape_raises(parts, monkeypatch):
    monkeypatch.setattr(knn_training, "builtin_test_hashes",
                        lambda count, seed=0: {parts[1].content_hash: "builtin_001_flange_open"})
    with pytest.raises(TrainingSetError, match=r"'train1_builtin_001_flange_open' is the built-in test shape "
                                               r"'builtin_001_flange_open' \(content hash [0-9a-f]{16}\)"):
        training_shapes(3)


@requires_shared("thingi10k")
def test_extra_dirs_add_every_mesh_of_the_folder_in_the_canonical_frame(shared_data):
    shapes = training_shapes(1, extra_dirs=[shared_data / "thingi10k"])
    names = get_dataset("meshes", data_dir=shared_data / "thingi10k").names()
    assert [s.name for s in shapes[1:]] == names and len(names) >= 5
    for s in shapes[1:]:
        side = (s.vertices.max(axis=0) - s.vertices.min(axis=0)).max()
        assert np.abs(s.vertices).max() <= 0.995 + 1e-9 and abs(side - 1.99) < 1e-9


def test_training_set_digest_names_the_set_whatever_its_order(parts):
    digest = training_set_digest(parts)
    assert len(digest) == 16 and int(digest, 16) >= 0
    assert training_set_digest(parts[::-1]) == digest
    assert training_set_digest(parts[:-1]) != digest
    renamed = [dataclasses.replace(parts[0], name="other")] + parts[1:]
    assert training_set_digest(renamed) != digest


def test_pools_are_seeded_float32_and_sized_by_the_budget(parts):
    a = TrainingPools(PointUDF(), parts[:2], TINY, seed=3)
    b = TrainingPools(PointUDF(), parts[:2], TINY, seed=3)
    c = TrainingPools(PointUDF(), parts[:2], TINY, seed=4)
    for pa, pb, pc in zip(a.pools, b.pools, c.pools):
        assert pa.anchors.shape == (TINY.pool_samples, 3) and pa.cloud.shape == (TINY.pool_points, 3)
        assert pa.anchors.dtype == pa.cloud.dtype == pa.targets["udf"].dtype == np.float32
        np.testing.assert_array_equal(pa.anchors, pb.anchors)
        np.testing.assert_array_equal(pa.cloud, pb.cloud)
        np.testing.assert_array_equal(pa.targets["udf"], pb.targets["udf"])
        assert not np.array_equal(pa.anchors, pc.anchors) and not np.array_equal(pa.cloud, pc.cloud)
    assert not np.array_equal(a.pools[0].anchors, a.pools[1].anchors)  # one stream per shape
    seg = TrainingPools(SegmentOS(), parts[:1], TINY, seed=3)
    assert seg.kind == "segment" and seg.pools[0].anchors.shape == (TINY.pool_samples, 2, 3)
    np.testing.assert_array_equal(seg.pools[0].anchors[:, 0], a.pools[0].anchors)  # u is the point sample
    assert 0 < seg.pools[0].targets["o"].mean() < 1


def test_a_batch_holds_each_samples_exact_neighbours_in_its_items_cloud(parts):
    """pool_points = points_per_item: an item's cloud is its whole pool (permuted), so the neighbours'
    distances to each segment's midpoint are the K smallest distances to the pool."""
    budget = _budget(pool_points=TINY.points_per_item, shapes_per_batch=1, samples_per_item=64)
    pools = TrainingPools(SegmentOS(), parts[:1], budget, seed=0)
    anchors, neighbours, targets = pools.batch(budget, np.random.default_rng(0))
    assert anchors.shape == (64, 2, 3) and neighbours.shape == (64, budget.k, 3) and targets["s"].shape == (64,)
    mid = anchors.mean(axis=1)
    d_all = np.sort(np.linalg.norm(pools.pools[0].cloud[None] - mid[:, None], axis=-1), axis=1)[:, :budget.k]
    np.testing.assert_allclose(np.linalg.norm(neighbours - mid[:, None], axis=-1), d_all, rtol=0, atol=1e-6)
    two = _budget(shapes_per_batch=2)
    a2, q2, t2 = TrainingPools(PointUDF(), parts[:2], two, seed=0).batch(two, np.random.default_rng(0))
    assert a2.shape == (2 * two.samples_per_item, 3) and q2.shape == (2 * two.samples_per_item, two.k, 3)


@pytest.mark.learned
@pytest.mark.slow
def test_tiny_budget_trains_the_point_method_and_its_loss_drops(parts, fit_seed, measured):
    """3 built-in parts (closed, open, non-manifold), the tiny budget (400 steps, ~6 s on one thread):
    the mean loss of the last 50 steps is below half that of the first 5 (outputs start near 0, so
    the first loss is the mean clamped UDF) and below 2/3 of the L1 loss of the best constant (the
    pools' median), so the network reads the neighbourhoods. Measured over seeds 0-4 x float paths x
    1-2 threads (docs/spread/learned.md): last / first 0.26-0.32, last / constant 0.25-0.29."""
    reports = []
    result = train(PointUDF(), parts[:3], TINY, seed=fit_seed, progress=lambda step, loss: reports.append((step, loss)))
    assert [s for s, _ in reports] == list(range(50, TINY.steps + 1, 50))
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
    anchors, neighbours, _ = TrainingPools(PointUDF(), parts[:1], budget).batch(budget, np.random.default_rng(1))
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
