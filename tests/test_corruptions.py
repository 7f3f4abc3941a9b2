"""foundation.corruptions: the named ladder of input clouds, each rung checked against its documented effect."""

import math

import numpy as np
import pytest
import trimesh

from foundation.corruptions import CORRUPTIONS, LEVELS, Corruption, input_cloud, parse_corruption
from foundation.scanner import scan_cloud, sphere_sensors
from foundation.surface import sample_surface

N = 3000
SEED = 11
SIDE = 1.99  # the canonical sphere below: radius 0.995, bounding box side 1.99


@pytest.fixture(scope="module")
def mesh():
    s = trimesh.creation.icosphere(subdivisions=4, radius=0.995)
    return np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)


@pytest.fixture(scope="module")
def clouds(mesh):
    """Every corruption of the sphere at (N, SEED)."""
    return {name: input_cloud(*mesh, N, name, np.random.default_rng(SEED)) for name in CORRUPTIONS}


def test_names_round_trip_and_refusals():
    assert CORRUPTIONS == ("uniform", "scan", "noise-1", "noise-2", "noise-3", "outliers-1", "outliers-2",
                           "outliers-3", "missing-1", "missing-2", "missing-3", "density-1", "density-2",
                           "density-3", "misalign-1", "misalign-2", "misalign-3")
    for name in CORRUPTIONS:
        c = parse_corruption(name)
        assert str(c) == name and parse_corruption(str(c)) == c and c.parameters is LEVELS[name]
    assert parse_corruption("noise-2") == Corruption("noise", 2) and parse_corruption("scan") == Corruption("scan")
    for bad in ("noise-4", "foo", "noise-0", "uniform-1", "Noise-1", "noise", "", " scan"):
        with pytest.raises(ValueError) as err:
            parse_corruption(bad)
        message = str(err.value)
        assert "\n" not in message and all(name in message for name in CORRUPTIONS)
    for kind, level in (("noise", 4), ("scan", 1), ("foo", 1), ("noise", True)):
        with pytest.raises(ValueError):
            Corruption(kind, level)
    assert set(LEVELS) == set(CORRUPTIONS)


def test_levels_follow_the_published_anchors():
    assert [LEVELS[f"noise-{i}"].sigma for i in (1, 2, 3)] == [0.001, 0.003, 0.006]
    assert [LEVELS[f"outliers-{i}"].fraction for i in (1, 2, 3)] == [0.01, 0.05, 0.10]
    assert [LEVELS[f"missing-{i}"].dropped for i in (1, 2, 3)] == [2, 4, 6]
    assert [LEVELS[f"density-{i}"].min_keep for i in (1, 2, 3)] == [0.5, 0.2, 0.05]
    assert [(LEVELS[f"misalign-{i}"].translation, LEVELS[f"misalign-{i}"].rotation_deg) for i in (1, 2, 3)] == \
        [(0.005, 0.5), (0.01, 1.0), (0.02, 2.0)]
    assert LEVELS["scan"].sensors == 10 and math.isclose(LEVELS["scan"].distance * 1.99, 3.0)


def test_same_seed_same_cloud_bit_for_bit(mesh, clouds):
    for name in CORRUPTIONS:
        again = input_cloud(*mesh, N, name, np.random.default_rng(SEED))
        ref = clouds[name]
        assert np.array_equal(again.points, ref.points), name
        assert np.array_equal(again.outlier_mask, ref.outlier_mask), name
        if name != "uniform":
            assert np.array_equal(again.sensors, ref.sensors) and np.array_equal(again.sensor_ids, ref.sensor_ids)
        assert len(ref) == N, name
        assert not np.array_equal(input_cloud(*mesh, N, name, np.random.default_rng(SEED + 1)).points, ref.points)


def test_uniform_is_sample_surface_and_scan_is_scan_cloud(mesh, clouds):
    points, _ = sample_surface(*mesh, N, np.random.default_rng(SEED))
    assert np.array_equal(clouds["uniform"].points, points) and clouds["uniform"].sensors is None
    layout = sphere_sensors(10, 3.0 / 1.99 * SIDE)
    scan = scan_cloud(*mesh, N, np.random.default_rng(SEED), sensors=layout, grazing_dropout_deg=85.0)
    assert np.array_equal(clouds["scan"].points, scan.points)
    assert np.array_equal(clouds["scan"].sensors, layout[scan.sensor_ids])
    assert np.allclose(np.linalg.norm(clouds["scan"].sensor_layout, axis=1), 3.0)


