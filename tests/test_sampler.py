"""The shared sampler: group sizes, noise scales, shared centres, determinism (SPEC section 3)."""

import numpy as np
import pytest
import trimesh

from benchmark.sampler import GROUPS, group_counts, sample_surface_points, sample_training_data


@pytest.fixture(scope="module")
def unit_sphere():
    s = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    return np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)


def test_group_counts_follow_fractions_and_sum():
    counts = group_counts(1000)
    assert counts.tolist() == [500, 300, 100, 80, 20]
    assert group_counts(7).sum() == 7


def test_surface_points_lie_on_sphere(unit_sphere):
    V, F = unit_sphere
    p = sample_surface_points(V, F, 20000, np.random.default_rng(0))
    r = np.linalg.norm(p, axis=1)
    # icosphere(4) chords sit at most ~0.5 * (1 - cos(edge/2)) below the sphere
    assert r.max() <= 0.5 + 1e-9 and r.min() > 0.497


def test_area_uniform_on_two_squares_of_different_size():
    # square A (area 1) and square B (area 4): B must get ~80% of the points
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [5, 0, 0], [7, 0, 0], [7, 2, 0], [5, 2, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    p = sample_surface_points(V, F, 100000, np.random.default_rng(1))
    frac_b = np.mean(p[:, 0] >= 5)
    assert abs(frac_b - 0.8) < 0.01
    assert np.all((p[:, 0] >= 0) & (p[:, 0] <= 7) & (p[:, 1] >= 0) & (p[:, 1] <= 2))


def test_noise_scales_per_group(unit_sphere):
    V, F = unit_sphere
    s = sample_training_data(V, F, 200000, seed=3)
    displacement = s.points - s.centres
    for gi, (name, _, _, sigma) in enumerate(GROUPS):
        d = displacement[s.group == gi]
        assert abs(d.std() / sigma - 1) < 0.05, name
        seg = s.segments[s.group == gi]
        assert abs((seg[:, 1] - s.centres[s.group == gi]).std() / sigma - 1) < 0.05
    # the first endpoint of every segment is exactly the point-based sample
    assert np.array_equal(s.segments[:, 0], s.points)
    # surface centres are on the sphere, space centres fill [-1, 1]^3
    surf = s.centres[s.group <= 2]
    assert np.abs(np.linalg.norm(surf, axis=1) - 0.5).max() < 3e-3
    space = s.centres[s.group == 4]
    assert space.min() >= -1 and space.max() <= 1 and space.max() > 0.95
    box = s.centres[s.group == 3]
    assert box.min() >= -0.5 - 0.01 - 1e-6 and box.max() <= 0.5 + 0.01 + 1e-6


def test_same_seed_same_samples_other_seed_differs(unit_sphere):
    V, F = unit_sphere
    a = sample_training_data(V, F, 5000, seed=7)
    b = sample_training_data(V, F, 5000, seed=7)
    c = sample_training_data(V, F, 5000, seed=8)
    assert np.array_equal(a.segments, b.segments) and np.array_equal(a.group, b.group)
    assert not np.array_equal(a.points, c.points)


def test_rejects_non_positive_count(unit_sphere):
    with pytest.raises(ValueError, match="positive"):
        sample_training_data(*unit_sphere, 0, seed=0)
