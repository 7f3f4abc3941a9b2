"""The paper tables of one run, computed once (:func:`build_summary`) and written as summary.md / summary.tex.

A joined reference set (``context['reference']``: its ``labels`` and ``note``, :mod:`runner.references`)
is rows like the run's, and its note is under every metric table.

Tables: mean, median and std per method (:func:`reports.statistics.statistic_table`; the caption
says what each mean is over, what its interval is and what bold means: the best and the methods
within the noise of it), mesh validity of the predictions (the schema's validity columns), and
per shape the mean over seeds of CD and ECD (bold: the best of a row at the printed precision; a
single shape has no paired test). statistics.csv holds the mean table's numbers with every
interval and p-value (:func:`reports.statistics.statistics_frame`). Failed jobs are listed with
their error text. Every cell carrying user text (shape names, method names, errors) is escaped by
each writer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from foundation.errors import one_line
from foundation.schema import columns as schema_columns
from reports.decomposition import decomposition_tables
from reports.frames import (as_bool, check_floor, check_results, numeric, ok_jobs, sensors_note, unscored_jobs,
                            without_unscored)
from reports.protocol import check_context, headline_metrics, protocol_caption, report_title
from reports.statistics import AGGREGATION, Statistics, method_statistics, statistic_table, statistics_frame
from reports.style import method_order
from reports.table import (
    DASH,
    Cell,
    Table,
    best_flags,
    fmt,
    md_escape,
    metric_header,
    table_latex,
    table_markdown_section,
    tex_escape,
)

#: Metrics that get a per-shape table (the distance metrics).
PER_SHAPE = ("cd", "ecd")
FLOOR_NOTE = ("Floor: GT against an independent resample of itself (the protocol's sampling noise), a reference "
              "row, never bold.")


@dataclass
class Summary:
    """Everything the writers need, computed once: the checked frames, the metrics, the row and
    column orders, the statistics and the tables."""

    results: pd.DataFrame
    floor: pd.DataFrame | None
    metrics: list
    methods: list[str]
    shapes: list[str]
    stats: Statistics
    tables: dict[str, Table]
    caption: str
    failed: pd.DataFrame
    scored: pd.DataFrame  # the rows the metric tables and plots use (reports.frames.without_unscored)
    reference_labels: tuple[str, ...] = ()  # rows of a joined reference set (context['reference']): no meshes

    @property
    def own_methods(self) -> list[str]:
        """The methods whose rows this run computed (its meshes exist), without a reference's."""
        return [m for m in self.methods if m not in self.reference_labels]

    def own_results(self) -> pd.DataFrame:
        """The rows this run computed, without a reference's."""
        return self.results[~self.results["method"].isin(self.reference_labels)]


def shape_order(results: pd.DataFrame, floor: pd.DataFrame | None, preferred) -> list[str]:
    """The shapes present, in the dataset's order (``preferred``), then any others as they appear."""
    present = list(dict.fromkeys(list(results["shape"]) + (list(floor["shape"]) if floor is not None
                                                           and "shape" in floor.columns else [])))
    first = [s for s in preferred if s in present]
    return first + [s for s in present if s not in first]


def validity_table(results: pd.DataFrame, floor: pd.DataFrame | None, methods: list[str], caption: str) -> Table:
    """Mesh validity of the predictions per method, mean over successful jobs (GT row from the floor).

    Columns are the result schema's validity columns present (``foundation.schema``); a column
    whose label ends in '%' is a flag, shown as the percentage of jobs where it holds.
    """
    present = [c for c in schema_columns("validity") if c.name in results.columns]
    headers = ["method", "jobs ok"] + [c.label for c in present]
    table = Table("validity", "Mesh validity of the predictions (mean over successful jobs)", caption,
                  headers, [tex_escape(h) for h in headers], ["l"] + ["r"] * (len(headers) - 1))

    def row(frame: pd.DataFrame) -> list[Cell]:
        cells = []
        for c in present:
            values = numeric(frame, c.name).dropna()
            if not len(values):
                cells.append(Cell(DASH))
            elif c.label.endswith("%"):
                cells.append(Cell(fmt(100.0 * as_bool(values).mean(), 0)))
            else:
                cells.append(Cell(fmt(values.mean(), 1)))
        return cells

    ok = ok_jobs(results)
    for m in methods:
        sel = ok[ok["method"] == m]
        table.add([Cell(m), Cell(str(len(sel)))] + row(sel))
    if floor is not None and any(c.name in floor.columns for c in present):
        table.add([Cell("GT"), Cell(str(len(floor)))] + row(floor), "floor")
    return table


#: Marks a per-shape cell whose shape was in the training set of the weights its method used.
SEEN_MARK = "§"


def seen_pairs(results: pd.DataFrame) -> set[tuple[str, str]]:
    """(shape, method) pairs of the jobs whose shape was in the training set of the weights their
    method used (``seen_in_training``)."""
    if "seen_in_training" not in results.columns:
        return set()
    seen = results[as_bool(results["seen_in_training"])]
    return set(zip(seen["shape"], seen["method"]))


