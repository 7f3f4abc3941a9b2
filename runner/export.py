"""From ``results.db`` to the files users read: ``results.csv``, ``floor.csv`` and the reports.

``results.csv`` leads with the schema's contract columns (:func:`foundation.schema.csv_lead`),
then every other metric/timing column; rows in table order (shapes in dataset order, methods in
display order, seeds). Raw units throughout; the reports apply the preset's multipliers.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from datasets.registry import up_axis_of
from runner.records import SWEEP_PREFIX, open_run_db
from foundation.schema import CSV_EXCLUDED, csv_lead


def _ordered(df: pd.DataFrame, by: list[tuple[str, list]]) -> pd.DataFrame:
    """Rows sorted by the given columns, each in the order of its list (unknown values last)."""
    keys = []
    for column, values in by:
        rank = {v: i for i, v in enumerate(values)}
        keys.append(df[column].map(rank).fillna(len(rank)))
    if not keys:
        return df.reset_index(drop=True)
    order = np.lexsort([k.to_numpy() for k in reversed(keys)])
    return df.iloc[order].reset_index(drop=True)


def table_frame(db, table: str, record: dict[str, Any]) -> pd.DataFrame:
    """A table of the database as a frame: contract columns first, rows in table order."""
    df = db.frame(table)
    lead = csv_lead(table)
    for col in lead:
        if col not in df.columns:
            df[col] = np.nan
    rest = [c for c in df.columns if c not in lead and c not in CSV_EXCLUDED]
    df = df[lead + rest]
    resolved = record.get("resolved", {})
    by = [("shape", resolved.get("shapes", []))]
    if table == "jobs":
        mode = record.get("config", {}).get("mode")
        by += [("mode", [mode, "oracle"])] + [(f"{SWEEP_PREFIX}{k}", list(v)) for k, v in sweep_of(record).items()
                                               if f"{SWEEP_PREFIX}{k}" in df.columns]
    if table in ("jobs", "checkpoints", "components"):
        by += [("method", resolved.get("methods", [])), ("seed", record.get("config", {}).get("seeds", []))]
    if table == "checkpoints":
        by.append(("fraction", sorted(set(df["fraction"].dropna()))))
    if table == "components":
        by.append(("exact", list(dict.fromkeys(df["exact"]))))
    return _ordered(df, by)


def complete_shapes(results: pd.DataFrame) -> list[str]:
    """The shapes of ``results`` (jobs' rows) that have a row for every job any shape has (method,
    mode, seed, sweep settings): in a run stopped part-way, the shapes whose every job finished
    (ok or failed), in table order."""
    if results.empty:
        return []
    job = ["method", "mode", "seed", *[c for c in results.columns if c.startswith(SWEEP_PREFIX)]]
    ids = results[job].astype(str).agg("|".join, axis=1)
    wanted = set(ids)
    has = ids.groupby(results["shape"], sort=False).agg(set)
    return [s for s in dict.fromkeys(results["shape"]) if has[s] >= wanted]


def sweep_of(record: dict[str, Any]) -> dict[str, list]:
    """The run's sweep, {key: values}, keys in the order given (config.json stores keys sorted)."""
    resolved = record.get("resolved", {})
    sweep = resolved.get("sweep", {})
    return {k: sweep[k] for k in resolved.get("sweep_keys", sweep)}


def report_context(record: dict[str, Any]) -> dict[str, Any]:
    """The flat description of a run the reports read (see ``reports.write_reports``)."""
    config, resolved, env = record.get("config", {}), record.get("resolved", {}), record.get("environment", {})
    return {
        "dataset": config.get("dataset"), "task": config.get("task"), "mode": config.get("mode"),
        "budget": config.get("budget"), "budget_values": resolved.get("budget"), "grid": config.get("grid"),
        "seeds": config.get("seeds", []), "methods": resolved.get("methods", []), "shapes": resolved.get("shapes", []),
        "metric_preset": config.get("metric_preset"), "eval_points": resolved.get("eval_points"),
        "device": env.get("device"), "cpu_model": env.get("cpu_model"), "gpu": env.get("gpu"),
        "git_commit": env.get("git_commit"), "sweep": sweep_of(record),
        "budget_params": config.get("budget_params", {}), "execution": record.get("execution"),
        "sessions": record.get("sessions"),
        "method_notes": method_notes(config.get("task", "encode"), resolved.get("methods", []),
                                     resolved.get("method_params", {})),
        "up_axis": up_axis_of(config.get("dataset")),
    }


