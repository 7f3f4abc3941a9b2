"""Speed of benchmark.metrics.evaluate (docs/PROTOCOL.md, "Metrics") on a real ABC mesh vs a perturbed copy.

Goal: all metrics for one pair at n = 1,000,000 in <= 15 s on 2 cores.

    .venv/bin/pytest benchmarks/bench_metrics.py --benchmark-enable     # pytest-benchmark table
    .venv/bin/python benchmarks/bench_metrics.py [N ...]               # per-stage seconds

The prediction is the GT with every vertex moved by Gaussian noise (sigma = 1e-3, canonical frame,
seed 1): same topology, slightly rough normals, so every stage (sampling, both KD-tree directions,
both edge-point searches, ECD/EF1, validity) does its usual amount of work.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmark.metrics import evaluate  # noqa: E402
from datasets.io import load_shape  # noqa: E402
from tests.conftest import SHARED_DATA  # noqa: E402

MESH = SHARED_DATA / "abc" / "00000006_0.obj"  # ABC 00000006, 32,664 faces, watertight


def gt_and_perturbed():
    shape = load_shape(MESH)
    noise = np.random.default_rng(1).normal(scale=1e-3, size=shape.vertices.shape)
    return shape.vertices, shape.faces, shape.vertices + noise, shape.faces


@pytest.fixture(scope="module")
def pair():
    if not MESH.exists():
        pytest.skip(f"{MESH} is absent: the metrics benchmark needs ../shared/data beside the checkout")
    return gt_and_perturbed()


@pytest.mark.parametrize("n_points", [100_000, 1_000_000])
def test_evaluate_speed(benchmark, pair, n_points):
    gv, gf, pv, pf = pair
    result = benchmark.pedantic(evaluate, args=(gv, gf, pv, pf), kwargs={"n_points": n_points}, rounds=1, iterations=1)
    benchmark.extra_info.update({k: round(v, 3) for k, v in result["seconds"].items()})
    assert np.isfinite(result["cd"]) and result["gt_edge_points"] > 0


if __name__ == "__main__":
    sizes = [int(a) for a in sys.argv[1:]] or [100_000, 1_000_000]
    gv, gf, pv, pf = gt_and_perturbed()
    for n in sizes:
        r = evaluate(gv, gf, pv, pf, n_points=n)
        stages = ", ".join(f"{k} {v:.2f}" for k, v in r["seconds"].items())
        print(f"n = {n:>9,}: {stages} s | CD {r['cd'] * 1e3:.4f}e-3 F1@0.005 {r['f1_005']:.4f} EF1 {r['ef1']:.4f}")
