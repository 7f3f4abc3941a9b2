"""The learned point-cloud methods' training set (methods.pointcloud.training_set): built-in parts
disjoint from the built-in test shapes, extra mesh folders, a digest that names the set, and seeded
float32 pools sized by the budget."""

import dataclasses

import numpy as np
import pytest

from datasets import get_dataset
from datasets.builtin import VARIANTS
from methods.pointcloud import training_set
from methods.pointcloud.knn.training import KNN_BUDGETS
from methods.pointcloud.training_set import TrainingPools, TrainingSetError, training_set_digest, training_shapes
from tests.conftest import requires_shared
from tests.learned_checks import PointUDF, SegmentOS

TINY = KNN_BUDGETS.get("tiny")


@pytest.fixture(scope="module")
def parts():
    return training_shapes(6)


def test_training_shapes_are_disjoint_from_the_builtin_test_shapes_and_cover_every_variant(parts):
    assert [s.kind for s in parts] == [VARIANTS[i % 3] for i in range(6)]
    assert all(s.name.startswith("train1_builtin_") and s.meta["seed"] == 1 for s in parts)
    test_set = get_dataset("builtin", count=6, seed=0)  # the test dataset, built the way a run builds it
    test_hashes = {s.content_hash for s in test_set}
    assert len({s.content_hash for s in parts}) == 6 and not test_hashes & {s.content_hash for s in parts}
    assert test_hashes <= set(training_set.builtin_test_hashes(6))  # the check covers the test dataset
    again = training_shapes(6)  # cached per process: the same arrays, nothing generated again
    assert [s.name for s in again] == [s.name for s in parts] and again[5].vertices is parts[5].vertices
    with pytest.raises(TrainingSetError, match="training seed 0 is the built-in test dataset's seed"):
        training_shapes(2, seed=0)


def test_a_training_shape_equal_to_a_test_shape_raises(parts, monkeypatch):
    monkeypatch.setattr(training_set, "builtin_test_hashes",
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
