"""Where a fitting step's time goes, part by part, beside what the same core does on the same shapes.

Print the table (one torch thread, the *cpu* budget, medians of interleaved repetitions):
    .venv/bin/python -m benchmarks.bench_fit_profile [--threads 1] [--rounds 60] [--methods sals sdf udf bof]
Compare whole steps with the network code of another revision REV (its ``methods/core/network.py``,
batches gathered by advanced indexing), interleaved in one process:
    .venv/bin/python -m benchmarks.bench_fit_profile --against REV
Steps per second of the machine, 2 one-thread processes side by side against one 2-thread process:
    .venv/bin/python -m benchmarks.bench_fit_profile --throughput 2
or as pytest-benchmark (one whole step per method):
    .venv/bin/pytest benchmarks/bench_fit_profile.py -o python_files='bench_*.py' --benchmark-enable -q

Parts of one step of :func:`methods.core.fitting.fit` (each method's real loss and network, synthetic
targets of the right kind near the sphere |x| = 0.6, 1M training rows as in the budget), with
denormal floats flushed to zero as in every fit (``methods.core.device.flush_denormals``):

* ``batch``: the step's row draw and :func:`methods.core.fitting.gather_rows` of inputs and targets.
* ``grid fwd`` / ``grid bwd``: the feature grid's lookup of the batch's points (2 per segment) with
  the gradient to the grid values, forward alone and the backward (fwd+bwd minus fwd), with a fixed
  upstream gradient.
* ``head fwd`` / ``head bwd``: the MLP head on the batch's codes, likewise.
* ``loss + 2nd order``: the whole forward, loss and backward minus the four parts above: the loss,
  the concatenations, and for UDF the autograd input gradient and its backward (``create_graph``).
* ``optimizer``: AdamW's step over every weight (the grid's values with torch's fused kernel).
* ``rest``: the whole step minus all of the above (zeroing gradients, Python, allocation).

The hardware references, measured in the same run on the same core: ``torch.mm`` of the head's layer
shapes (forward: one product per layer; backward: the two products per layer autograd makes),
``grid_sample`` (trilinear, border) of the same points on the same levels, a memory copy of the
bytes AdamW reads and writes, and the peak of ``torch.mm`` at 1024^3. Compare ratios within one run.
"""

from __future__ import annotations

import argparse
import time

import pytest
import torch
import torch.nn.functional as F

from benchmarks.bench_network import _interleaved, _sphere_data
from methods.base import get_method
from methods.core.device import flush_denormals
from methods.core.fitting import BUDGETS, gather_rows, make_optimizer
from methods.core.network import SEGMENT_SCALE, make_network

METHODS = ("sals", "sdf", "udf", "bof")
TARGETS = {"sals": ("o", "s"), "sdf": ("sdf",), "udf": ("udf", "grad"), "bof": ("occupancy",)}
ROWS = 1_000_000


