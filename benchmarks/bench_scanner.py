"""Speed of the virtual range scanner (foundation/scanner.py) against the area-uniform sampler, 40k points.

    OMP_NUM_THREADS=1 taskset -c 0 .venv/bin/python -m pytest benchmarks/bench_scanner.py \
        -o python_files='bench_*.py' --benchmark-enable

Target: ``scan_cloud`` (10 sensors at 3.0, pilot cast + final cast + subsample, embree scene built
inside the call) adds <= 2 s per shape at 40k points on one core, on a ~30k-face ABC mesh in the
canonical frame. ``sample_surface`` at 40k points is the side-by-side reference; the corruption
rungs that scan more than the clean scan (``density-3``: 2.5 n) are timed too.
"""

from __future__ import annotations

import numpy as np
import pytest

from foundation.corruptions import input_cloud
from foundation.scanner import scan_cloud
from foundation.surface import sample_surface
from datasets.io import load_shape
from tests.conftest import SHARED_DATA

MESH = SHARED_DATA / "abc" / "00000006_0.obj"  # ABC 00000006, 32,664 faces, watertight
N = 40_000

pytestmark = pytest.mark.skipif(not MESH.exists(), reason=f"{MESH} is absent (needs ../shared/data)")


@pytest.fixture(scope="module")
def shape():
    return load_shape(MESH)


def test_sample_surface(benchmark, shape):
    points, _ = benchmark(lambda: sample_surface(shape.vertices, shape.faces, N, np.random.default_rng(0)))
    benchmark.extra_info.update(faces=len(shape.faces), n=N)
    assert len(points) == N


def test_scan_cloud(benchmark, shape):
    scan = benchmark.pedantic(lambda: scan_cloud(shape.vertices, shape.faces, N, np.random.default_rng(0)),
                              rounds=5, iterations=1)
    benchmark.extra_info.update(faces=len(shape.faces), n=N)
    assert len(scan) == N


@pytest.mark.parametrize("corruption", ["noise-3", "density-3"])
def test_input_cloud(benchmark, shape, corruption):
    cloud = benchmark.pedantic(lambda: input_cloud(shape.vertices, shape.faces, N, corruption, np.random.default_rng(0)),
                               rounds=3, iterations=1)
    benchmark.extra_info.update(faces=len(shape.faces), n=N)
    assert len(cloud) == N
