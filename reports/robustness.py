"""Robustness tables and plots: the point-cloud methods against graded input corruptions.

A run that sweeps ``pc_corruption`` (``--recipe robustness``: every name of
:data:`foundation.corruptions.CORRUPTIONS`) gets, per corruption kind (noise, outliers, missing,
density, misalign), the sweep machinery of :mod:`reports.sweep` on the levels of that kind:

Levels
    ``uniform`` (area-uniform samples, the paper's input), ``scan`` (the clean virtual scan every
    level starts from: level 0), then levels 1, 2, 3; the ``uniform`` and ``scan`` jobs are the same
    jobs in every kind's table.
Tables
    Per kind a mean and a median table (a row per level and method: the headline metrics, jobs,
    failed, faces, boundary and non-manifold edges), bold within each level as in the sweep tables
    (the best and every method a paired Wilcoxon test over shapes cannot tell from it).
Overview
    Per headline metric one table of its mean on every input (a row per input: uniform, scan, then
    each kind's levels; a column per method), bold as in the per-kind tables.
Plots
    One figure per headline metric: a panel per kind, the metric's mean against the level, one line
    per method.
Order and monotonicity
    Per kind, the methods ordered by mean Chamfer distance at each level (where the order changes
    is where a corruption hurts methods unequally), and whether each method's mean Chamfer distance
    grows at every step scan -> 1 -> 2 -> 3 (the ladder's sanity check).

Files: robustness.md and robustness.csv (sweep.csv's tidy rows with a ``kind`` column); the report's
robustness section (:func:`robustness_html`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

from foundation.corruptions import KINDS
from reports.frames import sensors_note
from reports.html import esc, notes_html, plot_html, table_html
from reports.plots import STYLE, metric_panels, panels_svg, plot_label
from reports.protocol import check_context, protocol_caption, report_title, sweep_spec
from reports.style import method_colors
from reports.statistics import TIE
from reports.sweep import POS, PREFIX, SERIES, Sweep, build_sweep, sweep_frame
from reports.table import Cell, Table, fmt, md_escape, metric_header, metric_tex_header, table_markdown_section

#: The swept setting this module reads, and the sweep key of its per-kind tables.
KEY, LEVEL = "pc_corruption", "level"
#: The levels of every kind's table, as printed (0 is the clean scan).
REFERENCES = ("uniform", "scan")
#: The metric that orders the methods (lower is better).
ORDER_METRIC = "cd"


@dataclass
class Robustness:
    """Per corruption kind, the :class:`reports.sweep.Sweep` of its levels (``spec['level']``:
    the level texts present, in ladder order) and the notes on order and monotonicity."""

    kinds: dict[str, Sweep]
    notes: dict[str, list[str]]


def level_names(kind: str) -> list[str]:
    """The corruption names of one kind's table, in ladder order: uniform, scan, kind-1..3."""
    return [*REFERENCES, *(f"{kind}-{level}" for level in (1, 2, 3))]


def level_text(name: str) -> str:
    """A corruption name as its table's level: 'uniform', 'scan', or the level digit."""
    return name if name in REFERENCES else name.rsplit("-", 1)[1]


def build_robustness(results: pd.DataFrame, context: dict) -> Robustness | None:
    """The robustness tables of a run whose only sweep key is ``pc_corruption``; None otherwise, or
    when no kind has a graded level in the sweep."""
    context = check_context(context)
    spec = sweep_spec(context)
    if list(spec) != [KEY]:
        return None
    swept = [str(v) for v in spec[KEY]]
    column = results[PREFIX + KEY].astype(str) if PREFIX + KEY in results.columns else None
    if column is None:
        return None
    kinds, notes = {}, {}
    for kind in KINDS:
        names = [n for n in level_names(kind) if n in swept]
        if not any(n not in REFERENCES for n in names):
            continue
        jobs = results[column.isin(names)].drop(columns=[PREFIX + KEY])
        jobs[PREFIX + LEVEL] = column[column.isin(names)].map(level_text)
        sweep = build_sweep(jobs, {**context, "sweep": {LEVEL: [level_text(n) for n in names]}})
        note = sensors_note(jobs)
        for table in sweep.tables.values():
            table.key = table.key.replace(f"sweep-{LEVEL}", f"robustness-{kind}")
            table.title = table.title.replace(f"Sweep of {LEVEL}", f"Robustness to {kind}: levels")
            if note:
                table.notes.append(note)
        sweep.tables = {table.key: table for table in sweep.tables.values()}
        kinds[kind] = sweep
        notes[kind] = order_notes(sweep)
    return Robustness(kinds, notes) if kinds else None


