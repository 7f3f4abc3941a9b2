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
reference row, never bold.

Noise (:mod:`reports.significance`, stated in the captions by :func:`legend`): both tools work on
one value per shape, the mean over the shape's seeds under the same NaN rules (``per_shape``).

* The mean table shows each mean with the 95% percentile-bootstrap interval of the mean over shapes
  (2,000 resamples, seed 0), as ``4.500 [4.100, 4.930]``; the floor's too.
* Bold (mean and median tables, never 'std'): the best of a column (lowest CD/ECD, highest
  NC/F1/EF1; ties at the printed precision all best) and every method *not significantly worse*
  than the method of the best value: a two-sided paired Wilcoxon signed-rank test over the shapes
  both have, p < 0.05 with the ranks on the best's side being "worse". So a difference inside the
  noise prints as a tie (bold, marked †), never as a win; with fewer than 6 paired shapes the test
  cannot reach p < 0.05 and the table names the methods that tie for that reason. The median table
  tests against the best median's method the same way.
* :func:`statistics_frame` (statistics.csv) holds every row's mean, interval, median, std, paired
  shapes, p against the best mean and bold/tied flags.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from reports.frames import as_bool, numeric, ok_jobs
from reports.significance import (
    ALPHA,
    CONFIDENCE,
    MIN_PAIRS,
    N_RESAMPLES,
    SEED,
    against_best,
    mean_intervals,
    tied_with_best,
)
from reports.table import DASH, Cell, Table, fmt, metric_header, metric_tex_header

FLOOR_LABEL = "floor (GT vs resample)"
STATS = ("mean", "median", "std")
TITLES = {"mean": "Mean over shapes and seeds", "median": "Median over shapes and seeds",
          "std": "Standard deviation over shapes and seeds"}
AGGREGATION = ("Over successful jobs (shapes × seeds); failed jobs are counted, never averaged. CD, NC: over "
               "non-empty predictions ('empty' counts the others); F1, EF1: over all successful jobs, an empty "
               "prediction scoring 0; ECD: over jobs with a defined ECD ('ECD NaN' counts the others: empty "
               "predictions and predictions without sharp-edge points).")
TIE = "†"
CI_LEGEND = (f"[low, high]: {CONFIDENCE:.0%} percentile-bootstrap confidence interval of the mean over shapes (seeds "
             f"averaged per shape first; {N_RESAMPLES:,} resamples of the shapes, seed {SEED}).")


@dataclass
class Statistics:
    """Statistics of the headline metrics per row (a method, or :data:`FLOOR_LABEL`).

    Attributes
    ----------
    values : {'mean'|'median'|'std'|'ci_low'|'ci_high': DataFrame, rows x metric columns, table
        units}; the interval is the bootstrap one of the mean over shapes (NaN under 2 shapes).
    counts : DataFrame, same rows; columns ``jobs, failed, empty, ecd_nan`` (``failed`` NaN for
        the floor, ``empty`` NaN when the frame has no ``empty_prediction`` column).
    per_shape : {metric column: DataFrame, same rows x shapes}: the mean over the shape's
        successful seeds (NaN skipped; NaN where none), table units.
    """

    values: dict[str, pd.DataFrame]
    counts: pd.DataFrame
    per_shape: dict[str, pd.DataFrame]


@dataclass
class Tests:
    """One statistic's method rows against the best of each column (frames rows x metric columns,
    the floor and rows without a value: p NaN, pairs 0, flags False).

    Attributes
    ----------
    p : two-sided paired Wilcoxon p against the column's best row (NaN for that row itself).
    pairs : shapes the row shares with it.
    bold : the best at the printed precision, or not significantly worse.
    tied : bold but not the best itself (marked :data:`TIE`).
    """

    p: pd.DataFrame
    pairs: pd.DataFrame
    bold: pd.DataFrame
    tied: pd.DataFrame


def _label(key) -> tuple:
    return key if isinstance(key, tuple) else (key,)


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


def _shape_means(raw: pd.DataFrame, row: pd.Series, shape: pd.Series, rows) -> dict[str, pd.DataFrame]:
    """{column: rows x shapes} means of ``raw`` per (row label, shape), NaN skipped."""
    means = raw.groupby([row.rename("row"), shape.rename("shape")]).mean()
    return {c: means[c].unstack("shape").reindex(rows) for c in raw.columns}


