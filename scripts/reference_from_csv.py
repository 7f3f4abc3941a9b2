"""A reference set (runner/references.py) from a per-job CSV whose runs are gone: the rows RESULTS
cited before sets existed, each with the commit that computed it. The protocol is given here, as
RESULTS' provenance states it; the shapes' bytes are read from the dataset as it is now (the lists
of the paper's parts pin them: lists/sals-abc50.sha256); the code digests are computed on each
commit's files (git archive).

    python scripts/reference_from_csv.py ROWS.csv --name paper-abc50-encode --dataset sals-abc50 \\
        --task encode --mode neural --budget cpu --cpu "Intel Xeon (2 cores, AVX-512, AMX)" --date 2026-12-06 \\
        --command "python run_benchmark.py --methods ... --dataset sals-abc50 ..." --description "..."

A set made from a finished run directory: ``run_benchmark.py references make RUN_DIR --name NAME``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from runner.references import (REFERENCES_DIR, ROW_COLUMNS, code_digests, read_reference,  # noqa: E402
                               run_protocol, shape_digests, stale_reason, write_reference)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python scripts/reference_from_csv.py", description=__doc__.split("\n\n")[0])
    p.add_argument("csv", type=Path, help="per-job rows (runner.references.ROW_COLUMNS) with their commits")
    p.add_argument("--name", required=True)
    p.add_argument("--description", default="")
    p.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE", help="keep the rows with it")
    p.add_argument("--dataset", required=True)
    p.add_argument("--dataset-option", action="append", default=[], metavar="NAME=VALUE",
                   help="an option of the dataset as its runs gave it (data_dir=..., list_file=...)")
    p.add_argument("--task", default="encode", choices=("encode", "reconstruct"))
    p.add_argument("--mode", default="neural", choices=("neural", "oracle"))
    p.add_argument("--pc-points", type=int, default=40000)
    p.add_argument("--pc-noise", type=float, default=0.0)
    p.add_argument("--grid", type=int, default=128)
    p.add_argument("--eval-points", type=int, default=1_000_000)
    p.add_argument("--metric-preset", default="default")
    p.add_argument("--budget", help="the budget's name (none in oracle mode)")
    p.add_argument("--cpu", required=True, help="the machine that computed the rows")
    p.add_argument("--date", required=True)
    p.add_argument("--command", required=True, help="the command that made the rows (RESULTS' provenance)")
    p.add_argument("--into", type=Path, default=REFERENCES_DIR)
    args = p.parse_args(argv)

    rows = pd.read_csv(args.csv, dtype={"shape": str, "method": str, "commit": str})
    for condition in args.where:
        column, _, value = condition.partition("=")
        rows = rows[rows[column].map(str) == value]
    if not len(rows) or set(ROW_COLUMNS) - set(rows.columns):
        print(f"reference_from_csv: {args.csv}: no rows, or not the columns {ROW_COLUMNS}", file=sys.stderr)
        return 2
    options = dict(o.split("=", 1) for o in args.dataset_option)
    (corruption,) = set(rows["input"])  # a set is one input: filter the CSV with --where input=...
    protocol = run_protocol({"task": args.task, "mode": args.mode, "pc_corruption": corruption, "pc_points": args.pc_points,
                             "pc_noise": args.pc_noise, "grid": args.grid, "metric_preset": args.metric_preset,
                             "dataset": args.dataset}, {"eval_points": args.eval_points})
    shapes = list(dict.fromkeys(rows["shape"]))
    sources = []
    for commit in dict.fromkeys(rows["commit"]):
        methods = list(dict.fromkeys(rows.loc[rows["commit"] == commit, "method"]))
        sources.append({"commit": commit, "cpu": args.cpu, "python": None, "date": args.date, "command": args.command,
                        "code": code_digests(commit, methods)})
    # The budget's values are those of each commit's code, which its fit digests pin; not restated here.
    budget = {"name": args.budget, "values": None} if args.budget else None
    manifest = {"name": args.name, "description": args.description, "protocol": protocol, "budget": budget,
                "seeds": sorted({int(s) for s in rows["seed"]}), "methods": list(dict.fromkeys(rows["method"])),
                "dataset_options": options, "shapes": shape_digests({"dataset": args.dataset}, {"dataset_options": options}, shapes),
                "sources": sources}
    ref = read_reference(write_reference(args.into / args.name, manifest, rows))
    print(f"wrote {ref.folder}: {len(ref.rows)} rows, {len(shapes)} shapes, commits {', '.join(s['commit'] for s in sources)}")
    reason = stale_reason(ref)
    if reason:
        print(f"note: {reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
