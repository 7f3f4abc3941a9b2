"""``run_benchmark.py report RUN_DIR [RUN_DIR ...] [--out DIR]``: tables and report.html again from
finished runs' ``results.db``; several runs side by side."""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
from pathlib import Path
from typing import Callable, Sequence

from runner.parsing import EXIT_REFUSED, OneLineParser

#: Shapes from which one run's report draws them on a pool of processes (one per core): a worker
#: starts by importing torch and the project (about 3.5 s of CPU), more than drawing a few shapes.
POOL_MIN_SHAPES = 8


def pooled_when_many(pool_map: Callable, min_shapes: int = POOL_MIN_SHAPES) -> Callable:
    """A report's ``map_shapes``: ``pool_map(fn, shapes)`` for ``min_shapes`` shapes or more, else
    ``[fn(s) for s in shapes]`` in this process (the pool is then never started)."""

    def draw(fn: Callable, shapes) -> list:
        shapes = list(shapes)
        return list(pool_map(fn, shapes)) if len(shapes) >= min_shapes else [fn(s) for s in shapes]

    return draw


def build_report_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="run_benchmark.py report",
                       description="Regenerate results.csv, tables and report.html from run directories' "
                                   "results.db; with several runs, put them side by side.")
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run directories (each holds results.db)")
    p.add_argument("--complete-shapes", action="store_true",
                   help="only the shapes whose every job has a row (a run stopped part-way: every method's "
                        "means over the same shapes); one run only")
    p.add_argument("--reference", metavar="NAME",
                   help="join a reference set's rows to the tables (a set's name or folder; one run only; default: "
                        "the run's own --reference); refused where its protocol differs")
    p.add_argument("--reference-keep", choices=("run", "reference"),
                   help="where a row name is both in the run and in the reference: whose rows to keep")
    p.add_argument("--out", metavar="DIR", help="where to write (default: the run directory itself; for several "
                                                "runs: runs/compare-<timestamp>)")
    return p


def report_main(argv: Sequence[str]) -> int:
    from runner.config import ConfigError
    from runner.records import SchemaMismatch

    args = build_report_parser().parse_args(list(argv))
    for r in args.runs:
        if not (Path(r) / "results.db").is_file():
            print(f"run_benchmark.py report: error: {r}: no results.db (not a salsbench run directory)", file=sys.stderr)
            return EXIT_REFUSED
    try:
        return _report(args)
    except (SchemaMismatch, ConfigError) as exc:  # a results.db or config.json this version cannot read
        print(f"run_benchmark.py report: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED


def _report(args: argparse.Namespace) -> int:
    """The report of one run, or the comparison of several; every run is read before anything is
    written."""
    from runner.config import ConfigError
    from runner.export import export, report_context, table_frame
    from runner.records import open_run_db
    from runner.rundir import RunDirectory

    if args.complete_shapes and len(args.runs) > 1:
        raise ConfigError("--complete-shapes reads one run (compare finished runs side by side)")
    if (args.reference or args.reference_keep) and len(args.runs) > 1:
        raise ConfigError("--reference joins a set to one run's tables (compare finished runs side by side without it)")
    if len(args.runs) == 1:
        from runner.executors import ProcessExecutor, physical_cores

        drawing = ProcessExecutor(workers=physical_cores(), retries=0, threads=1)  # the report's shapes, one per core
        try:
            written = export(Path(args.runs[0]), out_dir=Path(args.out) if args.out else None,
                             only_complete_shapes=args.complete_shapes,
                             map_shapes=pooled_when_many(drawing.map) if drawing.workers > 1 else map,
                             reference=args.reference, reference_keep=args.reference_keep)
        finally:
            drawing.close()
        print(f"wrote {written['results']}", file=sys.stderr)
        return 0
    out = Path(args.out) if args.out else Path("runs") / _dt.datetime.now().strftime("compare-%Y%m%d-%H%M%S")
    runs = []
    for r in args.runs:
        run_dir = Path(r)
        record = RunDirectory(run_dir).read_record()
        with open_run_db(run_dir, must_exist=True) as db:
            runs.append({"name": run_dir.name, "results": table_frame(db, "jobs", record),
                         "floor": table_frame(db, "floor", record), "context": report_context(record),
                         "meshes_dir": run_dir / "meshes"})
    import reports

    out.mkdir(parents=True, exist_ok=True)
    reports.compare_runs(runs, out)
    print(f"wrote comparison of {len(runs)} runs to {out}", file=sys.stderr)
    return 0
