"""Several runs side by side: summary.md / summary.tex / timing.csv / timing.md of a comparison.

Each run is summarised as on its own (:func:`reports.summary.build_summary`); runs sharing a
metric protocol (the same headline metrics and multipliers) form one table whose rows are (run,
method) and each run's floor, built by the one statistics table builder
(:func:`reports.statistics.statistic_table`) on the runs' statistics stacked; bold is the best over
all runs of the table and every row not significantly worse than it (paired over the shapes both
have, so runs on other shapes tie), and statistics.csv holds every row's interval and p against
that best (:func:`reports.statistics.statistics_frame`, columns run, method first).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from reports.statistics import AGGREGATION, Statistics, statistic_table, statistics_frame
from reports.summary import Summary, build_summary, write_statistics
from reports.table import Table, md_escape, table_latex, table_markdown, table_markdown_section
from reports.timing import TIMING_COLUMNS, timing_caption, timing_frame, timing_table

RUN_KEYS = ("name", "results", "floor", "context")


@dataclass
class Run:
    """One run of a comparison: its label (unique), frames, context and summary."""

    label: str
    results: pd.DataFrame
    floor: pd.DataFrame | None
    context: dict
    summary: Summary


@dataclass
class Comparison:
    """The runs, the side-by-side tables (one per metric protocol), their statistics.csv frame and
    every run's timing (column ``run`` first)."""

    runs: list[Run]
    tables: list[Table]
    statistics: pd.DataFrame
    timing: pd.DataFrame


def as_runs(runs) -> list[Run]:
    """Runs from dicts with keys name, results, floor, context (and meshes_dir, not used: a
    comparison has no gallery); repeated names get ' (2)', ' (3)', ... appended."""
    out, seen = [], {}
    for i, item in enumerate(runs):
        missing = [k for k in RUN_KEYS if k not in item]
        if missing:
            raise ValueError(f"run {i + 1} lacks key(s) {', '.join(missing)}")
        name = str(item["name"])
        seen[name] = seen.get(name, 0) + 1
        label = name if seen[name] == 1 else f"{name} ({seen[name]})"
        out.append(Run(label, item["results"], item["floor"], item["context"],
                       build_summary(item["results"], item["floor"], item["context"])))
    if not out:
        raise ValueError("compare_runs needs at least one run")
    return out


def stacked(runs: list[Run]) -> Statistics:
    """The runs' statistics in one frame per statistic, rows (run label, method or floor)."""
    first = runs[0].summary.stats
    values = {stat: pd.concat({r.label: r.summary.stats.values[stat] for r in runs}) for stat in first.values}
    per_shape = {c: pd.concat({r.label: r.summary.stats.per_shape[c] for r in runs}) for c in first.per_shape}
    return Statistics(values, pd.concat({r.label: r.summary.stats.counts for r in runs}), per_shape)


def protocol_groups(runs: list[Run]) -> dict[tuple, list[Run]]:
    """The runs grouped by metric protocol (their headline metrics), in order of appearance."""
    groups: dict[tuple, list[Run]] = {}
    for run in runs:
        groups.setdefault(tuple(run.summary.metrics), []).append(run)
    return groups


def comparison_tables(runs: list[Run]) -> list[Table]:
    """One mean table per group of runs sharing a metric protocol (see the module docstring)."""
    groups = protocol_groups(runs)
    tables = []
    for g, (metrics, members) in enumerate(groups.items()):
        captions = list(dict.fromkeys(r.summary.caption for r in members))
        caption = (f"All runs: {captions[0]}" if len(captions) == 1
                   else " ".join(f"[{r.label}] {r.summary.caption}" for r in members))
        table = statistic_table(stacked(members), list(metrics), "mean",
                                key="compare" if len(groups) == 1 else f"compare-{g + 1}",
                                caption=f"{caption} {AGGREGATION}", lead=("run", "method"),
                                title="Runs side by side: mean over shapes and seeds")
        table.notes += [AGGREGATION, "Rows: each run's methods and its floor; bold and the tests: over all runs of "
                                     "the table."]
        tables.append(table)
    return tables


def comparison_statistics(runs: list[Run]) -> pd.DataFrame:
    """statistics.csv of a comparison: each group's :func:`reports.statistics.statistics_frame`."""
    return pd.concat([statistics_frame(stacked(members), list(metrics), lead=("run", "method"))
                      for metrics, members in protocol_groups(runs).items()], ignore_index=True)


def comparison_timing(runs: list[Run]) -> pd.DataFrame:
    """Every run's :func:`reports.timing.timing_frame`, with the run label as first column."""
    frame = pd.concat([timing_frame(r.results, r.context).assign(run=r.label) for r in runs], ignore_index=True)
    return frame[["run", *TIMING_COLUMNS]]


def build_comparison(runs) -> Comparison:
    """Summaries, side-by-side tables and timing of the runs (dicts, see :func:`as_runs`)."""
    runs = as_runs(runs)
    return Comparison(runs, comparison_tables(runs), comparison_statistics(runs), comparison_timing(runs))


def write_comparison(comparison: Comparison, out_dir: Path) -> dict[str, Path]:
    """summary.md, summary.tex, statistics.csv, timing.csv and timing.md of a comparison in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    labels = ", ".join(r.label for r in comparison.runs)
    md = [f"# salsbench comparison: {md_escape(labels)}", ""]
    for t in comparison.tables:
        md += table_markdown_section(t, with_caption=True)
    names = ("summary.md", "summary.tex", "statistics.csv", "timing.csv", "timing.md")
    paths = {name: out_dir / name for name in names}
    paths["summary.md"].write_text("\n".join(md), encoding="utf-8")
    head = f"% salsbench comparison: {' '.join(labels.split())}. Needs \\usepackage{{booktabs}}.\n\n"
    paths["summary.tex"].write_text(head + "\n".join(table_latex(t) for t in comparison.tables), encoding="utf-8")
    write_statistics(comparison.statistics, paths["statistics.csv"])
    timing = comparison.timing
    timing.to_csv(paths["timing.csv"], index=False, float_format="%.6g")
    tmd = [f"# salsbench timing: {md_escape(labels)}", ""]
    for run in comparison.runs:
        sel = timing[timing["run"] == run.label].drop(columns="run")
        caption = timing_caption(sel, run.context, run.results)
        table = timing_table(sel, "mean_s", caption)
        tmd += [f"## {md_escape(run.label)}: {table.title}", "", md_escape(caption), "", table_markdown(table)]
    paths["timing.md"].write_text("\n".join(tmd), encoding="utf-8")
    return paths
