"""Sweep tables and plots: how the headline metrics move with a swept setting.

A sweep run (``run_benchmark.py --sweep KEY=V1,V2,...``, repeatable: the cross product) gives the
reports ``context["sweep"] = {key: [values in the user's order]}`` and, in every job's row, its
value of each key in the column ``sweep.<key>`` (:data:`PREFIX`).

Sweep table
    One per swept key: a row per (value, series), the values in the user's order, with the mean of
    every headline metric over the successful jobs of that series at that value (shapes × seeds),
    in the summary tables' units (header multipliers), plus what a sweep needs to read the metrics:
    jobs, failed, the mean face count, boundary edges (holes: the o-threshold ablation) and
    non-manifold edges, how many fits ran (``fitted``; a job served from the cache is not counted)
    and their mean seconds. A second table holds the medians. With several keys, a key's table is the
    marginal (it pools the other keys' values) and one more table has a row per combination.
Noise
    As in the summary tables (:mod:`reports.statistics`, :mod:`reports.significance`), over the
    shapes (each shape's seeds averaged first): every mean of a headline metric carries its 95%
    bootstrap interval, ``4.500 [4.100, 4.930]``, and bold compares the methods *within one value*
    (one combination in the combinations table; "which method wins at this value", never across
    values): the best of a metric column among that value's method rows and every method not
    significantly worse (paired Wilcoxon over shapes; such ties marked †, and under 6 paired shapes
    tied by construction, named in the caption). The median table tests against the best median.
Broadcast rule
    A job whose ``sweep.<key>`` is null does not depend on the key (a method parameter of another
    method, a budget for an oracle job): it is the same job for every value, so it counts in every
    row of that key (a flat reference line in the plot); the caption names those series.
Ceiling rows
    A neural sweep also runs in oracle mode (exact field, no fit). Those jobs (``mode`` other than
    the run's) are their own series, 'sals (oracle)': reference rows in the tables (italics, between
    rules), dashed in the method's colour in the plots. The gap to 'sals' is the fitting error, the
    ceiling itself the extraction error. They never enter the ordinary tables
    (:func:`run_mode_results`).

Files: sweep.md, sweep.tex (booktabs) and sweep.csv (tidy: one row per key × value × series ×
quantity with mean, its interval, p against the value's best mean, median and counts, for
scripts); the report's sweep section (:func:`sweep_html`).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

from foundation.schema import columns as schema_columns
from reports.frames import as_bool, check_results, numeric, without_unscored
from reports.html import esc, notes_html, plot_html, table_html
from reports.plots import STYLE, metric_panels, panels_svg, plot_label
from reports.protocol import check_context, headline_metrics, protocol_caption, report_title, sweep_spec
from reports.significance import mean_intervals
from reports.statistics import TIE, Statistics, Tests, interval_text, legend, tests_against_best
from reports.style import fit_owner, method_colors, method_order
from reports.table import Cell, Table, fmt, md_escape, metric_header, metric_tex_header
from reports.table import table_latex, table_markdown_section, tex_escape

#: Result column of a swept key: ``sweep.<key>``.
PREFIX = "sweep."
#: Column of the expanded frame holding a job's position in a key's values, and its series.
POS, SERIES = "@", "@series"
#: Name of the table over every combination of values (several keys).
COMBINED = "combinations"
#: A numeric axis is logarithmic when its positive values span this factor (a decade or more: the
#: o thresholds 0.02-0.5 crowd their low end on a linear axis; grids 64-256 stay linear).
LOG_SPAN = 10.0
#: Validity means of a sweep table (their labels come from the result schema).
VALIDITY = ("n_faces", "boundary_edges", "nonmanifold_edges")
FIT = "fit_s"
TITLES = {"mean": "mean over shapes and seeds", "median": "median over shapes and seeds"}
SUMMARY_NOTE = "The sections below pool every value of the sweep; the oracle ceiling jobs are left out of them."


@dataclass
class Sweep:
    """A sweep's statistics and tables, computed once (:func:`build_sweep`).

    Attributes
    ----------
    spec : {key: values}, the context's sweep.
    metrics : the headline metrics shown.
    series : display order: methods, then the ceiling series ('sals (oracle)').
    method_of : {series: method}; ceilings : the ceiling series.
    broadcast : {key: series that do not depend on it}.
    stats : {key or :data:`COMBINED`: :func:`sweep_stats` frame in row order, plus ('p_vs_best',
        metric): the mean's p against the best mean at the row's value}.
    tables : {name: Table}; mean table 'sweep-<key>', medians 'sweep-<key>-median'.
    tests : {key or :data:`COMBINED`: {'mean'|'median': Tests}}, rows as in ``stats``, labelled
        (value text(s)..., series); the methods compared within each value (:func:`value_tests`).
    """

    spec: dict[str, list]
    metrics: list
    series: list[str]
    method_of: dict[str, str]
    ceilings: list[str]
    broadcast: dict[str, list[str]]
    stats: dict[str, pd.DataFrame]
    tables: dict[str, Table]
    tests: dict[str, dict[str, Tests]] = field(default_factory=dict)


def axis_scale(values) -> str:
    """The x axis of a key's plot: 'categorical' (any str or bool value), 'log' (positive numbers
    with max/min >= :data:`LOG_SPAN`), else 'linear'."""
    if not len(values) or any(isinstance(v, (bool, np.bool_, str)) or not isinstance(v, numbers.Real)
                              for v in values):
        return "categorical"
    return "log" if min(values) > 0 and max(values) / min(values) >= LOG_SPAN else "linear"


def value_text(value) -> str:
    """A swept value as printed: floats with %g, everything else as str."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def run_mode_results(results: pd.DataFrame, context: dict) -> pd.DataFrame:
    """The jobs of the run's own mode (``mode`` null or context['mode']): the ordinary tables' input,
    without a sweep's ceiling jobs. All jobs when the frame has no ``mode`` column."""
    if "mode" not in results.columns:
        return results
    return results[results["mode"].isna() | (results["mode"].astype(str) == str(context["mode"]))]


