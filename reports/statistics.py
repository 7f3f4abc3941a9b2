"""Per-method statistics of the headline metrics, their job counts, and the one table built from them.

Aggregation (:data:`AGGREGATION`, stated in every caption): a method's statistics are over its
successful jobs (status 'ok'), i.e. over shapes x seeds; failed jobs are counted, never averaged. A
metric that is NaN for a job is skipped by its mean, median and std, and the counts say how many:

* an empty (or degenerate) prediction has CD and NC NaN and F1 = EF1 = 0 (``empty_prediction``
  set), so CD and NC are over the non-empty predictions while F1 and EF1 include the empty ones as 0;
  the ``empty`` column counts them (a dash when the frame does not record the flag);
* ECD is NaN for an empty prediction and for one without sharp-edge points (``ecd_flag``; presets
  without an origin fallback): the ``ECD NaN`` column, next to ECD, counts them.

std is the sample standard deviation (ddof = 1). Values are in table units: the raw value times
the preset's multiplier (``HeadlineMetric.scale``). The floor (GT against a resample of itself) is a
reference row, never bold; best per column (lowest CD/ECD, highest NC/F1/EF1, at the printed
precision, ties all bold) is bold among the methods.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from reports.frames import as_bool, numeric, ok_jobs
from reports.table import DASH, Cell, Table, best_flags, fmt, metric_header, metric_tex_header

FLOOR_LABEL = "floor (GT vs resample)"
STATS = ("mean", "median", "std")
TITLES = {"mean": "Mean over shapes and seeds", "median": "Median over shapes and seeds",
          "std": "Standard deviation over shapes and seeds"}
AGGREGATION = ("Over successful jobs (shapes × seeds); failed jobs are counted, never averaged. CD, NC: over "
               "non-empty predictions ('empty' counts the others); F1, EF1: over all successful jobs, an empty "
               "prediction scoring 0; ECD: over jobs with a defined ECD ('ECD NaN' counts the others: empty "
               "predictions and predictions without sharp-edge points).")


@dataclass
class Statistics:
    """Statistics of the headline metrics per row (a method, or :data:`FLOOR_LABEL`).

    Attributes
    ----------
    values : {'mean'|'median'|'std': DataFrame, rows x metric columns, table units}.
    counts : DataFrame, same rows; columns ``jobs, failed, empty, ecd_nan`` (``failed`` NaN for
        the floor, ``empty`` NaN when the frame has no ``empty_prediction`` column).
    """

    values: dict[str, pd.DataFrame]
    counts: pd.DataFrame


def _counts(jobs: pd.DataFrame, row: pd.Series, rows: list) -> pd.DataFrame:
    """jobs, failed, empty, ecd_nan per row label; ``row`` holds each job's label."""
    ok = jobs["status"] == "ok" if "status" in jobs.columns else pd.Series(True, index=jobs.index)
    has_empty = "empty_prediction" in jobs.columns
    flags = pd.DataFrame({"jobs": True, "failed": ~ok,
                          "empty": ok & as_bool(jobs["empty_prediction"]) if has_empty else False,
                          "ecd_nan": ok & numeric(jobs, "ecd").isna()}, index=jobs.index)
    counts = flags.groupby(row).sum().reindex(rows, fill_value=0).astype(float)
    if not has_empty:
        counts["empty"] = np.nan
    return counts


def method_statistics(results: pd.DataFrame, floor: pd.DataFrame | None, metrics: list,
                      methods: list[str]) -> Statistics:
    """Mean, median, std and counts per method (rows in ``methods`` order), plus a floor row.

    Parameters
    ----------
    results : checked results frame (:func:`reports.frames.check_results`).
    floor : checked floor frame or None.
    metrics : ``benchmark.metrics.HeadlineMetric`` s to aggregate.
    methods : row order.
    """
    columns = [m.column for m in metrics]
    scale = pd.Series({m.column: m.scale for m in metrics}, dtype=float)
    ok = ok_jobs(results)
    raw = pd.DataFrame({c: numeric(ok, c) for c in columns}, index=ok.index)
    grouped = raw.groupby(ok["method"])
    values = {stat: grouped.agg(stat).reindex(index=methods, columns=columns) * scale for stat in STATS}
    counts = _counts(results, results["method"], methods)
    if floor is not None:
        floor_raw = pd.DataFrame({c: numeric(floor, c) for c in columns}, index=floor.index)
        for stat in STATS:
            values[stat].loc[FLOOR_LABEL] = floor_raw.agg(stat) * scale
        counts.loc[FLOOR_LABEL] = _counts(floor, pd.Series(FLOOR_LABEL, index=floor.index), [FLOOR_LABEL]).iloc[0]
        counts.loc[FLOOR_LABEL, "failed"] = np.nan  # the floor is a reference, not a job that can fail
    return Statistics(values, counts)


def _count_text(value) -> str:
    return DASH if value is None or not np.isfinite(value) else str(int(value))


def statistic_table(stats: Statistics, metrics: list, stat: str, *, key: str, caption: str,
                    lead: tuple[str, ...] = ("method",), title: str | None = None) -> Table:
    """Rows x metrics table of one statistic, with the jobs / failed / empty counts and 'ECD NaN'
    next to ECD.

    Rows are those of ``stats`` in order; an index entry is a tuple with one label per ``lead``
    column (a plain string when ``lead`` has one column), the last being a method or
    :data:`FLOOR_LABEL`. Best per column in bold over all method rows (never for 'std').
    """
    headers, tex_headers = [*lead, "jobs", "failed", "empty"], [*lead, "jobs", "failed", "empty"]
    for m in metrics:
        headers.append(metric_header(m))
        tex_headers.append(metric_tex_header(m))
        if m.column == "ecd":
            headers.append("ECD NaN")
            tex_headers.append("ECD NaN")
    table = Table(key, title or TITLES[stat], caption, headers, tex_headers,
                  ["l"] * len(lead) + ["r"] * (len(headers) - len(lead)))
    values = stats.values[stat]
    counts = stats.counts.reindex(values.index)
    labels = [k if isinstance(k, tuple) else (k,) for k in values.index]
    is_method = [label[-1] != FLOOR_LABEL for label in labels]
    method_rows = [i for i, yes in enumerate(is_method) if yes]
    bold = {m.column: dict(zip(method_rows, best_flags([values[m.column].iloc[i] for i in method_rows],
                                                       m.lower_is_better)))
            for m in metrics} if stat != "std" else {}
    for i, label in enumerate(labels):
        c = counts.iloc[i]
        cells = [Cell(str(part)) for part in label]
        cells += [Cell(_count_text(c["jobs"])), Cell(_count_text(c["failed"])), Cell(_count_text(c["empty"]))]
        for m in metrics:
            cells.append(Cell(fmt(values[m.column].iloc[i]), bold=bold.get(m.column, {}).get(i, False)))
            if m.column == "ecd":
                cells.append(Cell(_count_text(c["ecd_nan"])))
        table.add(cells, "method" if is_method[i] else "floor")
    return table
