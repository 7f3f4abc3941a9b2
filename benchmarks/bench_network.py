"""Training-step cost of the networks: activations, the grid lookup, and the backbones per method.

Run the ratio tables (interleaved steps, one process; medians):
    .venv/bin/python -m benchmarks.bench_network [threads] [rounds]
(threads=1 on a machine others are using: docs/PERFORMANCE.md, section 3)
or as pytest-benchmark:  .venv/bin/pytest benchmarks/bench_network.py -o python_files='bench_*.py' --benchmark-enable -q

1. Activations: the *paper* MLP (3 -> 9 x 512 -> 1) at batch 4,096 and the *quick* MLP (3 -> 5 x 128
   -> 1) at batch 2,048 with torch's Softplus(100), the clamped Softplus and ReLU; AdamW step on an
   L1 sphere-SDF loss. Value equality of the activations is a test (tests/test_network.py).
2. Grid lookup: the *cpu* budget's grid network (head 3 x 64) at batch 4,096 with levels 16/32/64
   and 16/32/64/128, its trilinear gather (:func:`methods.core.network.trilinear`) against
   ``torch.nn.functional.grid_sample`` (same values: :class:`GridSampleFeatureGrid`), with a first
   order loss (L1 SDF) and a second-order one (the UDF loss: L1 + cosine of the autograd input
   gradient, ``create_graph``).
3. Backbones: one training step of each registered method's real loss under the *quick* budget
   (MLP) and the *cpu* budget (grid), with synthetic targets of the right kind (sphere |x| = 0.6);
   reported as seconds per step and samples per second.
All inputs lie near the sphere like the shared sampler's. Compare only ratios within one run.
"""

from __future__ import annotations

import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from methods.base import METHODS, get_method
from methods.core.fitting import BUDGETS, make_optimizer
from methods.core.network import FeatureGrid, make_network

NETS = {"paper": (9, 512, 4096), "quick": (5, 128, 2048)}
ACTS = ("softplus", "softplus-clamped", "relu")
LEVELS = {"16-64": (16, 32, 64), "16-128": (16, 32, 64, 128)}
LOOKUPS = ("gather", "grid_sample")
ORDERS = {"first": "sdf", "second": "udf"}
BACKBONE_BUDGETS = ("quick", "cpu")
RADIUS = 0.6


class GridSampleFeatureGrid(FeatureGrid):
    """The same feature grid looked up with ``grid_sample`` (trilinear, align_corners, border).

    Built from a :class:`FeatureGrid` (same values); levels are stored as (1, C, R, R, R) volumes, the
    layout ``grid_sample`` reads without a copy (volume[c, k, j, i] is the feature at grid point
    (i, j, k), since grid_sample's x indexes the last axis).
    """

    def __init__(self, grid: FeatureGrid):
        super().__init__(grid.resolutions, grid.channels)
        with torch.no_grad():
            self.levels = torch.nn.ParameterList(torch.nn.Parameter(level.permute(3, 2, 1, 0)[None].contiguous())
                                                 for level in grid.levels)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        where = points.reshape(1, -1, 1, 1, 3)
        return torch.cat([F.grid_sample(level, where, mode="bilinear", padding_mode="border", align_corners=True)
                          .reshape(self.channels, -1).t() for level in self.levels], dim=1)


def _sphere_data(n: int, generator: torch.Generator) -> SimpleNamespace:
    """Points near the sphere |x| = RADIUS, segments of length ~0.02 from them, and every target kind."""
    p = torch.randn(n, 3, generator=generator)
    p = RADIUS * p / p.norm(dim=1, keepdim=True) + 0.02 * torch.randn(n, 3, generator=generator)
    q = p + 0.02 * torch.randn(n, 3, generator=generator)
    du, dv = p.norm(dim=1) - RADIUS, q.norm(dim=1) - RADIUS
    hit = (du * dv <= 0).float()
    s = (dv / (dv - du).where(du != dv, torch.ones_like(du))).clamp(0, 1)  # hit point s u + (1 - s) v
    targets = {"sdf": du, "udf": du.abs(), "grad": p / p.norm(dim=1, keepdim=True) * du.sign()[:, None],
               "occupancy": (du < 0).float(), "o": hit, "s": s * hit}
    return SimpleNamespace(points=p, segments=torch.cat([p, q], dim=1), targets=targets)


def _train_step(method, model, budget_name: str, batch: int, data: SimpleNamespace, generator: torch.Generator):
    """One step of ``method.loss`` on ``model`` with the budget's optimizer (its groups, its kernel)."""
    optimizer = make_optimizer(model, BUDGETS[budget_name])
    inputs = data.points if method.input_dim == 3 else data.segments

    def step():
        idx = torch.randint(0, len(inputs), (batch,), generator=generator)
        optimizer.zero_grad(set_to_none=True)
        loss = method.loss(method.predict(model, inputs[idx]), {k: v[idx] for k, v in data.targets.items()})
        loss.backward()
        optimizer.step()

    return step


