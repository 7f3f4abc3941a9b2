"""Speed of foundation.metrics.evaluate (docs/PROTOCOL.md, "Metrics") on a real ABC mesh vs a perturbed copy.

Goal: all metrics for one pair at n = 1,000,000 in <= 15 s on 2 cores.

    .venv/bin/pytest benchmarks/bench_metrics.py --benchmark-enable     # pytest-benchmark table
    .venv/bin/python benchmarks/bench_metrics.py [N ...]               # per-stage seconds

The prediction is the GT with every vertex moved by Gaussian noise (sigma = 1e-3, canonical frame,
seed 1): same topology, slightly rough normals, so every stage (sampling, both KD-tree directions,
both edge-point searches, ECD/EF1, validity) does its usual amount of work. It stays watertight, so
the volumetric IoU is computed too, and the noise makes a few faces cross (self-intersections).

The metrics added with the IoU are timed side by side with the rest: the ``iou`` and
``self_intersections`` stages of ``evaluate``, and the two that run inside older stages, the
distance distribution (in ``distances``: quantiles of the 2n pooled nearest distances, timed on
2n values) and the Euler characteristic (in ``validity``: one ``np.unique`` of the faces); "without"
is the total less these four. The self-intersection search is also timed on a 270,000-face
prediction (the noisy GT subdivided twice, its first 270,000 faces).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from foundation.metrics import distance_distribution, evaluate, self_intersections, volumetric_iou  # noqa: E402
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


def prediction_270k():
    """The noisy GT (:func:`gt_and_perturbed`) midpoint-subdivided twice (522,624 faces) and moved by
    the same noise again: its first 270,000 faces."""
    import trimesh

    _, _, pv, pf = gt_and_perturbed()
    v, f = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(pv, pf))
    v = v + np.random.default_rng(1).normal(scale=1e-3, size=v.shape)
    return v, f[:270_000]


def new_metric_seconds(result: dict, faces: np.ndarray) -> dict:
    """Seconds of the metrics added with the IoU in one ``evaluate`` result (module docstring)."""
    n = result["n_points"]
    pooled = np.abs(np.random.default_rng(0).normal(size=(2, n)))
    t = time.perf_counter()
    distance_distribution(pooled[0], pooled[1])
    distribution_s = time.perf_counter() - t
    t = time.perf_counter()
    np.unique(faces)
    euler_s = time.perf_counter() - t
    new = {"iou": result["seconds"]["iou_s"], "self_intersections": result["seconds"]["self_intersections_s"],
           "distance_distribution": distribution_s, "euler": euler_s}
    return {**new, "new_total": sum(new.values()), "without_new": result["seconds"]["total_s"] - sum(new.values())}


@pytest.mark.parametrize("n_points", [100_000, 1_000_000])
def test_evaluate_speed(benchmark, pair, n_points):
    gv, gf, pv, pf = pair
    result = benchmark.pedantic(evaluate, args=(gv, gf, pv, pf), kwargs={"n_points": n_points}, rounds=1, iterations=1)
    benchmark.extra_info.update({k: round(v, 3) for k, v in result["seconds"].items()})
    assert np.isfinite(result["cd"]) and result["gt_edge_points"] > 0


def test_new_stages_speed(benchmark, pair):
    """The IoU (100,000 points, both meshes) and the self-intersection search of the noisy copy."""
    gv, gf, pv, pf = pair

    def stages():
        return volumetric_iou(gv, gf, pv, pf, np.random.default_rng(0)), self_intersections(pv, pf)

    iou, crossings = benchmark.pedantic(stages, rounds=1, iterations=1)
    assert 0.9 < iou <= 1.0 and crossings["self_intersecting_pairs"] >= 0


if __name__ == "__main__":
    sizes = [int(a) for a in sys.argv[1:]] or [100_000, 1_000_000]
    gv, gf, pv, pf = gt_and_perturbed()
    for n in sizes:
        r = evaluate(gv, gf, pv, pf, n_points=n)
        stages = ", ".join(f"{k} {v:.2f}" for k, v in r["seconds"].items())
        print(f"n = {n:>9,}: {stages} s | CD {r['cd'] * 1e3:.4f}e-3 F1@0.005 {r['f1_005']:.4f} EF1 {r['ef1']:.4f}")
        new = new_metric_seconds(r, pf)
        print("    new metrics: " + ", ".join(f"{k} {v:.3f}" for k, v in new.items()) + " s | "
              f"IoU {r['iou']:.4f}, Hausdorff {r['hausdorff']:.4f}, genus {r['genus']:g}, "
              f"self-intersecting pairs {r['self_intersecting_pairs']}")
    v270, f270 = prediction_270k()
    t = time.perf_counter()
    crossings = self_intersections(v270, f270)
    print(f"self-intersections of a {len(f270):,}-face prediction: {time.perf_counter() - t:.2f} s, {crossings}")