def method_notes(task: str, names, params: dict) -> dict[str, str]:
    """{method: its table note} of the rows ``names`` of ``task`` that have one (a name no longer
    known, e.g. an unloaded plugin's, has none)."""
    from tasks.rows import row_kind

    notes = {}
    for name in names:
        try:
            note = row_kind(task, name, params.get(name)).note
        except ValueError:
            continue
        if note:
            notes[name] = note
    return notes


def _with_reference(results: pd.DataFrame, context: dict[str, Any], record: dict[str, Any], name: str | None,
                    keep: str | None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """``results`` and ``context`` with a reference set joined (:func:`runner.references.join_reference`):
    ``name``, else the run's own ``--reference``."""
    from runner.config import ConfigError
    from runner.references import join_reference

    own = name is None
    name, keep = (record.get("config", {}).get("reference"), record.get("config", {}).get("reference_keep")) if own \
        else (name, keep)
    if not name:
        return results, context
    try:
        return join_reference(results, context, record, name, keep)
    except ConfigError as exc:
        if not own:
            raise
        print(f"salsbench: the tables leave out --reference {name}: {exc}", file=sys.stderr)
        return results, context


def export(run_dir: str | Path, db=None, record: dict[str, Any] | None = None,
           out_dir: str | Path | None = None, gallery: int | None = None,
           only_complete_shapes: bool = False, map_shapes=map, reference: str | None = None,
           reference_keep: str | None = None) -> dict[str, Any]:
    """Write results.csv, floor.csv and the reports of a run directory; returns what was written.

    ``gallery``: shapes with thumbnails in report.html (None: the report's default).
    ``only_complete_shapes``: every file covers only :func:`complete_shapes` (a run stopped
    part-way: every method's mean over the same shapes); the protocol line says how many of the
    run's shapes that is. ``map_shapes``: how the report's per-shape drawings are made (builtin
    ``map``; the driver passes its executor's ``map``, which draws on the run's workers).
    ``reference``: join that reference set's rows to the tables (:mod:`runner.references`; a set
    that cannot be joined raises ConfigError); None: the run's own ``--reference``, if any (one
    that can no longer be joined is reported on stderr and left out).

    A failure while writing the reports is reported on stderr and never loses results.csv.
    """
    from runner.rundir import RunDirectory

    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    record = record if record is not None else RunDirectory(run_dir).read_record()
    own = db is None
    db = open_run_db(run_dir, must_exist=True) if own else db
    try:
        results, floor = table_frame(db, "jobs", record), table_frame(db, "floor", record)
        checkpoints = table_frame(db, "checkpoints", record)
        components = table_frame(db, "components", record)
    finally:
        if own:
            db.close()
    context = report_context(record)
    if only_complete_shapes:
        keep = complete_shapes(results)
        results, floor, checkpoints, components = (t[t["shape"].isin(keep)].reset_index(drop=True)
                                                   for t in (results, floor, checkpoints, components))
        context.update(shapes=[s for s in context["shapes"] if s in keep], planned_shapes=len(context["shapes"]))
    shown, context = _with_reference(results, context, record, reference, reference_keep)  # tables only
    out_dir.mkdir(parents=True, exist_ok=True)  # after reading: a database that cannot be read writes nothing
    import reports
    from foundation.errors import one_line

    results.to_csv(out_dir / "results.csv", index=False, float_format="%.9g")
    floor.to_csv(out_dir / "floor.csv", index=False, float_format="%.9g")
    written: dict[str, Any] = {"results": out_dir / "results.csv", "floor": out_dir / "floor.csv"}
    if len(checkpoints):
        checkpoints.to_csv(out_dir / "checkpoints.csv", index=False, float_format="%.9g")
        written["checkpoints"] = out_dir / "checkpoints.csv"
    if len(components):
        components.to_csv(out_dir / "components.csv", index=False, float_format="%.9g")
        written["components"] = out_dir / "components.csv"
    try:
        gallery_limit = {} if gallery is None else {"gallery_limit": gallery}
        written["reports"] = reports.write_reports(shown, floor, context, out_dir, run_dir / "meshes",
                                                   **gallery_limit, checkpoints=checkpoints if len(checkpoints) else None,
                                                   components=components if len(components) else None,
                                                   map_shapes=map_shapes)
    except Exception as exc:  # noqa: BLE001 -- the results are safe in results.db / results.csv
        print(f"salsbench: writing reports failed: {one_line(exc)}", file=sys.stderr)
        written["reports"] = None
    return written
