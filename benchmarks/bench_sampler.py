"""Speed of the shared sampler (docs/PROTOCOL.md, "Shared sampler"): five-group points + segments for one shape.

    .venv/bin/python -m pytest benchmarks/bench_sampler.py -o python_files='bench_*.py' --benchmark-enable
"""

import pytest

from foundation.sampler import sample_training_data
from foundation.seeding import job_streams
from datasets import get_dataset


@pytest.fixture(scope="module")
def shape():
    ds = get_dataset("builtin")
    return ds.load(ds.names()[0])


@pytest.mark.parametrize("total", [200_000, 2_000_000])
def test_sample_training_data(benchmark, shape, total):
    def draw():  # the run layer's stream of (shape, seed 0), fresh for every round
        return sample_training_data(shape.vertices, shape.faces, total, job_streams(shape.content_hash, 0).sampler_rng())

    samples = benchmark(draw)
    assert len(samples) == total