def make_activation_step(net_name: str, activation: str):
    depth, width, batch = NETS[net_name]
    torch.manual_seed(0)
    net = make_network(3, 1, depth=depth, width=width, activation=activation)
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3)
    g = torch.Generator().manual_seed(0)
    P = torch.randn(100_000, 3, generator=g)
    P = 0.6 * P / P.norm(dim=1, keepdim=True) + 0.01 * torch.randn(100_000, 3, generator=g)
    Y = P.norm(dim=1) - 0.6

    def step():
        idx = torch.randint(0, len(P), (batch,), generator=g)
        opt.zero_grad()
        loss = (net(P[idx])[:, 0] - Y[idx]).abs().mean()
        loss.backward()
        opt.step()

    return step, batch


def make_lookup_step(levels: str, lookup: str, order: str):
    """A *cpu*-budget training step of the grid network with ``levels`` and ``lookup`` (gather or grid_sample)."""
    b = BUDGETS["cpu"]
    torch.manual_seed(0)
    net = make_network(3, 1, depth=b.depth, width=b.width, beta=b.beta, activation=b.activation, backbone="grid",
                       grid_resolutions=LEVELS[levels], grid_channels=b.grid_channels)
    if lookup == "grid_sample":
        net.encoder = GridSampleFeatureGrid(net.encoder)
    g = torch.Generator().manual_seed(0)
    return _train_step(get_method(ORDERS[order]), net, "cpu", b.batch_size, _sphere_data(100_000, g), g), b.batch_size


def make_backbone_step(method_name: str, budget_name: str):
    """One step of ``method_name``'s loss on the network of ``budget_name`` at its batch size."""
    b = BUDGETS[budget_name]
    method = get_method(method_name)
    torch.manual_seed(0)
    net = make_network(method.input_dim, method.output_dim, **b.network_config())
    g = torch.Generator().manual_seed(0)
    return _train_step(method, net, budget_name, b.batch_size, _sphere_data(100_000, g), g), b.batch_size


@pytest.mark.parametrize("net_name", list(NETS))
@pytest.mark.parametrize("activation", ACTS)
def test_train_step(benchmark, net_name, activation):
    step, _ = make_activation_step(net_name, activation)
    step()
    benchmark(step)


@pytest.mark.parametrize("order", list(ORDERS))
@pytest.mark.parametrize("levels", list(LEVELS))
@pytest.mark.parametrize("lookup", LOOKUPS)
def test_grid_lookup_step(benchmark, lookup, levels, order):
    step, _ = make_lookup_step(levels, lookup, order)
    step()
    benchmark(step)


@pytest.mark.parametrize("budget_name", BACKBONE_BUDGETS)
@pytest.mark.parametrize("method_name", sorted(METHODS.names()))
def test_backbone_step(benchmark, method_name, budget_name):
    step, _ = make_backbone_step(method_name, budget_name)
    step()
    benchmark(step)


def _interleaved(steps: dict, rounds: int) -> dict:
    """Median seconds per call of each step, calls interleaved round by round (after one warm-up)."""
    times = {key: [] for key in steps}
    for s in steps.values():
        s()
    for _ in range(int(rounds)):
        for key, s in steps.items():
            t = time.perf_counter()
            s()
            times[key].append(time.perf_counter() - t)
    return {key: float(np.median(v)) for key, v in times.items()}


def main(threads=2, rounds=7):
    torch.set_num_threads(int(threads))
    print(f"torch threads={torch.get_num_threads()}, rounds={rounds} (median step, interleaved)")
    print("1. activations")
    for net_name in NETS:
        batch = NETS[net_name][2]
        med = _interleaved({a: make_activation_step(net_name, a)[0] for a in ACTS}, rounds)
        row = ", ".join(f"{a} {batch / med[a]:,.0f} samples/s" for a in ACTS)
        print(f"  {net_name:6s}: {row}; softplus/relu time ratio {med['softplus'] / med['relu']:.2f}, "
              f"clamped/torch softplus time ratio {med['softplus-clamped'] / med['softplus']:.2f}")
    print("2. grid lookup (cpu budget network, batch 4,096): ms/step, grid_sample/gather time ratio")
    for order in ORDERS:
        for levels in LEVELS:
            med = _interleaved({k: make_lookup_step(levels, k, order)[0] for k in LOOKUPS}, rounds)
            print(f"  levels {levels:6s} {order:6s}-order loss: gather {1e3 * med['gather']:7.1f} ms, "
                  f"grid_sample {1e3 * med['grid_sample']:7.1f} ms, ratio {med['grid_sample'] / med['gather']:.2f}")
    print("3. backbones (each method's loss): ms/step and samples/s, cpu(grid)/quick(mlp) time ratio")
    for method_name in sorted(METHODS.names()):
        steps = {b: make_backbone_step(method_name, b) for b in BACKBONE_BUDGETS}
        med = _interleaved({b: s for b, (s, _) in steps.items()}, rounds)
        row = ", ".join(f"{b} {1e3 * med[b]:6.1f} ms ({steps[b][1] / med[b]:,.0f} samples/s)" for b in BACKBONE_BUDGETS)
        print(f"  {method_name:5s}: {row}; ratio {med['cpu'] / med['quick']:.2f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