def _column(jobs: pd.DataFrame, key: str) -> pd.Series:
    name = PREFIX + key
    return jobs[name] if name in jobs.columns else pd.Series(np.nan, index=jobs.index, dtype=object)


def _equals(column: pd.Series, value) -> pd.Series:
    """Where ``column`` holds ``value``, compared as the context value's type (0/1 as bools)."""
    if isinstance(value, (bool, np.bool_)):
        return column.astype(str).str.lower().isin(("1", "1.0", "true") if value else ("0", "0.0", "false"))
    if isinstance(value, numbers.Real):
        found = np.isclose(pd.to_numeric(column, errors="coerce"), float(value), rtol=1e-9, atol=0.0)
        return pd.Series(found, index=column.index)
    return column.astype(str) == str(value)


def value_index(column: pd.Series, values: list) -> pd.Series:
    """Each job's position in ``values`` (float): NaN where its value is null (the key does not
    apply: broadcast), -1 where it is none of ``values``."""
    hits = pd.concat([_equals(column, v) for v in values], axis=1, ignore_index=True)
    position = hits.idxmax(axis=1).where(hits.any(axis=1), -1).astype(float)
    return position.mask(column.isna())


def expand(jobs: pd.DataFrame, spec: dict[str, list], keys) -> pd.DataFrame:
    """``jobs`` with a column ``@<key>`` per key of ``keys``: the position of the job's value. A job
    whose value is null is repeated once per value (the broadcast rule); one whose value is not in
    the sweep is left out."""
    for key in keys:
        position = value_index(_column(jobs, key), spec[key])
        fixed = jobs[position >= 0].assign(**{POS + key: position[position >= 0].astype(int)})
        every = jobs[position.isna()].merge(pd.DataFrame({POS + key: range(len(spec[key]))}), how="cross")
        jobs = pd.concat([f for f in (fixed, every) if len(f)] or [fixed], ignore_index=True)
    return jobs


