"""Measure what the learned tests reach across seeds, CPU float paths and thread counts.

    .venv/bin/python scripts/measure_learned_spread.py                 # seeds 0-4, every path, 1 and 2 threads
    .venv/bin/python scripts/measure_learned_spread.py --seeds 0 1 --threads 1 --out /tmp/spread

Runs ``pytest -m learned`` once per (float path, thread count), the seeds as parameters of each
test's ``fit_seed`` (see tests/conftest.py), with ``ATEN_CPU_CAPABILITY`` set per path. Every test
logs its measured values before asserting, so failures are data here, not errors. Writes
``<out>/raw-<path>-<threads>t.jsonl`` per run, then ``<out>/learned.jsonl`` (every row of every run in
``<out>``, earlier invocations' included) and ``<out>/learned.md`` (per test value: min, median and
max over everything, and the range on each path), the tables that the learned tests' bounds cite.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from methods.core.device import FLOAT_PATHS, float_path_environment  # noqa: E402


def run_learned_tests(path: str, threads: int, seeds: list[int], log: Path, select: str) -> int:
    env = float_path_environment(path)
    env.update(SALSBENCH_TEST_SEEDS=",".join(map(str, seeds)), SALSBENCH_TEST_THREADS=str(threads),
               SALSBENCH_SPREAD_OUT=str(log), OMP_NUM_THREADS=str(threads))
    cmd = [sys.executable, "-m", "pytest", "-q", "-m", select, "--no-header", "-rN"]
    with open(log.with_suffix(".log"), "w") as out:
        return subprocess.run(cmd, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT).returncode


def summarise(rows: list[dict]):
    """Per test, case and measured quantity: count, min, median, max, and the range on each path."""
    import pandas as pd

    frame = pd.DataFrame(rows)
    frame["path"] = frame["float_path"] + "/" + frame["threads"].astype(str) + "t"
    keys = {"test", "case", "seed", "float_path", "threads", "path", "capability"}
    long = frame.melt(id_vars=["test", "case", "path"], value_vars=[c for c in frame.columns if c not in keys],
                      var_name="quantity", value_name="x").dropna(subset=["x"])
    groups = ["test", "case", "quantity"]
    table = long.groupby(groups)["x"].agg(["count", "min", "median", "max"])
    per_path = long.groupby([*groups, "path"])["x"].agg(lambda v: f"{v.min():.4g}-{v.max():.4g}").unstack("path")
    return table.join(per_path).reset_index()


def header(rows: list[dict]) -> str:
    """Where and how the table was measured."""
    import datetime
    import platform

    import torch

    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").is_file() \
        else platform.processor()
    runs = sorted({f"{r['float_path']}/{r['threads']}t ({r['capability']})" for r in rows})
    seeds = sorted({r["seed"] for r in rows if r.get("seed") is not None})
    return (f"# What the learned tests reach\n\nMeasured {datetime.date.today()} on {cpu} ({os.cpu_count()} cores), "
            f"torch {torch.__version__}, by `python scripts/measure_learned_spread.py`: seeds {seeds}, runs "
            f"(float path / torch threads (kernels)): {', '.join(runs)}. One row per test, case and measured "
            f"quantity: over every run, then the range on each run.\n\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--paths", nargs="+", default=list(FLOAT_PATHS), choices=FLOAT_PATHS)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--select", default="learned", help="pytest -m expression (default: learned)")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "spread")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    cores = os.cpu_count() or 1
    runs = [(p, t) for t in sorted(args.threads) for p in args.paths]
    logs = {run: args.out / f"raw-{run[0]}-{run[1]}t.jsonl" for run in runs}
    for log in logs.values():
        log.unlink(missing_ok=True)
    for threads in sorted(set(args.threads)):  # as many runs side by side as the cores hold
        batch = [run for run in runs if run[1] == threads]
        with ThreadPoolExecutor(max(1, cores // threads)) as pool:
            codes = pool.map(lambda run: run_learned_tests(*run, args.seeds, logs[run], args.select), batch)
            for run, code in zip(batch, codes):
                print(f"{run[0]:>8} {run[1]}t: pytest exit {code} (log {logs[run].with_suffix('.log').name})")
    rows = []  # every run in the folder: earlier invocations' (other paths or threads) too
    for log in sorted(args.out.glob("raw-*.jsonl")):
        path = log.stem.split("-")[1]
        rows += [{**json.loads(line), "float_path": path} for line in log.read_text().splitlines()]
    with open(args.out / "learned.jsonl", "w") as f:
        f.writelines(json.dumps(r) + "\n" for r in rows)
    table = summarise(rows)
    (args.out / "learned.md").write_text(header(rows) + table.to_markdown(index=False, floatfmt=".4g") + "\n")
    print(table.to_markdown(index=False, floatfmt=".4g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
