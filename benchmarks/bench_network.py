"""Training throughput of the MLP with torch's Softplus(100), the clamped Softplus and ReLU.

Run the ratio table (interleaved steps, one process; medians):
    .venv/bin/python benchmarks/bench_network.py [threads] [rounds]
or as pytest-benchmark:  .venv/bin/pytest benchmarks/bench_network.py -o python_files='bench_*.py' --benchmark-enable -q

Nets: the *paper* net (3 -> 9 x 512 -> 1) at batch 4,096 and the *quick* net (3 -> 5 x 128 -> 1) at
batch 2,048; AdamW step on an L1 sphere-SDF loss; inputs near a sphere like the sampler's.
Value equality of the activations is a test (tests/test_network.py), not measured here.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest
import torch

from methods.network import make_network

NETS = {"paper": (9, 512, 4096), "quick": (5, 128, 2048)}
ACTS = ("softplus", "softplus-clamped", "relu")


def make_step(net_name: str, activation: str):
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


@pytest.mark.parametrize("net_name", list(NETS))
@pytest.mark.parametrize("activation", ACTS)
def test_train_step(benchmark, net_name, activation):
    step, _ = make_step(net_name, activation)
    step()
    benchmark(step)


def main(threads=2, rounds=7):
    torch.set_num_threads(int(threads))
    print(f"torch threads={torch.get_num_threads()}, rounds={rounds} (median step, interleaved)")
    for net_name in NETS:
        steps = {a: make_step(net_name, a) for a in ACTS}
        times = {a: [] for a in ACTS}
        for a, (s, _) in steps.items():
            s()  # warm-up
        for _ in range(int(rounds)):
            for a, (s, _) in steps.items():
                t = time.perf_counter()
                s()
                times[a].append(time.perf_counter() - t)
        batch = steps[ACTS[0]][1]
        med = {a: float(np.median(v)) for a, v in times.items()}
        row = ", ".join(f"{a} {batch / med[a]:,.0f} samples/s" for a in ACTS)
        print(f"{net_name:6s}: {row}; softplus/relu time ratio {med['softplus'] / med['relu']:.2f}, "
              f"clamped/torch softplus time ratio {med['softplus-clamped'] / med['softplus']:.2f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