def series_labels(jobs: pd.DataFrame, context: dict) -> pd.Series:
    """Each job's series: its method, or 'method (mode)' for a job of another mode (a ceiling)."""
    mode = jobs["mode"] if "mode" in jobs.columns else pd.Series(np.nan, index=jobs.index, dtype=object)
    other = mode.notna() & (mode.astype(str) != str(context["mode"]))
    return jobs["method"].where(~other, jobs["method"] + " (" + mode.astype(str) + ")")


def fitted_jobs(jobs: pd.DataFrame) -> pd.Series:
    """Where a job trained its network: the ``fitted`` flag when the frame has it (a mesh or weights
    from the cache: 0), else a ``fit_s`` without 'weights' in ``cache``."""
    if "fitted" in jobs.columns:
        return as_bool(jobs["fitted"])
    cache = jobs["cache"] if "cache" in jobs.columns else pd.Series(np.nan, index=jobs.index, dtype=object)
    return numeric(jobs, FIT).notna() & ~cache.astype(str).str.contains("weights", na=False)


def sweep_stats(jobs: pd.DataFrame, by: list[str], metrics: list) -> tuple[pd.DataFrame, dict[str, pd.DataFrame]]:
    """(stats, per_shape). stats, per group of the columns ``by``: the counts (``count``: jobs,
    failed, fits run) and the mean, median and n (finite values) over successful jobs of each
    headline metric (table units), each :data:`VALIDITY` column and the seconds of the fits that
    ran, and the headline metrics' ci_low, ci_high (bootstrap interval of the mean over shapes);
    columns (statistic, quantity). per_shape: {metric column: groups x shapes}, the mean over each
    shape's successful seeds (NaN skipped)."""
    jobs = without_unscored(jobs)  # a shape without a GT has no metrics to sweep
    ok = jobs["status"] == "ok"
    fit_s = numeric(jobs, FIT)
    fitted = ok & fitted_jobs(jobs) & fit_s.notna()
    values = pd.DataFrame({**{m.column: numeric(jobs, m.column) * m.scale for m in metrics},
                           **{c: numeric(jobs, c) for c in VALIDITY}, FIT: fit_s.where(fitted)})
    values.loc[~ok] = np.nan
    keys = [jobs[c] for c in by]
    grouped = values.groupby(keys, sort=False)
    counts = pd.DataFrame({"jobs": 1, "failed": ~ok, "fits": fitted}).groupby(keys, sort=False).sum()
    columns = [m.column for m in metrics]
    shapes = values[columns].groupby([*keys, jobs["shape"].rename("@shape")], sort=False).mean()
    per_shape = {c: shapes[c].unstack("@shape").reindex(counts.index) for c in columns}
    bounds = {c: mean_intervals(per_shape[c]) for c in columns}
    ci = {name: pd.DataFrame({c: bounds[c][:, k] for c in columns}, index=counts.index)
          for k, name in enumerate(("ci_low", "ci_high"))}
    return pd.concat({"count": counts, "mean": grouped.mean(), "median": grouped.median(), "n": grouped.count(),
                      **ci}, axis=1), per_shape


def _in_order(stats: pd.DataFrame, levels: list) -> pd.DataFrame:
    """``stats`` in the product order of ``levels`` (values in the user's order, then series)."""
    full = pd.MultiIndex.from_product(levels, names=stats.index.names)
    return stats.reindex(full).dropna(subset=[("count", "jobs")])


def _lead(stats: pd.DataFrame, keys: list[str], spec: dict) -> list[pd.Series]:
    """The row labels of a stats frame: each key's value text, then the series."""
    index = stats.index.to_frame(index=False)
    texts = [index[POS + k].map(dict(enumerate(map(value_text, spec[k])))) for k in keys]
    return texts + [index[SERIES]]


