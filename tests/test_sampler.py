"""The shared sampler: group sizes, noise scales, shared centres, determinism."""

import numpy as np
import pytest
import trimesh

from foundation.sampler import GROUPS, group_counts, sample_training_data
from foundation.seeding import job_streams
from foundation.surface import sample_surface


@pytest.fixture(scope="module")
def unit_sphere():
    s = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    return np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)


def test_group_counts_follow_fractions_and_sum():
    counts = group_counts(1000)
    assert counts.tolist() == [500, 300, 100, 80, 20]
    assert group_counts(7).sum() == 7


def test_noise_scales_per_group(unit_sphere):
    V, F = unit_sphere
    s = sample_training_data(V, F, 200000, np.random.default_rng(3))
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


def test_surface_centres_are_the_shared_surface_samplers_points(unit_sphere):
    """One surface sampler: the 900 surface centres of 1000 samples are the first draws of the
    generator, i.e. exactly ``sample_surface(V, F, 900, same generator)``'s points (in float32)."""
    V, F = unit_sphere
    s = sample_training_data(V, F, 1000, np.random.default_rng(11))
    points, _ = sample_surface(V, F, 900, np.random.default_rng(11))
    assert np.array_equal(s.centres[s.group <= 2], points.astype(np.float32))


def test_same_stream_same_samples_other_seed_differs(unit_sphere):
    """The run layer passes the sampler stream of (shape, seed) (foundation.seeding)."""
    V, F = unit_sphere
    a = sample_training_data(V, F, 5000, job_streams("shape-a", 7).sampler_rng())
    b = sample_training_data(V, F, 5000, job_streams("shape-a", 7).sampler_rng())
    c = sample_training_data(V, F, 5000, job_streams("shape-a", 8).sampler_rng())
    assert np.array_equal(a.segments, b.segments) and np.array_equal(a.group, b.group)
    assert not np.array_equal(a.points, c.points)


def test_rejects_non_positive_count_and_a_seed_instead_of_a_generator(unit_sphere):
    with pytest.raises(ValueError, match="positive"):
        sample_training_data(*unit_sphere, 0, np.random.default_rng(0))
    # a bare seed would be a second seed derivation: refused in one line
    with pytest.raises(TypeError, match="^rng must be a numpy.random.Generator, got int$"):
        sample_training_data(*unit_sphere, 100, 7)