def method_statistics(results: pd.DataFrame, floor: pd.DataFrame | None, metrics: list,
                      methods: list[str]) -> Statistics:
    """Mean, median, std, the mean's interval and counts per method (rows in ``methods`` order),
    plus a floor row.

    Parameters
    ----------
    results : checked results frame (:func:`reports.frames.check_results`).
    floor : checked floor frame or None (one row per shape; its rows are the shapes when it has no
        ``shape`` column).
    metrics : ``foundation.metrics.HeadlineMetric`` s to aggregate.
    methods : row order.
    """
    columns = [m.column for m in metrics]
    scale = pd.Series({m.column: m.scale for m in metrics}, dtype=float)
    ok = ok_jobs(results)
    raw = pd.DataFrame({c: numeric(ok, c) for c in columns}, index=ok.index) * scale
    grouped = raw.groupby(ok["method"])
    values = {stat: grouped.agg(stat).reindex(index=methods, columns=columns) for stat in STATS}
    counts = _counts(results, results["method"], methods)
    parts = [(raw, ok["method"], ok["shape"])]
    if floor is not None:
        floor_raw = pd.DataFrame({c: numeric(floor, c) for c in columns}, index=floor.index) * scale
        for stat in STATS:
            values[stat].loc[FLOOR_LABEL] = floor_raw.agg(stat)
        counts.loc[FLOOR_LABEL] = _counts(floor, pd.Series(FLOOR_LABEL, index=floor.index), [FLOOR_LABEL]).iloc[0]
        counts.loc[FLOOR_LABEL, "failed"] = np.nan  # the floor is a reference, not a job that can fail
        shape = floor["shape"] if "shape" in floor.columns else pd.Series(floor.index.astype(str), index=floor.index)
        parts.append((floor_raw, pd.Series(FLOOR_LABEL, index=floor.index), shape))
    raw_all, row_all, shape_all = (pd.concat([part[k] for part in parts], ignore_index=True) for k in range(3))
    per_shape = _shape_means(raw_all, row_all, shape_all, values["mean"].index)
    bounds = {c: mean_intervals(per_shape[c]) for c in columns}
    for k, name in enumerate(("ci_low", "ci_high")):
        values[name] = pd.DataFrame({c: bounds[c][:, k] for c in columns}, index=values["mean"].index)
    return Statistics(values, counts, per_shape)


def tests_against_best(stats: Statistics, metrics: list, stat: str, *, within=None, reference=None) -> Tests:
    """The method rows of ``stats.values[stat]`` against each column's best row, paired by shape
    (:func:`reports.significance.against_best`, :func:`reports.significance.tied_with_best`).

    ``within``: a group label per row (the sweep tables: a swept value), rows compared only with
    their group's (default: one group); ``reference``: a flag per row, rows never compared nor bold
    (default: the :data:`FLOOR_LABEL` rows)."""
    center = stats.values[stat]
    if reference is None:
        reference = [_label(k)[-1] == FLOOR_LABEL for k in center.index]
    is_method = ~np.asarray(reference, dtype=bool)
    groups = pd.factorize(np.zeros(len(center)) if within is None else np.asarray(within))[0]
    columns = [m.column for m in metrics]
    tests = Tests(*(pd.DataFrame(fill, index=center.index, columns=columns) for fill in (np.nan, 0, False, False)))
    for g in range(groups.max(initial=-1) + 1):
        for j, m in enumerate(metrics):
            c = center[m.column].to_numpy(dtype=float)
            rows = np.flatnonzero(is_method & (groups == g) & np.isfinite(c))
            if not len(rows):
                continue
            matrix = stats.per_shape[m.column].reindex(center.index).to_numpy(dtype=float)[rows]
            best = int(np.argmin(c[rows]) if m.lower_is_better else np.argmax(c[rows]))
            p, pairs, worse = against_best(matrix, best, m.lower_is_better)
            bold, tied = tied_with_best(c[rows], worse, m.lower_is_better)
            for target, value in ((tests.p, p), (tests.pairs, pairs), (tests.bold, bold), (tests.tied, tied)):
                target.iloc[rows, j] = value
    return tests


def legend(stat: str, tests: Tests, metrics: list, *, scope: str = "of a column", csv: str = "statistics.csv") -> str:
    """What bold, † (and for the mean the interval) mean in a table of ``stat``, and which methods
    tie only because they share fewer than :data:`MIN_PAIRS` shapes with the best (named by their
    row labels, joined by ' / '). ``scope`` says where the best is taken, ``csv`` where the p-values are."""
    text = (f"Bold: the best {stat} {scope} (ties at the printed precision all best) and every method not "
            f"significantly worse than it: two-sided paired Wilcoxon signed-rank test against the best over the "
            f"shapes both have (seeds averaged per shape), worse: p < {ALPHA:g} with the paired differences favouring "
            f"the best. "
            f"{TIE} marks these ties: a difference inside the noise is a tie, never a win.")
    few = tests.tied & (tests.pairs < MIN_PAIRS)
    if few.to_numpy().any():
        names = {m.column: m.name for m in metrics}
        items = [f"{' / '.join(map(str, _label(k)))} ({', '.join(names[c] for c in few.columns[few.loc[k]])})"
                 for k in few.index[few.any(axis=1)]]
        text += (f" Fewer than {MIN_PAIRS} shapes in common with the best, where no test can reach p < {ALPHA:g}, so "
                 f"tied by construction: {'; '.join(items)}.")
    return f"{text} {CI_LEGEND} p-values in {csv}." if stat == "mean" else text