def value_tests(sweep: Sweep, stats: pd.DataFrame, per_shape: dict, keys: list[str]) -> dict[str, Tests]:
    """{'mean'|'median': Tests} of a group's ordered ``stats``: at each value (combination of
    values) its method rows against the best of each metric column there, paired by shape
    (:func:`reports.statistics.tests_against_best`); the ceiling rows are references. Rows
    labelled (value text(s)..., series), as the tables and captions name them."""
    labels = pd.MultiIndex.from_arrays(_lead(stats, keys, sweep.spec))
    columns = [m.column for m in sweep.metrics]
    frames = Statistics({s: stats[s][columns].set_axis(labels) for s in TITLES}, stats["count"].set_axis(labels),
                        {c: per_shape[c].reindex(stats.index).set_axis(labels) for c in columns})
    within = stats.index.droplevel(SERIES).factorize()[0]
    reference = stats.index.get_level_values(SERIES).isin(sweep.ceilings)
    return {s: tests_against_best(frames, sweep.metrics, s, within=within, reference=reference) for s in TITLES}


def sweep_table(sweep: Sweep, group: str, stat: str, caption: str) -> Table:
    """The table of one group (a key, or :data:`COMBINED`) and statistic ('mean' with the validity
    columns, or 'median'): a row per (value(s), series); in bold per value the best of each metric
    column over its method rows and the methods tied with it (:func:`value_tests`, tied ones marked
    †), the means with their intervals, the ceiling rows references."""
    keys = list(sweep.spec) if group == COMBINED else [group]
    stats = sweep.stats[group]
    extra = [c.label for c in schema_columns("validity") if c.name in VALIDITY] + ["fits", "fit s"]
    extra = extra if stat == "mean" else []
    headers = [*keys, "series", "jobs", "failed", *map(metric_header, sweep.metrics), *extra]
    tex_headers = [*map(tex_escape, keys), "series", "jobs", "failed", *map(metric_tex_header, sweep.metrics),
                   *map(tex_escape, extra)]
    what = " × ".join(keys) + (", every combination" if group == COMBINED else "")
    table = Table(f"sweep-{group}" + ("" if stat == "mean" else f"-{stat}"), f"Sweep of {what}: {TITLES[stat]}",
                  caption, headers, tex_headers, ["l"] * (len(keys) + 1) + ["r"] * (len(headers) - len(keys) - 1))
    reference = stats.index.get_level_values(SERIES).isin(sweep.ceilings)
    columns = [m.column for m in sweep.metrics]
    tests = sweep.tests[group][stat]
    values = stats[stat][columns].map(fmt) + np.where(tests.tied.to_numpy(dtype=bool), TIE, "")
    counts = stats["count"][["jobs", "failed"]].astype(int).astype(str)
    validity = stats["mean"][list(VALIDITY) + [FIT]].map(lambda v: fmt(v, 1))
    validity.insert(3, "fits", stats["count"]["fits"].astype(int).astype(str))
    texts = pd.concat([*(s.set_axis(stats.index) for s in _lead(stats, keys, sweep.spec)), counts, values,
                       *([validity] if extra else [])], axis=1)
    intervals = np.vectorize(interval_text, otypes=[object])(stats["ci_low"][columns], stats["ci_high"][columns])
    width = ((0, 0), (len(keys) + 3, len(extra)))  # metric columns -> every column
    flags = np.pad(tests.bold.to_numpy(dtype=bool), width)
    details = np.pad(intervals if stat == "mean" else np.full_like(intervals, ""), width, constant_values="")
    for row, row_bold, row_detail, ref in zip(texts.to_numpy(), flags, details, reference):
        table.add([Cell(str(t), bool(b), detail=d) for t, b, d in zip(row, row_bold, row_detail)],
                  "floor" if ref else "method")
    return table


def _names(series: list[str]) -> str:
    return ", ".join(series) + (" does" if len(series) == 1 else " do")


