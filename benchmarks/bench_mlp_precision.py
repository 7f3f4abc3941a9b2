"""One fitting step of a plain Softplus MLP in float32 and in bfloat16 (the budget field ``precision``),
per network size, on this CPU: the measurement behind the `mlp` budget (docs/PERFORMANCE.md, section 17).

Print the table (one torch thread, medians of interleaved repetitions, ms per step, denormals
flushed as in every fit; the float32/bfloat16 ratio of each size is measured side by side):
    .venv/bin/python -m benchmarks.bench_mlp_precision [--threads 1] [--rounds 15] [--methods sals sdf]
or as pytest-benchmark (the `mlp` budget's network, both precisions):
    .venv/bin/pytest benchmarks/bench_mlp_precision.py -o python_files='bench_*.py' --benchmark-enable -q

A step is :func:`methods.core.fitting.fit`'s: a random batch of the budget's size, the method's
``predict`` under :func:`methods.core.device.autocast`, its loss on the float32 prediction, backward
and AdamW. On a CPU without bfloat16 instructions the bfloat16 column is torch's emulation (slow);
the runner refuses such fits (:func:`methods.core.device.precision_unavailable`).
"""

from __future__ import annotations

import argparse

import pytest
import torch

from benchmarks.bench_network import _interleaved, _sphere_data
from methods.base import get_method
from methods.core.device import PRECISIONS, autocast, flush_denormals, precision_unavailable
from methods.core.fitting import BUDGETS, as_float32, make_optimizer
from methods.core.network import make_network

#: (depth, width) of the networks compared: the paper's, then CPU sizes (the `mlp` budget's is 5 x 256).
SIZES = ((9, 512), (6, 256), (5, 256), (4, 256), (5, 128))
ROWS = 200_000


def make_step(method_name: str, depth: int, width: int, precision: str, batch: int | None = None):
    """A closure running one fitting step of ``method_name``'s plain MLP at ``precision``."""
    method = get_method(method_name)
    budget = BUDGETS["mlp"]
    torch.manual_seed(0)
    model = make_network(method.input_dim, method.output_dim, depth=depth, width=width, beta=budget.beta,
                         activation=budget.activation)
    optimizer = make_optimizer(model, budget)
    generator = torch.Generator().manual_seed(0)
    data = _sphere_data(ROWS, generator)
    inputs = data.points if method.input_dim == 3 else data.segments
    B = batch or budget.batch_size

    def step():
        idx = torch.randint(0, ROWS, (B,), generator=generator)
        optimizer.zero_grad(set_to_none=True)
        with flush_denormals():
            with autocast(precision, "cpu"):
                prediction = method.predict(model, inputs[idx])
            loss = method.loss(as_float32(prediction), {k: v[idx] for k, v in data.targets.items()})
            loss.backward()
            optimizer.step()

    return step


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_mlp_precision", description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--methods", nargs="+", default=["sals", "sdf"])
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    native = precision_unavailable("bfloat16", "cpu")
    print(f"bfloat16 here: {'native' if native is None else 'emulated (' + native + ')'}; "
          f"{args.threads} thread(s), batch {BUDGETS['mlp'].batch_size}")
    print("| method | network | float32 ms/step | bfloat16 ms/step | float32 / bfloat16 |")
    print("|---|---|---|---|---|")
    for name in args.methods:
        for depth, width in SIZES:
            ms = _interleaved({p: make_step(name, depth, width, p) for p in PRECISIONS}, args.rounds)
            print(f"| {name} | {depth} x {width} | {1e3 * ms['float32']:.1f} | {1e3 * ms['bfloat16']:.1f} | "
                  f"{ms['float32'] / ms['bfloat16']:.2f} |", flush=True)
    return 0


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("method_name", ["sals", "sdf"])
def test_mlp_step(benchmark, method_name, precision):
    if precision != "float32" and precision_unavailable(precision, "cpu"):
        pytest.skip(precision_unavailable(precision, "cpu"))
    budget = BUDGETS["mlp"]
    benchmark(make_step(method_name, budget.depth, budget.width, precision))


if __name__ == "__main__":
    raise SystemExit(main())