def statistics_frame(stats: Statistics, metrics: list, lead: tuple[str, ...] = ("method",)) -> pd.DataFrame:
    """statistics.csv: one row per (row, metric): ``lead`` labels, metric column, scale, shapes (with
    a value), mean, ci_low, ci_high, median, std (table units), then against the best mean: pairs,
    p_vs_best, bold, tied (as in the mean table)."""
    tests = tests_against_best(stats, metrics, "mean")
    index = stats.values["mean"].index
    labels = pd.DataFrame([_label(k) for k in index], columns=list(lead))
    numbers = ("mean", "ci_low", "ci_high", "median", "std")
    parts = [labels.assign(metric=m.column, scale=m.scale,
                           shapes=stats.per_shape[m.column].reindex(index).notna().sum(axis=1).to_numpy(),
                           **{s: stats.values[s][m.column].to_numpy() for s in numbers},
                           pairs=tests.pairs[m.column].to_numpy(), p_vs_best=tests.p[m.column].to_numpy(),
                           bold=tests.bold[m.column].to_numpy(), tied=tests.tied[m.column].to_numpy())
             for m in metrics]
    return pd.concat(parts).sort_index(kind="stable").reset_index(drop=True)


def _count_text(value) -> str:
    return DASH if value is None or not np.isfinite(value) else str(int(value))


def interval_text(low, high) -> str:
    """A mean's interval as its cell's detail: '[4.100, 4.930]'; empty without both bounds."""
    return f"[{fmt(low)}, {fmt(high)}]" if np.isfinite(low) and np.isfinite(high) else ""


def _interval(stats: Statistics, column: str, i: int) -> str:
    return interval_text(stats.values["ci_low"][column].iloc[i], stats.values["ci_high"][column].iloc[i])


def statistic_table(stats: Statistics, metrics: list, stat: str, *, key: str, caption: str,
                    lead: tuple[str, ...] = ("method",), title: str | None = None) -> Table:
    """Rows x metrics table of one statistic, with the jobs / failed / empty counts and 'ECD NaN'
    next to ECD.

    Rows are those of ``stats`` in order; an index entry is a tuple with one label per ``lead``
    column (a plain string when ``lead`` has one column), the last being a method or
    :data:`FLOOR_LABEL`. Bold and † over all method rows by :func:`tests_against_best` (never for
    'std'), the mean with its interval; the caption gets :func:`legend`, which is also the first note.
    """
    headers, tex_headers = [*lead, "jobs", "failed", "empty"], [*lead, "jobs", "failed", "empty"]
    for m in metrics:
        headers.append(metric_header(m))
        tex_headers.append(metric_tex_header(m))
        if m.column == "ecd":
            headers.append("ECD NaN")
            tex_headers.append("ECD NaN")
    tests = tests_against_best(stats, metrics, stat) if stat != "std" else None
    text = legend(stat, tests, metrics) if tests is not None else ""
    table = Table(key, title or TITLES[stat], f"{caption} {text}".strip(), headers, tex_headers,
                  ["l"] * len(lead) + ["r"] * (len(headers) - len(lead)), notes=[text] if text else [])
    values = stats.values[stat]
    counts = stats.counts.reindex(values.index)
    none = pd.DataFrame(False, index=values.index, columns=values.columns)
    bold, tied = (tests.bold, tests.tied) if tests is not None else (none, none)
    for i, row_key in enumerate(values.index):
        label, c = _label(row_key), counts.iloc[i]
        cells = [Cell(str(part)) for part in label]
        cells += [Cell(_count_text(c["jobs"])), Cell(_count_text(c["failed"])), Cell(_count_text(c["empty"]))]
        for m in metrics:
            cells.append(Cell(fmt(values[m.column].iloc[i]) + (TIE if tied[m.column].iloc[i] else ""),
                              bold=bool(bold[m.column].iloc[i]),
                              detail=_interval(stats, m.column, i) if stat == "mean" else ""))
            if m.column == "ecd":
                cells.append(Cell(_count_text(c["ecd_nan"])))
        table.add(cells, "floor" if label[-1] == FLOOR_LABEL else "method")
    return table