class Profile:
    """One method's network, optimizer and data at a budget, with a closure per part of a step."""

    def __init__(self, method_name: str, budget_name: str = "cpu", rows: int = ROWS):
        self.method = get_method(method_name)
        self.budget = BUDGETS[budget_name]
        torch.manual_seed(0)
        self.model = make_network(self.method.input_dim, self.method.output_dim, **self.budget.network_config())
        self.model.train()
        self.optimizer = make_optimizer(self.model, self.budget)
        generator = torch.Generator().manual_seed(0)
        data = _sphere_data(rows, generator)
        self.inputs = data.points if self.method.input_dim == 3 else data.segments
        self.targets = {key: data.targets[key] for key in TARGETS[method_name]}
        self.generator = generator
        self.B = self.budget.batch_size
        rows_ = torch.randint(0, rows, (self.B,), generator=generator)
        self.xb, self.tb = gather_rows(self.inputs, self.targets, rows_)
        self.points = self.xb.reshape(-1, 3)
        encoder = self.model.encoder
        self.codes_grad = torch.randn(len(self.points), encoder.out_dim, generator=generator)
        with torch.no_grad():
            codes = torch.cat([encoder(self.points), self.points], dim=1).reshape(self.B, -1)
            if self.model.k == 2:
                codes = torch.cat([codes, (self.xb[:, 3:] - self.xb[:, :3]) / SEGMENT_SCALE], dim=1)
        self.codes = codes
        self.head_grad = torch.randn(self.B, self.method.output_dim, generator=generator)
        self.layer_shapes = [(m.in_features, m.out_features) for m in self.model.head.modules()
                             if isinstance(m, torch.nn.Linear)]

    # the parts -----------------------------------------------------------------------------------
    def batch(self):
        rows = torch.randint(0, len(self.inputs), (self.B,), generator=self.generator)
        return gather_rows(self.inputs, self.targets, rows)

    def grid_fwd(self):
        return self.model.encoder(self.points)

    def grid_fwd_bwd(self):
        self.model.zero_grad(set_to_none=True)
        self.model.encoder(self.points).backward(self.codes_grad)

    def head_fwd(self):
        return self.model.head(self.codes)

    def head_fwd_bwd(self):
        self.model.zero_grad(set_to_none=True)
        self.model.head(self.codes).backward(self.head_grad)

    def forward_backward(self):
        self.model.zero_grad(set_to_none=True)
        self.method.loss(self.method.predict(self.model, self.xb), self.tb).backward()

    def optimizer_step(self):
        self.optimizer.step()

    def step(self):
        """One whole step as :func:`methods.core.fitting.fit` runs it."""
        x, t = self.batch()
        self.optimizer.zero_grad(set_to_none=True)
        self.method.loss(self.method.predict(self.model, x), t).backward()
        self.optimizer.step()

    # the references ------------------------------------------------------------------------------
    def references(self):
        """Closures of the hardware references for this method's shapes (module docstring)."""
        B, g = self.B, torch.Generator().manual_seed(1)
        acts = [torch.randn(B, i, generator=g) for i, _ in self.layer_shapes]
        weights = [torch.randn(o, i, generator=g) for i, o in self.layer_shapes]
        grads = [torch.randn(B, o, generator=g) for _, o in self.layer_shapes]
        volumes = [level.detach().permute(3, 2, 1, 0)[None].contiguous() for level in self.model.encoder.levels]
        where = self.points.reshape(1, -1, 1, 1, 3)
        n_params = sum(p.numel() for p in self.model.parameters())
        src, dst = torch.randn(n_params * 4), torch.empty(n_params * 3)

        def mm_fwd():
            for a, w in zip(acts, weights):
                a @ w.T

        def mm_bwd():
            for a, w, d in zip(acts, weights, grads):
                d @ w
                d.T @ a

        def grid_sample():
            for v in volumes:
                F.grid_sample(v, where, mode="bilinear", padding_mode="border", align_corners=True)

        def adam_bytes():  # AdamW reads weight, gradient and two moments and writes three
            dst.copy_(src[: len(dst)])
            src[: len(dst)].sum()

        return {"mm fwd": mm_fwd, "mm bwd": mm_bwd, "grid_sample": grid_sample, "adam bytes": adam_bytes}

    def head_flops(self) -> float:
        """Multiply-adds x 2 of the head's forward."""
        return 2.0 * self.B * sum(i * o for i, o in self.layer_shapes)


def _median_ms(closures: dict, rounds: int) -> dict:
    """Median milliseconds of each closure, calls interleaved round by round
    (:func:`benchmarks.bench_network._interleaved`)."""
    return {key: 1e3 * seconds for key, seconds in _interleaved(closures, rounds).items()}


def profile(method_name: str, rounds: int = 60, budget_name: str = "cpu") -> dict:
    """Milliseconds of each part of a step and of its references (module docstring)."""
    p = Profile(method_name, budget_name)
    parts = {"step": p.step, "batch": p.batch, "grid fwd": p.grid_fwd, "grid fwd+bwd": p.grid_fwd_bwd,
             "head fwd": p.head_fwd, "head fwd+bwd": p.head_fwd_bwd, "fwd+loss+bwd": p.forward_backward,
             "optimizer": p.optimizer_step}
    ms = _median_ms({**parts, **p.references()}, rounds)
    ms["grid bwd"] = ms["grid fwd+bwd"] - ms["grid fwd"]
    ms["head bwd"] = ms["head fwd+bwd"] - ms["head fwd"]
    ms["loss + 2nd order"] = ms["fwd+loss+bwd"] - ms["grid fwd+bwd"] - ms["head fwd+bwd"]
    ms["rest"] = ms["step"] - ms["batch"] - ms["fwd+loss+bwd"] - ms["optimizer"]
    ms["head GFLOP/s"] = 3 * p.head_flops() / (ms["head fwd+bwd"] * 1e6)
    ms["mm GFLOP/s"] = 3 * p.head_flops() / ((ms["mm fwd"] + ms["mm bwd"]) * 1e6)
    return ms


def peak_mm_gflops(size: int = 1024, rounds: int = 10) -> float:
    """GFLOP/s of ``torch.mm`` of two size x size float32 matrices on this core."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    ms = _median_ms({"mm": lambda: a @ b}, rounds)["mm"]
    return 2.0 * size ** 3 / (ms * 1e6)


ROWS_OF_TABLE = ("batch", "grid fwd", "grid bwd", "head fwd", "head bwd", "loss + 2nd order", "optimizer", "rest",
                 "step")
REFERENCE_OF = {"grid fwd": "grid_sample", "head fwd": "mm fwd", "head bwd": "mm bwd", "optimizer": "adam bytes"}


def markdown(results: dict, peak: float) -> str:
    """The profile table: ms per part and method, each with its reference's ms where it has one."""
    names = list(results)
    lines = ["| part | " + " | ".join(f"{m} ms (reference)" for m in names) + " |",
             "|---|" + "---|" * len(names)]
    for part in ROWS_OF_TABLE:
        cells = []
        for m in names:
            ref = REFERENCE_OF.get(part)
            cell = f"{results[m][part]:.2f}"
            cells.append(cell + (f" ({results[m][ref]:.2f})" if ref else ""))
        lines.append(f"| {part} | " + " | ".join(cells) + " |")
    lines.append("| head GFLOP/s (torch.mm of its shapes) | " + " | ".join(
        f"{results[m]['head GFLOP/s']:.0f} ({results[m]['mm GFLOP/s']:.0f})" for m in names) + " |")
    lines.append(f"\ntorch.mm at 1024^3 on this core: {peak:.0f} GFLOP/s.")
    return "\n".join(lines)