def training_overlap_note(results: pd.DataFrame, shapes: list[str]) -> str | None:
    """One paragraph: per method whose weights saw some of ``shapes``, which ones (and what the
    weights were trained on), and the methods for which it is unknown; None when no method's
    weights saw any and none is unknown."""
    if "seen_in_training" not in results.columns:
        return None
    parts = []
    for method, rows in results.groupby("method", sort=False):
        flags = pd.to_numeric(rows["seen_in_training"], errors="coerce")
        seen = sorted(set(rows.loc[flags > 0.5, "shape"]))
        if seen:
            parts.append(f"{method}: its weights were trained on {len(seen)} of the {len(shapes)} shapes "
                         f"({', '.join(seen)}), marked {SEEN_MARK} in the per-shape tables.")
        elif flags.isna().all() and _has_record(rows):
            parts.append(f"{method}: whether its weights saw these shapes is unknown (its weights do not "
                         "record their training shapes).")
    return " ".join(["Seen in training."] + parts) if parts else None


def _has_record(rows: pd.DataFrame) -> bool:
    """Whether these jobs used trained weights with a training record (``info.training_record``)."""
    info = rows["info"] if "info" in rows.columns else pd.Series(dtype=object)
    return bool(info.astype(str).str.contains("training_record", regex=False).any())


def per_shape_table(results: pd.DataFrame, floor: pd.DataFrame | None, metric, methods: list[str],
                    shapes: list[str], caption: str) -> Table:
    """Shapes x methods, the mean over the seeds of successful jobs of one metric.

    A cell is 'failed' where every seed failed (hover text: the error), 'empty' where every
    successful seed predicted an empty mesh, 'NaN' where the metric is otherwise undefined (no
    predicted edge points), a dash where the method has no job. Best per row in bold; the floor
    column is a reference. A value whose shape was in the training set of its method's weights
    carries :data:`SEEN_MARK`.
    """
    seen = seen_pairs(results)
    has_floor = floor is not None and "shape" in floor.columns and metric.column in floor.columns
    headers = ["shape"] + methods + (["floor"] if has_floor else [])
    table = Table(f"shape-{metric.column}", f"Per shape: {metric_header(metric)} (mean over seeds)", caption,
                  headers, ["shape"] + [tex_escape(m) for m in methods] + (["floor"] if has_floor else []),
                  ["l"] + ["r"] * (len(headers) - 1))
    key = [results["shape"], results["method"]]
    ok = ok_jobs(results)
    ok_key = [ok["shape"], ok["method"]]
    n_jobs = results.groupby(key).size()
    n_ok = ok.groupby(ok_key).size()
    mean = numeric(ok, metric.column).groupby(ok_key).mean() * metric.scale
    all_empty = (as_bool(ok["empty_prediction"]).groupby(ok_key).all() if "empty_prediction" in ok.columns
                 else pd.Series(dtype=bool))
    bad = results[results["status"] != "ok"]
    error = bad["error"].groupby([bad["shape"], bad["method"]]).first()  # first non-null per group
    floor_mean = (numeric(floor, metric.column).groupby(floor["shape"]).mean() * metric.scale
                  if has_floor else pd.Series(dtype=float))
    for shape in shapes:
        values = [mean.get((shape, m), np.nan) for m in methods]
        row = [Cell(shape)]
        for m, v, bold in zip(methods, values, best_flags(values, metric.lower_is_better)):
            k = (shape, m)
            if k not in n_jobs.index:
                row.append(Cell(DASH))
            elif k not in n_ok.index:
                row.append(Cell("failed", title=one_line(error.get(k))))
            elif np.isfinite(v):
                row.append(Cell(fmt(v) + (SEEN_MARK if k in seen else ""), bold))
            else:
                row.append(Cell("empty" if all_empty.get(k, False) else "NaN"))
        if has_floor:
            row.append(Cell(fmt(floor_mean.get(shape, np.nan))))
        table.add(row)
    return table


def unscored_table(results: pd.DataFrame, methods: list[str], caption: str) -> Table | None:
    """The successful jobs of shapes without a GT (point clouds given alone): shape, method, seed and
    the prediction's validity counts; None when there are none."""
    jobs = unscored_jobs(results)
    if not len(jobs):
        return None
    present = [c for c in schema_columns("validity") if c.name in jobs.columns]
    headers = ["shape", "method", "seed"] + [c.label for c in present]
    table = Table("unscored", "Reconstructed without a GT (not scored)", caption, headers,
                  [tex_escape(h) for h in headers], ["l", "l", "r"] + ["r"] * len(present))
    rank = {m: i for i, m in enumerate(methods)}
    jobs = jobs.assign(_rank=jobs["method"].map(rank)).sort_values(["shape", "_rank", "seed"], kind="stable")
    counts = pd.DataFrame({c.name: numeric(jobs, c.name) for c in present}, index=jobs.index)
    for i, row in jobs.iterrows():
        cells = [Cell(str(row["shape"])), Cell(str(row["method"])), Cell(str(row["seed"]))]
        for c in present:
            v = counts.at[i, c.name]
            text = DASH if not np.isfinite(v) else ("yes" if v > 0.5 else "no") if c.label.endswith("%") else f"{v:,.0f}"
            cells.append(Cell(text))
        table.add(cells)
    table.notes.append("These point clouds came without a GT mesh: their reconstructions are in meshes/ and counted "
                       "here, and no metric table includes them.")
    return table