def test_noise_is_range_noise_of_the_level_sigma(clouds):
    clean = clouds["scan"]
    sight = clean.points - clean.sensors
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    stds, draws = [], []
    for level in (1, 2, 3):
        cloud = clouds[f"noise-{level}"]
        residual = cloud.points - clean.points
        along = np.einsum("ij,ij->i", residual, sight)
        assert np.abs(residual - along[:, None] * sight).max() < 1e-14  # along the line of sight
        sigma = LEVELS[f"noise-{level}"].sigma * SIDE
        assert abs(along.std() / sigma - 1) < 4 / math.sqrt(2 * N)  # 4 standard errors
        stds.append(along.std())
        draws.append(along / sigma)
    assert stds[0] < stds[1] < stds[2]
    assert np.allclose(draws[0], draws[1], atol=1e-9) and np.allclose(draws[1], draws[2], atol=1e-9)


def test_outliers_replace_the_exact_fraction_inside_the_enlarged_box(clouds):
    clean = clouds["scan"]
    masks = []
    for level, count in ((1, 30), (2, 150), (3, 300)):  # 1%, 5%, 10% of 3000
        cloud = clouds[f"outliers-{level}"]
        mask = cloud.outlier_mask
        assert mask.sum() == count and len(cloud) == N
        assert np.array_equal(cloud.points[~mask], clean.points[~mask])  # the rest untouched
        pad = 0.0025 * SIDE
        assert np.all(np.abs(cloud.points[mask]) <= 0.995 + pad)  # the box [-1, 1]^3 (to 2.5e-5)
        masks.append(mask)
    assert np.all(masks[0] <= masks[1]) and np.all(masks[1] <= masks[2])  # nested
    # mostly off the surface: the shell |r - 0.995| < 0.05 is ~16% of the box [-1, 1]^3
    radius = np.linalg.norm(clouds["outliers-3"].points[masks[2]], axis=1)
    assert np.mean(np.abs(radius - 0.995) > 0.05) > 0.75
    # the same outlier positions at every level
    assert np.array_equal(clouds["outliers-1"].points[masks[0]], clouds["outliers-3"].points[masks[0]])


def test_missing_drops_the_sensors_nearest_one_side(clouds):
    dropped_sets, cap_counts = [], []
    direction = clouds["missing-1"].direction
    for level, k in ((1, 2), (2, 4), (3, 6)):
        cloud = clouds[f"missing-{level}"]
        assert len(cloud) == N and np.array_equal(cloud.direction, direction)  # same side at every level
        layout = cloud.sensor_layout
        nearness = layout @ direction / np.linalg.norm(layout, axis=1)
        dropped = cloud.dropped_sensors
        kept = np.setdiff1d(np.arange(10), dropped)
        assert len(dropped) == k and nearness[dropped].min() > nearness[kept].max()
        assert not np.isin(cloud.sensor_ids, dropped).any()  # no point from a dropped sensor
        assert set(np.unique(cloud.sensor_ids).tolist()) == set(kept.tolist())
        dropped_sets.append(set(dropped.tolist()))
        cap_counts.append(np.sum(cloud.points @ direction > 0.5))  # the cap facing the dropped side
    assert dropped_sets[0] < dropped_sets[1] < dropped_sets[2]
    clean_cap = np.sum(clouds["scan"].points @ direction > 0.5)
    assert clean_cap > cap_counts[0] > cap_counts[1] > cap_counts[2]


def test_density_thins_one_side_more_at_each_level(clouds):
    direction = clouds["density-1"].direction
    counts = []
    for level in (1, 2, 3):
        cloud = clouds[f"density-{level}"]
        assert len(cloud) == N and np.array_equal(cloud.direction, direction)
        counts.append(np.sum(cloud.points @ direction > 0))  # the thinned half of the sphere
    clean = np.sum(clouds["scan"].points @ direction > 0)
    assert clean > counts[0] > counts[1] > counts[2]
    # level 3 keeps 1 -> 0.05 linearly: the thinned half holds well under half of the points
    assert counts[2] < 0.35 * N


def kabsch(source, target):
    """The rigid (R, t) with target ~ source @ R.T + t (least squares)."""
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - cs).T @ (target - ct))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1, 1, d]) @ u.T
    return rot, ct - cs @ rot.T


def test_misalign_is_a_rigid_error_per_sensor_of_the_level_size(clouds):
    clean = clouds["scan"]
    mean_shift = []
    for level in (1, 2, 3):
        cloud = clouds[f"misalign-{level}"]
        params = LEVELS[f"misalign-{level}"]
        assert np.array_equal(cloud.sensor_ids, clean.sensor_ids)
        for s in np.unique(clean.sensor_ids):
            rows = clean.sensor_ids == s
            rot, shift = kabsch(clean.points[rows], cloud.points[rows])
            angle = math.degrees(math.acos(min(1.0, (np.trace(rot) - 1) / 2)))
            assert abs(angle - params.rotation_deg) < 1e-6
            assert abs(np.linalg.norm(shift) - params.translation * SIDE) < 1e-9
            assert np.abs(cloud.points[rows] - (clean.points[rows] @ rot.T + shift)).max() < 1e-12
        mean_shift.append(np.linalg.norm(cloud.points - clean.points, axis=1).mean())
    assert mean_shift[0] < mean_shift[1] < mean_shift[2]
