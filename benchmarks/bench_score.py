"""Scoring meshes made elsewhere against the metric time of a built-in method's run on the same shapes.

    .venv/bin/python -m benchmarks.bench_score [--data-dir ../shared/data/abc] [--out /tmp/bench_score]

Runs, one after the other on one core each (``--executor local --threads 1``): the built-in
``poisson`` reconstruction of every shape at 1M evaluation points, then ``run_benchmark.py score``
on that run's own meshes (``meshes/<shape>/poisson.ply``, linked as ``<shape>.ply``; canonical
frame) under another name. Prints
per shape the built-in job's ``metrics_s`` and the score job's ``total_s`` (loading the GT, reading the
prediction, the metrics, saving), their sums and ratio, and both runs' wall seconds. The target: the
score run's jobs take no more than the built-in jobs' metric time (ratio <= 1, up to the reading).
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import pandas as pd

from methods.base import METHODS
from runner.cli import main as run_main


def run_timed(argv: list[str]) -> float:
    """Wall seconds of one ``run_benchmark.py`` run in this process; exits when it fails."""
    t0 = time.perf_counter()
    code = run_main(argv)
    if code not in (0, 3):
        raise SystemExit(f"run failed with exit {code}: {' '.join(argv)}")
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_score")
    parser.add_argument("--data-dir", default=str(Path(__file__).resolve().parents[2] / "shared" / "data" / "abc"))
    parser.add_argument("--out", default="/tmp/bench_score")
    parser.add_argument("--eval-points", default="1000000")
    args = parser.parse_args(argv)
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    common = ["--dataset", "abc", "--data-dir", args.data_dir, "--eval-points", args.eval_points, "--quiet",
              "--gallery", "0", "--executor", "local", "--threads", "1", "--cache-dir", str(out / "cache")]
    builtin_wall = run_timed(["--task", "reconstruct", "--methods", "poisson", "--out", str(out / "builtin"), *common])
    flat = out / "predictions"  # <shape>.ply: the built-in run's meshes under the matching rule
    flat.mkdir()
    for mesh in (out / "builtin" / "meshes").glob("*/poisson.ply"):
        (flat / f"{mesh.parent.name}.ply").symlink_to(mesh)
    score_wall = run_timed(["score", "--pred-dir", str(flat), "--name", "poisson-again",
                       "--pred-frame", "canonical", "--out", str(out / "score"), *common])
    METHODS.unregister("poisson-again")
    a = pd.read_csv(out / "builtin" / "results.csv").set_index("shape")
    b = pd.read_csv(out / "score" / "results.csv").set_index("shape")
    table = pd.DataFrame({"built-in metrics_s": a["metrics_s"], "score total_s": b["total_s"],
                          "score read_s": b["read_s"], "score metrics_s": b["metrics_s"],
                          "cd built-in": a["cd"], "cd re-scored": b["cd"]})
    print(table.round(4).to_markdown())
    ratio = table["score total_s"].sum() / table["built-in metrics_s"].sum()
    print(f"\nsum built-in metrics_s {table['built-in metrics_s'].sum():.1f} s; sum score total_s "
          f"{table['score total_s'].sum():.1f} s; ratio {ratio:.3f}")
    print(f"wall: built-in run {builtin_wall:.1f} s, score run {score_wall:.1f} s (both with their floor tasks)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
