"""Per-job results of finished runs as one CSV for docs/results/: every job, failed ones included
(NaN metrics and their status), with the columns RESULTS.md's tables are computed from.

    python scripts/export_results.py RUN_DIR [RUN_DIR ...] --commit SHA --out docs/results/NAME.csv
    python scripts/export_results.py RUN_DIR --components --commit SHA --out docs/results/NAME.csv
    python scripts/export_results.py RUN_DIR --commit SHA --out docs/results/NAME.csv --append
    python scripts/export_results.py RUN_DIR --commit SHA --out docs/results/NAME.csv --append --replace-failed

Columns: ``shape, method, seed, mode, budget, input, cd, nc, f1_005, f1_01, ecd, ef1, n_faces,
status, error, seen_in_training, commit``. ``input``: ``mesh`` for the encode task (the GT mesh's
exact fields), else the reconstruct task's input cloud (``uniform``, ``scan``, ``noise-2``, ...).
``budget``: the budget's name followed by the run's ``--budget-param`` changes (``cpu steps=2400``).
``commit``: the commit whose code computed the rows (the frozen worktree a long run ran from).
Rows are sorted by method, shape and seed; numbers keep 9 significant digits.

``--append`` adds the runs' jobs to an existing CSV, whose rows keep their own commits (new rows of the
same table computed at a later commit); a job already in it (the same shape, method, seed, mode,
budget and input) is refused, naming it. With ``--replace-failed``, a job the CSV holds as failed and the runs hold as
``ok`` (re-run after a fix, at the commit given) replaces it; every other repeat is still refused.

``--cost`` adds what each job cost and on which grid: :data:`COST_COLUMNS` (``grid``, the seconds
of its stages and in all, and ``peak_rss_mib``, the peak resident memory of its worker while it ran,
from the job's info in results.db); with ``--components``, each row's grid.

``--extra A,B`` adds those columns of results.csv (e.g. ``eprecision,erecall``: EF1's precision and
recall; ``sweep.KEY``: a sweep's value, which then tells its jobs apart) before ``commit``.

``--budget-fields A,B`` adds a column per field of the encode budget (e.g. ``steps``): each job's value,
from its sweep column (``sweep.budget.A``) where the run swept it, else the run's budget as
config.json resolved it (its ``--budget-param`` changes included); empty for oracle rows.

``--where COLUMN=VALUE`` (repeatable) keeps the runs' jobs with that value (``--where mode=oracle``);
``--complete-shapes`` keeps the shapes that have every (method, mode, budget, input, grid) the kept jobs
have anywhere, so that each table over the CSV is over the same shapes (a run stopped part-way).

``--components`` exports a ``--decompose`` run's extractions instead (its components.csv): one row
per job and set of exact components, columns :data:`COMPONENT_COLUMNS` (``exact``: the components
taken from the exact field, e.g. ``flags+normals``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from runner.references import ROW_COLUMNS as COLUMNS, budget_label, run_input  # noqa: E402  (one row schema)

COST_COLUMNS = ["grid", "fit_s", "query_s", "extract_s", "metrics_s", "total_s", "peak_rss_mib"]

COMPONENT_COLUMNS = ["shape", "method", "seed", "exact", "cd", "nc", "f1_005", "f1_01", "ecd", "ef1", "n_faces",
                     "extract_s", "commit"]


def run_config(run_dir: Path) -> dict:
    """The settings a run was given (its config.json's ``config``)."""
    return json.loads((run_dir / "config.json").read_text())["config"]


def peak_memory(run_dir: Path) -> pd.Series:
    """Each job's ``peak_rss_mib`` (from its info in results.db) by its key, ``config_hash``."""
    import sqlite3

    with sqlite3.connect(f"file:{run_dir / 'results.db'}?mode=ro", uri=True) as con:
        rows = con.execute("SELECT config_hash, info FROM jobs").fetchall()
    return pd.Series({key: json.loads(info or "{}").get("peak_rss_mib") for key, info in rows}, dtype=float)


def budget_fields(run_dir: Path, frame: pd.DataFrame, fields: tuple[str, ...]) -> pd.DataFrame:
    """Each job's value of each encode budget field of ``fields`` (see the module docstring)."""
    resolved = (json.loads((run_dir / "config.json").read_text()).get("resolved", {}).get("budget") or {}).get("encode")
    if resolved is None:
        raise ValueError(f"--budget-fields: {run_dir}: the run has no encode budget")
    out = pd.DataFrame(index=frame.index)
    for name in fields:
        if name not in resolved:
            raise ValueError(f"--budget-fields: {run_dir}: the encode budget has no field {name}")
        swept = frame.get(f"sweep.budget.{name}")
        value = swept if swept is not None else pd.Series(resolved[name], index=frame.index)
        out[name] = value.where(frame["mode"] == "neural")
    return out


def job_rows(run_dir: Path, commit: str, cost: bool = False, extra: tuple[str, ...] = (),
             budget: tuple[str, ...] = ()) -> pd.DataFrame:
    """The jobs of one run directory (its results.csv) in :data:`COLUMNS` (and :data:`COST_COLUMNS`
    with ``cost``, then ``extra`` and the ``budget`` fields, before ``commit``)."""
    config = run_config(run_dir)
    frame = pd.read_csv(run_dir / "results.csv")
    if budget:
        frame[list(budget)] = budget_fields(run_dir, frame, budget)
    frame["input"] = run_input(config)
    if "budget" in frame:
        changes = config.get("budget_params") or {}
        frame["budget"] = [budget_label(b, changes) for b in frame["budget"]]
    frame["commit"] = commit
    if cost:
        frame["peak_rss_mib"] = frame["config_hash"].map(peak_memory(run_dir))
    missing = [c for c in extra if c not in frame]
    if missing:
        raise ValueError(f"--extra: {run_dir}: results.csv has no column {missing[0]}")
    return frame.reindex(columns=COLUMNS[:-1] + (COST_COLUMNS if cost else []) + list(extra) + list(budget)
                         + COLUMNS[-1:])


def complete_shapes(jobs: pd.DataFrame) -> pd.DataFrame:
    """The jobs of the shapes that have every kind of job (method, mode, budget, input, grid, seed)
    that any shape has."""
    kind = [c for c in ("method", "mode", "budget", "input", "grid", "seed", "exact") if c in jobs]
    kinds = jobs[kind].apply(lambda column: column.map(str)).agg("|".join, axis=1)
    every = set(kinds)
    complete = [shape for shape, ks in kinds.groupby(jobs["shape"]) if set(ks) == every]
    return jobs[jobs["shape"].isin(complete)]


def component_rows(run_dir: Path, commit: str, cost: bool = False) -> pd.DataFrame:
    """The decomposition rows of one run directory (its components.csv) in :data:`COMPONENT_COLUMNS`
    (with ``cost``, the grid of each row's job before ``commit``, from results.csv)."""
    frame = pd.read_csv(run_dir / "components.csv")
    frame["commit"] = commit
    if not cost:
        return frame.reindex(columns=COMPONENT_COLUMNS)
    jobs = pd.read_csv(run_dir / "results.csv").set_index("config_hash")["grid"]
    frame["grid"] = frame["config_hash"].map(jobs)
    return frame.reindex(columns=COMPONENT_COLUMNS[:-1] + ["grid"] + COMPONENT_COLUMNS[-1:])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python scripts/export_results.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished run directories")
    parser.add_argument("--commit", required=True, help="the commit whose code computed the rows")
    parser.add_argument("--out", type=Path, required=True, help="the CSV to write")
    parser.add_argument("--cost", action="store_true",
                        help="add each job's grid, seconds and peak memory (COST_COLUMNS)")
    parser.add_argument("--extra", default="", metavar="A,B", help="more columns of results.csv to keep")
    parser.add_argument("--budget-fields", default="", metavar="A,B",
                        help="add each job's value of these encode budget fields (e.g. steps)")
    parser.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE",
                        help="keep the runs' jobs whose COLUMN has VALUE (repeatable)")
    parser.add_argument("--complete-shapes", action="store_true",
                        help="keep the shapes that have every job kind the kept jobs have")
    parser.add_argument("--components", action="store_true",
                        help="export the runs' --decompose extractions (components.csv) instead of their jobs")
    parser.add_argument("--append", action="store_true",
                        help="add the runs' jobs to the existing --out, refusing a job it already has")
    parser.add_argument("--replace-failed", action="store_true",
                        help="with --append: an ok job of the runs replaces the same job held as failed in --out")
    args = parser.parse_args(argv)
    if args.replace_failed and (args.components or not args.append):
        print("export_results: --replace-failed needs --append and jobs, not --components (it replaces failed jobs "
              "of an existing CSV)", file=sys.stderr)
        return 2
    table_file = "components.csv" if args.components else "results.csv"
    frames = []
    for run in args.runs:
        if not (run / table_file).is_file():
            print(f"export_results: {run} has no {table_file} (run `run_benchmark.py report {run}` first"
                  + (", on a --decompose run" if args.components else "") + ")", file=sys.stderr)
            return 2
        extra = tuple(c for c in args.extra.split(",") if c)
        budget = tuple(c for c in args.budget_fields.split(",") if c)
        try:
            frames.append(component_rows(run, args.commit, args.cost) if args.components
                          else job_rows(run, args.commit, args.cost, extra, budget))
        except ValueError as exc:
            print(f"export_results: {exc}", file=sys.stderr)
            return 2
    for condition in args.where:
        column, _, value = condition.partition("=")
        if not value or any(column not in f for f in frames):
            print(f"export_results: --where {condition}: expected COLUMN=VALUE with a column of the rows", file=sys.stderr)
            return 2
        frames = [f[f[column].map(str) == value] for f in frames]
    if args.complete_shapes:
        frames = [complete_shapes(pd.concat(frames, ignore_index=True))]
    keys = ["method", "shape", "seed"] + (["exact"] + (["grid"] if args.cost else []) if args.components else [])
    if args.append:
        if not args.out.is_file():
            print(f"export_results: --append: {args.out} does not exist", file=sys.stderr)
            return 2
        frames.insert(0, pd.read_csv(args.out))
    extra = [c for c in (args.extra + "," + args.budget_fields).split(",") if c]  # they tell jobs apart
    job = keys + ([] if args.components else ["mode", "budget", "input"] + (["grid"] if args.cost else []) + extra)
    replaced = 0
    if args.replace_failed:
        held, new = frames[0], pd.concat(frames[1:], ignore_index=True)
        rerun = pd.MultiIndex.from_frame(new.loc[new.status == "ok", job])
        superseded = (held.status != "ok") & pd.MultiIndex.from_frame(held[job]).isin(rerun)
        replaced = int(superseded.sum())
        frames[0] = held[~superseded]
    table = pd.concat(frames, ignore_index=True)
    repeated = table.duplicated(job)
    if repeated.any():
        first = table[repeated].iloc[0]
        print(f"export_results: {int(repeated.sum())} job(s) twice (in the runs" + (f" or {args.out}" if args.append else "")
              + "), e.g. "
              + ", ".join(f"{k}={first[k]}" for k in job), file=sys.stderr)
        return 2
    table = table.sort_values(keys, kind="stable")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False, float_format="%.9g")
    if args.components:
        print(f"wrote {args.out}: {len(table)} extractions")
    else:
        print(f"wrote {args.out}: {len(table)} jobs ({int((table.status == 'ok').sum())} ok)"
              + (f", {replaced} failed job(s) replaced by their re-runs" if args.replace_failed else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