def sweep_note(sweep: Sweep, group: str, stat: str) -> str:
    """What a sweep table shows: the key(s), the aggregation, the units, the broadcast series, the
    ceiling rows and what bold, † and the intervals mean (:func:`reports.statistics.legend`; one
    paragraph)."""
    keys = list(sweep.spec) if group == COMBINED else [group]
    others = [k for k in sweep.spec if k not in keys]
    parts = [f"Rows: the values of {' × '.join(keys)} in the order given, a row per series; {stat} over the "
             "successful jobs (shapes × seeds)" + (f", pooled over every value of {', '.join(others)} (the "
                                                    "marginal)" if others else "") + ". Metrics in the summary "
             "tables' units (the header's multiplier)."]
    if stat == "mean":
        parts.append("#F, boundary edges, non-manifold edges: means over successful jobs; fits: fits run "
                     "(jobs served from the cache not counted), fit s their mean seconds.")
    parts += [f"{_names(sweep.broadcast[k])} not depend on {k}: the same jobs for each of its values."
              for k in keys if sweep.broadcast[k]]
    if sweep.ceilings:
        parts.append(f"Ceiling rows ({', '.join(sweep.ceilings)}; references, never bold): the same sweep in oracle "
                     "mode (exact field, no fit); the gap to the method is the fitting error, the ceiling the "
                     "extraction error.")
    where = "combination of values" if group == COMBINED else f"value of {group}"
    parts += [f"Bold compares the methods within one {where} (which method wins there), never across values.",
              legend(stat, sweep.tests[group][stat], sweep.metrics, scope="of a metric column among them",
                     csv="sweep.csv")]
    return " ".join(parts)


def build_sweep(results: pd.DataFrame, context: dict) -> Sweep | None:
    """The statistics and tables of a sweep run; None when the context has no sweep."""
    context = check_context(context)
    spec = sweep_spec(context)
    if not spec:
        return None
    jobs = check_results(results)
    jobs[SERIES] = series_labels(jobs, context)
    metrics = headline_metrics(context, jobs.columns)
    methods = method_order(jobs["method"], context["methods"])
    pairs = jobs[[SERIES, "method"]].drop_duplicates()
    pairs = pairs.assign(rank=pairs["method"].map({m: i for i, m in enumerate(methods)}),
                         ceiling=pairs[SERIES] != pairs["method"]).sort_values(["ceiling", "rank"])
    series = list(pairs[SERIES])
    constant = {k: _column(jobs, k).isna().groupby(jobs[SERIES]).all() for k in spec}
    broadcast = {k: [s for s in series if constant[k][s]] for k in spec}
    sweep = Sweep(spec, metrics, series, dict(zip(pairs[SERIES], pairs["method"])),
                  list(pairs.loc[pairs["ceiling"], SERIES]), broadcast, {}, {})
    groups = {k: [k] for k in spec} | ({COMBINED: list(spec)} if len(spec) > 1 else {})
    for group, keys in groups.items():
        by = [POS + k for k in keys] + [SERIES]
        stats, per_shape = sweep_stats(expand(jobs, spec, keys), by, metrics)
        stats = _in_order(stats, [range(len(spec[k])) for k in keys] + [series])
        sweep.tests[group] = value_tests(sweep, stats, per_shape, keys)
        p = sweep.tests[group]["mean"].p.set_axis(stats.index)
        sweep.stats[group] = pd.concat([stats, pd.concat({"p_vs_best": p}, axis=1)], axis=1)
    protocol = protocol_caption(context)
    for group in groups:
        for stat in TITLES:
            note = sweep_note(sweep, group, stat)
            table = sweep_table(sweep, group, stat, f"{note} {protocol}")
            table.notes.append(note)
            sweep.tables[table.key] = table
    return sweep