@pytest.mark.parametrize("method_name", METHODS)
def test_fit_step(benchmark, method_name):
    p = Profile(method_name)
    with flush_denormals():
        p.step()
        benchmark(p.step)


def network_module_at(revision: str):
    """``methods/core/network.py`` as of git ``revision``, loaded as a module of its own."""
    import importlib.util
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    source = subprocess.run(["git", "show", f"{revision}:methods/core/network.py"], capture_output=True, text=True,
                            check=True, cwd=Path(__file__).resolve().parents[1]).stdout
    path = Path(tempfile.mkdtemp()) / "network_at_revision.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(f"network_at_{revision}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def step_against(method_name: str, network_module, rounds: int = 60) -> dict:
    """Median ms of a whole step with this checkout's code and with ``network_module``'s network
    and advanced-indexing batches (the same seed, data and optimizer settings), interleaved."""
    now = Profile(method_name)
    then = Profile(method_name)
    torch.manual_seed(0)
    then.model = network_module.make_network(then.method.input_dim, then.method.output_dim,
                                             **then.budget.network_config())
    then.model.train()
    then.optimizer = make_optimizer(then.model, then.budget)

    def old_step():
        rows = torch.randint(0, len(then.inputs), (then.B,), generator=then.generator)
        x, t = then.inputs[rows], {k: v[rows] for k, v in then.targets.items()}
        then.optimizer.zero_grad(set_to_none=True)
        then.method.loss(then.method.predict(then.model, x), t).backward()
        then.optimizer.step()

    ms = _median_ms({"now": now.step, "then": old_step}, rounds)
    return {**ms, "speed-up": ms["then"] / ms["now"]}


def _steps_per_second(method_name: str, threads: int, steps: int, start) -> float:
    """Steps per second of ``steps`` whole steps with ``threads`` torch threads, after ``start`` (a
    multiprocessing Event: the processes of one measurement start together)."""
    torch.set_num_threads(threads)
    p = Profile(method_name)
    with flush_denormals():
        p.step()
        start.wait()
        t = time.perf_counter()
        for _ in range(steps):
            p.step()
        return steps / (time.perf_counter() - t)


def throughput(method_name: str, steps: int = 300, cores: int = 2) -> dict:
    """Steps per second of the machine: ``cores`` processes of one thread side by side (what the
    ``auto`` executor runs) against one process of ``cores`` threads (what a single job may use)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    ctx = mp.get_context("spawn")
    with ctx.Manager() as manager, ProcessPoolExecutor(cores, mp_context=ctx) as pool:
        start = manager.Event()
        futures = [pool.submit(_steps_per_second, method_name, 1, steps, start) for _ in range(cores)]
        time.sleep(5.0)  # every worker built its data
        start.set()
        side_by_side = sum(f.result() for f in futures)
        start = manager.Event()
        future = pool.submit(_steps_per_second, method_name, cores, steps, start)
        time.sleep(5.0)
        start.set()
        one = future.result()
    return {"processes": side_by_side, "threads": one, "ratio": side_by_side / one}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=60)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--against", metavar="REV", help="compare whole steps with the network code of git REV")
    parser.add_argument("--throughput", type=int, metavar="CORES",
                        help="steps per second of CORES one-thread processes side by side against one process of "
                             "CORES threads")
    args = parser.parse_args(argv)
    with flush_denormals():  # as every fit runs its steps (methods.core.training_loop.run_steps)
        _report(args)


def _report(args):
    if args.throughput:
        print(f"| method | {args.throughput} processes x 1 thread, steps/s | 1 process x {args.throughput} threads, "
              f"steps/s | ratio |\n|---|---|---|---|")
        for m in args.methods:
            r = throughput(m, cores=args.throughput)
            print(f"| {m} | {r['processes']:.1f} | {r['threads']:.1f} | {r['ratio']:.2f}x |")
        return
    torch.set_num_threads(args.threads)
    if args.against:
        module = network_module_at(args.against)
        print(f"| method | step ms at {args.against} | step ms now | speed-up |\n|---|---|---|---|")
        for m in args.methods:
            r = step_against(m, module, args.rounds)
            print(f"| {m} | {r['then']:.2f} | {r['now']:.2f} | {r['speed-up']:.2f}x |")
        return
    results = {m: profile(m, args.rounds) for m in args.methods}
    print(f"torch threads={torch.get_num_threads()}, cpu budget, batch {BUDGETS['cpu'].batch_size}, "
          f"median of {args.rounds} interleaved rounds")
    print(markdown(results, peak_mm_gflops()))


if __name__ == "__main__":
    main()
