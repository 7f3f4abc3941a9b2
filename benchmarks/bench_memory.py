"""Peak memory per grid point, measured: the models of runner/measured_memory.csv from finished runs.

    .venv/bin/python -m benchmarks.bench_memory RUN_DIR [RUN_DIR ...] [--write] [--cpu TEXT]

Reads every ok job of the run directories (their ``results.db``: grid, mode, method and the peak
resident memory of the job's worker, ``peak_rss_mib`` in its info; the task from ``config.json``),
fits ``peak = base + bytes_per_point * N^3`` per (task, method, mode) over the grids it ran at
(:func:`runner.memory_need.fit_models`: the largest peak at each grid, least squares), and prints
each model beside the peak it predicts and the one measured at each grid, and beside the estimate
the guard used before (240 B x N^3 for every method). ``--write`` puts these models into
runner/measured_memory.csv (the guard of every run), with the CPU and commit the runs' config.json
record: each replaces the model of its (task, method, mode); the file's other models stay.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
from pathlib import Path

import pandas as pd

from runner.memory_need import MEASURED, MIB, fit_models, read_models, write_models

#: The guard's figure before it was measured: 240 bytes per grid point for every method.
GUESSED_BYTES_PER_POINT = 240


def run_record(run_dir: Path) -> dict:
    return json.loads((run_dir / "config.json").read_text())


def jobs_of(run_dir: Path) -> pd.DataFrame:
    """task, method, mode, grid, shape, peak_rss_mib of a run's ok jobs."""
    task = run_record(run_dir)["config"].get("task", "encode")
    with sqlite3.connect(f"file:{run_dir / 'results.db'}?mode=ro", uri=True) as con:
        jobs = pd.read_sql_query("SELECT shape, method, mode, grid, info FROM jobs WHERE status = 'ok'", con)
    jobs["peak_rss_mib"] = [json.loads(i or "{}").get("peak_rss_mib") for i in jobs.pop("info")]
    jobs["task"] = task
    return jobs.dropna(subset=["peak_rss_mib"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished run directories")
    parser.add_argument("--write", action="store_true",
                        help=f"put the fitted models into {MEASURED.name} (each replaces its method's; others stay)")
    args = parser.parse_args(argv)
    jobs = pd.concat([jobs_of(r) for r in args.runs], ignore_index=True)
    environments = [run_record(r).get("environment", {}) for r in args.runs]
    commits = sorted({str(e.get("git_commit", "unknown"))[:7] for e in environments})
    cpus = sorted({str(e.get("cpu_model", "unknown CPU")) for e in environments})
    models = fit_models(jobs.to_dict("records"), cpu=" / ".join(cpus), commit=" ".join(commits))
    rows = []
    for m in models:
        part = jobs[(jobs.task == m.task) & (jobs.method == m.method) & (jobs["mode"] == m.mode)]
        for grid, peaks in part.groupby("grid")["peak_rss_mib"]:
            rows.append({"task": m.task, "method": m.method, "mode": m.mode, "grid": grid, "jobs": len(peaks),
                         "measured MiB (max)": round(peaks.max()), "model MiB": round(m.need_bytes(grid) / MIB),
                         "guessed MiB": round(GUESSED_BYTES_PER_POINT * grid**3 / MIB),
                         "base MiB": m.base_mib, "B per point": m.bytes_per_point})
    print(pd.DataFrame(rows).to_markdown(index=False))
    if args.write:
        kept = {**read_models(MEASURED), **{(m.task, m.method, m.mode): m for m in models}}
        write_models(sorted(kept.values(), key=lambda m: (m.task, m.method, m.mode)))
        read_models.cache_clear()
        print(f"wrote {len(models)} models to {MEASURED} ({len(kept)} in all)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
