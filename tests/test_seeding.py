"""foundation.seeding: the job's streams, and that the first three are those of a three-way spawn
(the calibration stream is spawned fourth)."""

from __future__ import annotations

import numpy as np

from foundation.seeding import job_seed_sequence, job_streams


def test_the_first_three_streams_are_those_of_a_three_way_spawn():
    streams = job_streams("abc123", 7)
    sampler, fitting, metrics = job_seed_sequence("abc123", 7).spawn(3)
    for mine, theirs in ((streams.sampler, sampler), (streams.fitting, fitting), (streams.metrics, metrics)):
        np.testing.assert_array_equal(mine.generate_state(4), theirs.generate_state(4))
    assert not np.array_equal(streams.calibration.generate_state(4), streams.metrics.generate_state(4))


def test_streams_depend_on_the_shape_content_and_the_seed_only():
    a, b = job_streams("abc123", 0), job_streams("abc123", 0)
    assert a.fitting_seed() == b.fitting_seed()
    assert a.fitting_seed() != job_streams("abc123", 1).fitting_seed() != job_streams("abd123", 0).fitting_seed()
