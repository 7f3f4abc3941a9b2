"""Speed of the exact fields (foundation/fields.py) on the biggest ABC mesh in ../shared/data/abc.

Run:  .venv/bin/pytest benchmarks/bench_fields.py -o python_files='bench_*.py' --benchmark-enable -q
Target: the four 128^3 grid fields (occupancy, sdf, udf + gradient, grid-edge LSF) of a ~40k-face
ABC mesh in <= 15 s on 2 cores (``test_all_four_grid_fields``). Every field benchmark builds a fresh
:class:`ExactFields` (cold: acceleration structures and the shared distance band included).
"""

from __future__ import annotations

import numpy as np
import pytest

from foundation.fields import ExactFields
from foundation.grid import edge_endpoints
from datasets.io import load_shape
from tests.conftest import SHARED_DATA

MESH = SHARED_DATA / "abc" / "00000006_d4fe04f0f5f84b52bd4f10e4_trimesh_001.stl"  # 37,288 faces
N = 128

pytestmark = pytest.mark.skipif(not MESH.exists(), reason=f"{MESH} is absent (needs ../shared/data)")


@pytest.fixture(scope="module")
def shape():
    return load_shape(MESH)


def fresh(shape):
    return (ExactFields(shape.vertices, shape.faces),), {}


@pytest.mark.parametrize("field", ["occupancy", "sdf", "udf_grad", "edges"])
def test_grid_field(benchmark, shape, field):
    def run(f):
        if field == "udf_grad":
            return f.grid_udf_with_grad(N)
        if field == "edges":
            return f.grid_edges(N)
        return f.grid_scalar(N, field)

    benchmark.extra_info.update(faces=len(shape.faces), N=N)
    benchmark.pedantic(run, setup=lambda: fresh(shape), rounds=1, iterations=1)


def test_all_four_grid_fields(benchmark, shape):
    """One ExactFields for all four (sdf and udf_grad share the narrow-band distance pass)."""

    def run(f):
        f.grid_scalar(N, "occupancy")
        f.grid_scalar(N, "sdf")
        f.grid_udf_with_grad(N)
        f.grid_edges(N)

    benchmark.extra_info.update(faces=len(shape.faces), N=N)
    benchmark.pedantic(run, setup=lambda: fresh(shape), rounds=1, iterations=1)


def test_segments_throughput(benchmark, shape):
    """1M random segments (like the shared sampler's: centres in the box, endpoint noise sigma 0.05)."""
    rng = np.random.default_rng(0)
    u = rng.uniform(-1, 1, (1_000_000, 3))
    v = u + rng.normal(0, 0.05, u.shape)
    f = ExactFields(shape.vertices, shape.faces)
    f.segments(u[:10], v[:10])  # build the embree scene outside the timing
    benchmark.extra_info.update(faces=len(shape.faces), segments=len(u))
    benchmark.pedantic(f.segments, args=(u, v), rounds=3, iterations=1)


def test_segments_all_grid_edges(benchmark, shape):
    """Reference: one embree ray per edge for all 6.2M edges of the 128^3 grid (what grid_edges avoids)."""
    u, v = edge_endpoints(N, dtype=np.float64)
    f = ExactFields(shape.vertices, shape.faces)
    f.segments(u[:10], v[:10])
    benchmark.pedantic(f.segments, args=(u, v), rounds=1, iterations=1)