def _means(sweep: Sweep, column: str) -> pd.DataFrame:
    """levels x series: the mean of one metric column (table units), levels as printed."""
    means = sweep.stats[LEVEL]["mean"][column].unstack(SERIES)
    means.index = [sweep.spec[LEVEL][int(i)] for i in means.index]
    return means[[s for s in sweep.series if s in means.columns]]


def order_notes(sweep: Sweep) -> list[str]:
    """The methods ordered by mean CD at each level, and which methods' mean CD grows at every
    step from the clean scan up (monotone degradation) and which do not."""
    if ORDER_METRIC not in [m.column for m in sweep.metrics]:
        return []
    means = _means(sweep, ORDER_METRIC)
    lines = []
    for level, row in means.iterrows():
        ranked = row.dropna().sort_values(kind="stable")
        lines.append(f"Order by mean CD at {level}: " + " < ".join(f"{s} ({v:.3g})" for s, v in ranked.items()))
    ladder = [lv for lv in means.index if lv not in ("uniform",)]
    if len(ladder) >= 2:
        steps = means.loc[ladder].diff().iloc[1:]
        monotone = [s for s in means.columns if (steps[s] > 0).all()]
        other = [s for s in means.columns if s not in monotone]
        lines.append(f"Mean CD grows at every step {' -> '.join(ladder)}: {', '.join(monotone) or 'none'}"
                     + (f"; not for {', '.join(other)}" if other else "") + ".")
    return lines


def overview_table(robustness: Robustness, column: str) -> Table | None:
    """The mean of one headline metric on every input (rows: ``uniform``, ``scan``, then every
    kind's levels by name) for every method (columns), bold and † as in the per-kind tables (the
    same paired tests within one input). None when the run has no such metric."""
    first = next(iter(robustness.kinds.values()))
    metric = next((m for m in first.metrics if m.column == column), None)
    if metric is None:
        return None
    series = list(first.series)
    cells: dict[str, dict[str, Cell]] = {}
    for kind, sweep in robustness.kinds.items():
        stats, tests = sweep.stats[LEVEL], sweep.tests[LEVEL]["mean"]
        index = stats.index.to_frame(index=False)
        levels = index[POS + LEVEL].map(lambda i: sweep.spec[LEVEL][int(i)])
        names = levels.where(levels.isin(REFERENCES), kind + "-" + levels)
        text = stats["mean"][column].map(fmt).to_numpy() + np.where(tests.tied[column].to_numpy(dtype=bool), TIE, "")
        for name, method, value, bold in zip(names, index[SERIES], text, tests.bold[column].to_numpy(dtype=bool)):
            cells.setdefault(name, {})[method] = Cell(value, bool(bold))
    header = metric_header(metric)
    table = Table(f"robustness-overview-{column}", f"Every input: mean {header}", "", ["input", *series],
                  ["input", *series], ["l"] + ["r"] * len(series))
    table.tex_headers[0] = f"input ({metric_tex_header(metric)})"
    for name, row in cells.items():
        table.add([Cell(name), *(row.get(s, Cell("")) for s in series)])
    table.notes.append(f"{header}: the mean over the shapes; bold per input (row) as in the per-kind tables.")
    return table