def failed_jobs(results: pd.DataFrame) -> pd.DataFrame:
    """shape, method, seed, error of every job whose status is not 'ok'."""
    bad = results[results["status"] != "ok"]
    return bad[["shape", "method", "seed", "error"]].reset_index(drop=True)


def build_summary(results: pd.DataFrame, floor: pd.DataFrame | None, context: dict,
                  components: pd.DataFrame | None = None) -> Summary:
    """Check the frames and the context, compute the statistics and build every table of one run
    (with ``components``, the rows of a decomposed run, its decomposition tables too)."""
    context = check_context(context)
    results = check_results(results)
    floor = check_floor(floor)
    metrics = headline_metrics(context, results.columns)
    methods = method_order(results["method"], context["methods"])
    shapes = shape_order(results, floor, context["shapes"])
    rows = without_unscored(results)  # shapes without a GT: validity only (their own table)
    stats = method_statistics(rows, floor, metrics, methods)
    caption = protocol_caption(context)
    stat_caption = f"{caption} {AGGREGATION}"
    tables = {stat: statistic_table(stats, metrics, stat, key=stat, caption=stat_caption)
              for stat in ("mean", "median", "std")}
    tables["validity"] = validity_table(results, floor, methods, caption)
    tables["mean"].notes += [AGGREGATION, FLOOR_NOTE] + [n for n in [sensors_note(results)] if n]
    tables["std"].notes.append("Sample standard deviation (ddof = 1) over successful jobs; – with fewer than 2.")
    scored_shapes = [s for s in shapes if s in set(rows["shape"])]
    for m in metrics:
        if m.column in PER_SHAPE:
            tables[f"shape-{m.column}"] = per_shape_table(rows, floor, m, methods, scored_shapes, caption)
    overlap = training_overlap_note(rows, scored_shapes)
    if overlap:
        tables["mean"].notes.append(overlap)
        unseen = [s for s in scored_shapes if s not in {shape for shape, _ in seen_pairs(rows)}]
        if unseen:
            kept = rows[rows["shape"].isin(unseen)]
            kept_floor = floor[floor["shape"].isin(unseen)] if floor is not None and "shape" in floor.columns else floor
            tables["mean-unseen"] = statistic_table(
                method_statistics(kept, kept_floor, metrics, methods), metrics, "mean", key="mean-unseen",
                caption=stat_caption, title=f"Mean over the {len(unseen)} shapes no method's weights were trained on")
            tables["mean-unseen"].notes.append(f"Shapes: {', '.join(unseen)}; bold and † over these shapes only.")
    unscored = unscored_table(results, methods, caption)
    if unscored is not None:
        tables["unscored"] = unscored
    tables.update(decomposition_tables(results, components, metrics, methods, caption))
    reference = context.get("reference") or {}
    if reference:
        for key, table in tables.items():
            if key in ("mean", "median", "std", "mean-unseen") or key.startswith("shape-"):
                table.notes.append(reference["note"])
    return Summary(results, floor, metrics, methods, shapes, stats, tables, caption, failed_jobs(results), rows,
                   tuple(reference.get("labels", ())))


def summary_markdown(summary: Summary, title: str) -> str:
    """summary.md: the protocol, every table with its notes, the failed jobs."""
    parts = [f"# {md_escape(title)}", "", md_escape(summary.caption), ""]
    for table in summary.tables.values():
        parts += table_markdown_section(table)
    if len(summary.failed):
        parts += ["## Failed jobs", ""]
        parts += [f"- {md_escape(r.shape)} / {md_escape(r.method)} / seed {r.seed}: {md_escape(one_line(r.error))}"
                  for r in summary.failed.itertuples()]
        parts.append("")
    return "\n".join(parts)


def summary_latex(summary: Summary, title: str) -> str:
    """summary.tex: one booktabs float per table."""
    head = [f"% {one_line(title)}: generated by salsbench (reports.summary). Needs \\usepackage{{booktabs}}.", ""]
    return "\n".join(head) + "\n".join(table_latex(t) for t in summary.tables.values())


def write_statistics(frame: pd.DataFrame, path: Path) -> None:
    """statistics.csv (:func:`reports.statistics.statistics_frame`)."""
    frame.to_csv(path, index=False, float_format="%.6g")


def write_summary(summary: Summary, context: dict, out_dir: Path) -> dict[str, Path]:
    """summary.md, summary.tex and statistics.csv in ``out_dir``; returns {name: path}."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    title = report_title(context)
    paths = {name: out_dir / name for name in ("summary.md", "summary.tex", "statistics.csv")}
    paths["summary.md"].write_text(summary_markdown(summary, title), encoding="utf-8")
    paths["summary.tex"].write_text(summary_latex(summary, title), encoding="utf-8")
    write_statistics(statistics_frame(summary.stats, summary.metrics), paths["statistics.csv"])
    return paths
