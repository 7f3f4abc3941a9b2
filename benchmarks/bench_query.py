"""Sparse vs dense grid queries at 128^3 (methods/core/query.py), and grid edges with shared endpoints.

Run the ratio table (interleaved, one process):  .venv/bin/python -m benchmarks.bench_query [N] [threads]
SALS's query + normals against SDF's query on networks fitted at the *cpu* budget (one thread, medians
of 3 interleaved; fits SALS and SDF on each mesh first):
    .venv/bin/python -m benchmarks.bench_query --fitted MESH [MESH ...]
or as pytest-benchmark:  .venv/bin/pytest benchmarks/bench_query.py -o python_files='bench_*.py' --benchmark-enable -q
Goal: sparse / dense query time <= 0.2 at N = 128 for points (sdf) and edges (sals, 6.24M edges dense).
Also: a band of grid edges through ``evaluate_grid_edges`` (each endpoint encoded once) against the plain
per-edge forward, with the *cpu* budget's grid network (16/32/64 x 4, 3 x 64 head); the ratios
measured: docs/PERFORMANCE.md, section 6.

The network is the *quick* architecture (5 linear layers, width 128) whose output is replaced by an
analytic sphere field (radius 0.6; points: signed distance; edges: hit logit +-30 and the linear
crossing parameter), so the cost is a real network's while the marked blocks are a real surface's.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from foundation.grid import edge_inputs
from methods.core import query
from methods.core.fitting import BUDGETS
from methods.core.network import make_network

R = 0.6


class CostlySphere(torch.nn.Module):
    """The quick MLP's cost, the sphere's values (see module docstring)."""

    def __init__(self, in_dim):
        super().__init__()
        b = BUDGETS["quick"]
        self.mlp = make_network(in_dim, 2 if in_dim == 6 else 1, depth=b.depth, width=b.width)
        self.config = self.mlp.config
        self.in_dim = in_dim

    def forward(self, x):
        cost = self.mlp(x) * 0.0
        if self.in_dim == 3:
            return (x.norm(dim=1) - R)[:, None] + cost
        fu, fv = x[:, :3].norm(dim=1) - R, x[:, 3:].norm(dim=1) - R
        hit = fu * fv <= 0
        tau = (fu / (fu - fv).where(fu != fv, torch.ones_like(fu))).clamp(1e-4, 1 - 1e-4)
        s = 1 - tau
        return torch.stack([torch.where(hit, 30.0, -30.0), torch.log(s / (1 - s))], 1) + cost


def dense_points(N):
    return query.dense_grid_points(CostlySphere(3), N)


def sparse_points(N):
    return query.sparse_grid_points(CostlySphere(3), N, query.near_level(0.0, query.block_half_diagonal(N)))


def dense_edges(N):
    return query.dense_grid_edges(CostlySphere(6), N)


def sparse_edges(N):
    return query.sparse_grid_edges(CostlySphere(6), N, lambda v: v[:, 0] > np.log(0.02 / 0.98),
                                   edge_fill=np.array([-30.0, 0.0], np.float32))


def band_edges(N, width=0.05):
    """Flat ids of the grid edges whose midpoint lies within ``width`` of the sphere |x| = R (a surface
    band like the sparse query's), and the cpu budget's segment network with random grid values."""
    u, v = edge_inputs(N).reshape(-1, 2, 3).transpose(1, 0, 2)
    ids = np.flatnonzero(np.abs(np.linalg.norm((u + v) / 2, axis=1) - R) < width)
    net = make_network(6, 2, **BUDGETS["cpu"].network_config())
    with torch.no_grad():
        for level in net.encoder.levels:
            level.normal_(0, 0.1)
    return net, ids


def plain_edges(net, N, ids):
    return query.evaluate(net, edge_inputs(N, ids))


def shared_endpoint_edges(net, N, ids):
    return query.evaluate_grid_edges(net, N, ids)


@pytest.mark.parametrize("fn", [dense_points, sparse_points, dense_edges, sparse_edges])
def test_query_128(benchmark, fn):
    benchmark.pedantic(fn, args=(128,), rounds=1, iterations=1)


@pytest.mark.parametrize("fn", [plain_edges, shared_endpoint_edges])
def test_band_edges_128(benchmark, fn):
    net, ids = band_edges(128)
    benchmark.pedantic(fn, args=(net, 128, ids), rounds=3, iterations=1)


def main(N=128, threads=None):
    if threads:
        torch.set_num_threads(int(threads))
    torch.manual_seed(0)
    rows = []
    for kind, dense, sparse in (("points", dense_points, sparse_points), ("edges", dense_edges, sparse_edges)):
        t0 = time.perf_counter()
        d = dense(N)
        t1 = time.perf_counter()
        s, evaluated, info = sparse(N)
        t2 = time.perf_counter()
        if kind == "points":
            agree = float((np.sign(s[..., 0]) == np.sign(d[..., 0])).mean())
        else:
            agree = float(((s[:, 0] > 0) == (d[:, 0] > 0)).mean())
        rows.append((kind, t1 - t0, t2 - t1, (t2 - t1) / (t1 - t0), info.fraction, agree))
    print(f"N={N}, torch threads={torch.get_num_threads()}; quick MLP (5 x 128) cost, sphere r={R} values")
    print(f"{'kind':7s} {'dense s':>8s} {'sparse s':>9s} {'time ratio':>10s} {'evaluated':>10s} {'agreement':>10s}")
    for kind, td, ts, ratio, frac, agree in rows:
        print(f"{kind:7s} {td:8.2f} {ts:9.2f} {ratio:10.3f} {frac:10.3f} {agree:10.5f}")
    net, ids = band_edges(N)
    times = {fn.__name__: [] for fn in (plain_edges, shared_endpoint_edges)}
    for _ in range(3):  # interleaved rounds, medians
        for fn in (plain_edges, shared_endpoint_edges):
            t0 = time.perf_counter()
            fn(net, N, ids)
            times[fn.__name__].append(time.perf_counter() - t0)
    plain, shared = (float(np.median(t)) for t in times.values())
    print(f"band of {len(ids):,} edges, cpu grid network: plain {plain:.2f} s, shared endpoints {shared:.2f} s, "
          f"ratio {shared / plain:.3f}")


def fitted_query_ratio(path, N: int = 128, budget: str = "cpu", rounds: int = 3) -> dict:
    """Seconds of SALS's ``neural_grid`` (edge query + normals) and SDF's (point query) on networks
    fitted to the mesh at ``path`` (seed 0), one torch thread, medians of ``rounds`` interleaved."""
    from foundation.fields import ExactFields
    from foundation.sampler import sample_training_data
    from datasets.io import load_shape
    from methods.base import get_method
    from methods.core.fitting import fit, get_budget

    torch.set_num_threads(1)
    shape = load_shape(path)
    b = get_budget(budget)
    samples = sample_training_data(shape.vertices, shape.faces, b.num_samples, np.random.default_rng(0))
    fields = ExactFields(shape.vertices, shape.faces)
    queries = {}
    for name in ("sals", "sdf"):
        method = get_method(name)
        model = fit(method, samples, method.training_targets(fields, samples), b, seed=0).model
        queries[name] = lambda method=method, model=model: method.neural_grid(model, N, "cpu")
    times = {name: [] for name in queries}
    for _ in range(rounds):
        for name, run in queries.items():
            t0 = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - t0)
    sals, sdf = (float(np.median(times[name])) for name in ("sals", "sdf"))
    return {"sals": sals, "sdf": sdf, "ratio": sals / sdf}


if __name__ == "__main__":
    if sys.argv[1:2] == ["--fitted"]:
        print("| part | SALS s | SDF s | ratio |\n|---|---|---|---|")
        for mesh in sys.argv[2:]:
            r = fitted_query_ratio(mesh)
            print(f"| {Path(mesh).name.split('_')[0]} | {r['sals']:.2f} | {r['sdf']:.2f} | {r['ratio']:.2f} |", flush=True)
    else:
        main(*(int(a) for a in sys.argv[1:]))