def sweep_frame(sweep: Sweep) -> pd.DataFrame:
    """sweep.csv: one row per key × value × series × quantity (headline metrics in table units with
    their ``scale``, the validity means, fit seconds), with mean, median, n (finite values), n_jobs,
    n_failed and whether the series is a ceiling or broadcast over the key; for the headline metrics
    also ci_low, ci_high (the mean's interval over shapes) and p_vs_best (the paired Wilcoxon p
    against the best mean at the value, as the table's bold; NaN for the best and the ceilings)."""
    scale = {m.column: m.scale for m in sweep.metrics}
    parts = []
    for key, values in sweep.spec.items():
        stats = sweep.stats[key]
        long = stats[["mean", "ci_low", "ci_high", "p_vs_best", "median", "n"]].stack(level=1).rename_axis(
            ["position", "series", "quantity"])
        counts = stats["count"].rename(columns={"jobs": "n_jobs", "failed": "n_failed"}).rename_axis(
            ["position", "series"])
        long = long.reset_index().merge(counts.reset_index(), on=["position", "series"])
        parts.append(long.assign(key=key, value=long["position"].map(dict(enumerate(values))),
                                 method=long["series"].map(sweep.method_of),
                                 ceiling=long["series"].isin(sweep.ceilings),
                                 broadcast=long["series"].isin(sweep.broadcast[key])))
    out = pd.concat(parts, ignore_index=True)
    out["scale"] = out["quantity"].map(scale).fillna(1.0)
    out[["n", "n_jobs", "n_failed"]] = out[["n", "n_jobs", "n_failed"]].astype(int)
    return out[["key", "value", "series", "method", "ceiling", "broadcast", "quantity", "scale", "mean", "ci_low",
                "ci_high", "p_vs_best", "median", "n", "n_jobs", "n_failed"]]


def sweep_markdown(sweep: Sweep, context: dict) -> str:
    """sweep.md: the protocol, then every sweep table with its note."""
    parts = [f"# {md_escape(report_title(context, 'sweep'))}", "", md_escape(protocol_caption(context)), ""]
    for table in sweep.tables.values():
        parts += table_markdown_section(table)
    return "\n".join(parts)