def robustness_frame(robustness: Robustness) -> pd.DataFrame:
    """robustness.csv: the tidy rows of :func:`reports.sweep.sweep_frame` of every kind, with the
    column ``kind`` first (key 'level', values as printed)."""
    frames = [sweep_frame(s).assign(kind=k) for k, s in robustness.kinds.items()]
    out = pd.concat(frames, ignore_index=True)
    return out[["kind", *[c for c in out.columns if c != "kind"]]]


def robustness_markdown(robustness: Robustness, context: dict) -> str:
    """robustness.md: the protocol, then per kind its order notes and its tables."""
    parts = [f"# {md_escape(report_title(context, 'robustness'))}", "", md_escape(protocol_caption(context)), ""]
    first = next(iter(robustness.kinds.values()))
    for metric in first.metrics:
        parts += table_markdown_section(overview_table(robustness, metric.column))
    for kind, sweep in robustness.kinds.items():
        parts += [f"## {kind}", ""] + [f"- {md_escape(line)}" for line in robustness.notes[kind]] + [""]
        for table in sweep.tables.values():
            parts += table_markdown_section(table)
    return "\n".join(parts)


def write_robustness(robustness: Robustness, context: dict, out_dir: Path) -> dict[str, Path]:
    """robustness.md and robustness.csv in ``out_dir``; returns {name: path}."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {name: out_dir / name for name in ("robustness.md", "robustness.csv")}
    paths["robustness.md"].write_text(robustness_markdown(robustness, context), encoding="utf-8")
    robustness_frame(robustness).to_csv(paths["robustness.csv"], index=False, float_format="%.6g")
    return paths


def robustness_plot(robustness: Robustness, column: str) -> bytes | None:
    """One figure for one headline metric: a panel per kind, the mean against the level (uniform,
    scan, 1, 2, 3), a line per method in its colour. SVG bytes; None when there is nothing to plot."""
    kinds = list(robustness.kinds)
    first = robustness.kinds[kinds[0]]
    metric = next((m for m in first.metrics if m.column == column), None)
    if metric is None:
        return None
    colors = method_colors(list(dict.fromkeys(first.method_of.values())))
    with matplotlib.rc_context(STYLE):
        fig, axes, nrows = metric_panels(len(kinds))
        for ax, kind in zip(axes, kinds):
            sweep = robustness.kinds[kind]
            means = _means(sweep, column)
            x = np.arange(len(means.index), dtype=float)
            for series in means.columns:
                ax.plot(x, means[series], color=colors[sweep.method_of[series]], marker="o", ms=4, lw=1.8,
                        label=plot_label(series))
            ax.set_xticks(x, [plot_label(v) for v in means.index])
            ax.set_title(plot_label(kind))
            ax.set_xlabel("level")
            ax.set_ylabel(plot_label(metric_header(metric)))
        return panels_svg(fig, axes, len(kinds), nrows)


def robustness_html(robustness: Robustness) -> str:
    """The report's robustness section: a figure per headline metric, then per kind its order notes,
    mean table (medians folded)."""
    first = next(iter(robustness.kinds.values()))
    parts = [plot_html(robustness_plot, robustness, m.column, alt=f"{m.column} against corruption level")
             for m in first.metrics]
    overview = "".join(table_html(overview_table(robustness, m.column)) for m in first.metrics)
    parts.append(f"<details><summary>Every input and method, one table per metric</summary>{overview}</details>")
    for kind, sweep in robustness.kinds.items():
        mean = sweep.tables[f"robustness-{kind}"]
        median = sweep.tables[f"robustness-{kind}-median"]
        notes = "".join(f"<li>{esc(line)}</li>" for line in robustness.notes[kind])
        parts.append(f"<h3>{esc(kind)}</h3><ul class=\"note\">{notes}</ul>{table_html(mean)}{notes_html(mean)}"
                     f"<details><summary>{esc(median.title)}</summary>{table_html(median)}</details>")
    return "".join(parts)