def write_sweep(sweep: Sweep, context: dict, out_dir: Path) -> dict[str, Path]:
    """sweep.md, sweep.tex and sweep.csv in ``out_dir``; returns {name: path}."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {name: out_dir / name for name in ("sweep.md", "sweep.tex", "sweep.csv")}
    paths["sweep.md"].write_text(sweep_markdown(sweep, context), encoding="utf-8")
    head = (f"% {report_title(context, 'sweep')}: generated by salsbench (reports.sweep). "
            "Needs \\usepackage{booktabs}.\n\n")
    paths["sweep.tex"].write_text(head + "\n".join(table_latex(t) for t in sweep.tables.values()), encoding="utf-8")
    sweep_frame(sweep).to_csv(paths["sweep.csv"], index=False, float_format="%.6g")
    return paths


# ---------------------------------------------------------------------------------------------
# Plot and report section
# ---------------------------------------------------------------------------------------------


def sweep_plot(sweep: Sweep, key: str) -> bytes | None:
    """One panel per headline metric against the key's values (log, linear or categorical x, see
    :func:`axis_scale`): a line per series through its means, method colours, ceilings dashed, a
    series broadcast over the key without markers. SVG bytes; None when there is nothing to plot."""
    values, scale = sweep.spec[key], axis_scale(sweep.spec[key])
    if not sweep.metrics or not sweep.series:
        return None
    x = np.arange(len(values), dtype=float) if scale == "categorical" else np.asarray(values, dtype=float)
    colors = method_colors(list(dict.fromkeys(sweep.method_of.values())))
    means = sweep.stats[key]["mean"]
    with matplotlib.rc_context(STYLE):
        fig, axes, nrows = metric_panels(len(sweep.metrics))
        for ax, metric in zip(axes, sweep.metrics):
            lines = means[metric.column].unstack(SERIES)
            for s in [s for s in sweep.series if s in lines.columns]:
                flat = s in sweep.broadcast[key]  # a constant reference: a line without markers
                ax.plot(x[lines.index], lines[s], color=colors[sweep.method_of[s]], marker="" if flat else "o",
                        ms=4, lw=1.2 if flat else 1.8, ls="--" if s in sweep.ceilings else "-", label=plot_label(s))
            if scale == "log":
                ax.set_xscale("log")
            else:
                ax.set_xticks(x, [plot_label(value_text(v)) for v in values])
            ax.set_title(metric_header(metric))
            ax.set_xlabel(plot_label(key))
        return panels_svg(fig, axes, len(sweep.metrics), nrows)


def cost_seconds(sweep: Sweep, key: str) -> pd.DataFrame:
    """The x of each cost-plot point: the mean seconds of the fits that ran, per value of ``key``
    (rows, positions) and series (columns). A series whose method extracts another method's fits
    (``sdf-ndc``: ``sdf``'s, :func:`reports.style.fit_owner`) and ran none itself gets the seconds
    of that method's series at the same value: what its field cost."""
    seconds = sweep.stats[key]["mean"][FIT].unstack(SERIES)
    for s in [s for s in sweep.series if s in seconds.columns]:
        owner = s.replace(sweep.method_of[s], fit_owner(sweep.method_of[s]), 1)
        if owner != s and owner in seconds.columns:
            seconds[s] = seconds[s].fillna(seconds[owner])
    return seconds


def cost_plot(sweep: Sweep, key: str) -> bytes | None:
    """One panel per headline metric against the mean seconds of the fits that ran (log x): a line
    per series through the key's values (:func:`cost_seconds`: a method extracting another's fits
    at that method's seconds), its 95% bootstrap band of the mean over shapes shaded, each point
    labelled with its value. For a budget key (``budget.steps``, ...), where the
    x axis of :func:`sweep_plot` is the setting and this one its cost. SVG bytes; None when no
    series has fit seconds at two values or more."""
    stats = sweep.stats[key]
    seconds = cost_seconds(sweep, key)
    fitted = [s for s in sweep.series if s in seconds.columns and seconds[s].notna().sum() >= 2]
    if not sweep.metrics or not fitted:
        return None
    colors = method_colors(list(dict.fromkeys(sweep.method_of.values())))
    labels = [value_text(v) for v in sweep.spec[key]]
    with matplotlib.rc_context(STYLE):
        fig, axes, nrows = metric_panels(len(sweep.metrics))
        for ax, metric in zip(axes, sweep.metrics):
            mean, low, high = (stats[stat][metric.column].unstack(SERIES) for stat in ("mean", "ci_low", "ci_high"))
            for s in fitted:
                x, ok = seconds[s], seconds[s].notna() & mean[s].notna()
                color = colors[sweep.method_of[s]]
                ax.plot(x[ok], mean[s][ok], color=color, marker="o", ms=4, lw=1.8, label=plot_label(s))
                ax.fill_between(x[ok], low[s][ok], high[s][ok], color=color, alpha=0.15, lw=0)
                for position in np.flatnonzero(ok.to_numpy()):
                    ax.annotate(plot_label(labels[int(x.index[position])]), (x.iloc[position], mean[s].iloc[position]),
                                fontsize=6, xytext=(2, 2), textcoords="offset points", color=color)
            ax.set_xscale("log")
            ax.set_title(metric_header(metric))
            ax.set_xlabel("mean fit seconds")
        return panels_svg(fig, axes, len(sweep.metrics), nrows)


def sweep_html(sweep: Sweep) -> str:
    """The report's sweep section: per key its plot, mean table and note (medians folded), then the
    table over every combination."""
    parts = [f'<p class="note">{esc(SUMMARY_NOTE)}</p>']
    for group in [*sweep.spec, *([COMBINED] if COMBINED in sweep.stats else [])]:
        mean, median = sweep.tables[f"sweep-{group}"], sweep.tables[f"sweep-{group}-median"]
        plot = plot_html(sweep_plot, sweep, group, alt=f"metrics against {group}") if group in sweep.spec else ""
        if group.startswith("budget."):  # a budget setting: its cost axis too
            plot += plot_html(cost_plot, sweep, group, alt=f"metrics against the fit seconds of each {group}")
        parts.append(f"<h3>{esc(mean.title)}</h3>{plot}{table_html(mean)}{notes_html(mean)}"
                     f"<details><summary>{esc(median.title)}</summary>{table_html(median)}</details>")
    return "".join(parts)
