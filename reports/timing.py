"""Timing tables: wall-clock seconds per job and stage, per method (timing.csv, timing.md).

A timing column is any result column ending in ``_s``. Pipeline stages (:data:`STAGE_LABELS`, of
both tasks) are summed into 'sum of stages'; a column ``<stage>_<step>_s`` of a stage present (e.g.
``extract_qef_s``, ``reconstruct_field_knn_s``) is a sub-step, listed under its stage and not added
again; other ``_s`` columns are stages of their own, placed before scoring; ``total_s`` is the job's
wall time. Statistics are over a method's successful jobs (all its jobs when none succeeded).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from reports.frames import check_results
from reports.protocol import device_text, execution_text
from reports.style import method_order
from reports.table import DASH, Cell, Table, fmt, md_escape, table_markdown_section, tex_escape

STAGE_LABELS = {
    "load_s": "loading",
    "network_s": "network (train or load)",
    "sample_s": "sampling",
    "label_s": "labelling",
    "fit_s": "fitting",
    "reconstruct_s": "reconstruction",
    "query_s": "field queries",
    "extract_s": "extraction",
    "metrics_s": "metrics",
    "total_s": "total",
}
TIMING_COLUMNS = ["method", "stage", "label", "level", "n_jobs", "mean_s", "median_s", "std_s", "device", "execution"]
SUM_STAGE = "sum_of_stages"


def timing_stages(columns) -> list[tuple[str, str, str]]:
    """(column, label, level) of the timing columns present, in pipeline order, with
    'sum_of_stages' (level 'sum') just before the total. level: 'stage' (summed), 'step' (a
    sub-step of a stage present, not summed), 'total'."""
    cols = [str(c) for c in columns if str(c).endswith("_s")]
    stages = [c for c in STAGE_LABELS if c in cols and c != "total_s"]
    parents = [c[:-2] for c in stages]
    steps: dict[str, list[str]] = {}
    others = []
    for c in cols:
        if c in STAGE_LABELS or c == SUM_STAGE:
            continue
        parent = next((p for p in parents if c.startswith(p + "_")), None)
        if parent:
            steps.setdefault(parent + "_s", []).append(c)
        else:
            others.append(c)
    extra = [(o, o[:-2].replace("_", " "), "stage") for o in others]
    out = []
    for c in stages:
        if c == "metrics_s":  # stages of their own go before scoring
            out += extra
        out.append((c, STAGE_LABELS[c], "stage"))
        out += [(s, f"{STAGE_LABELS[c]}: {s[len(c) - 1:-2].replace('_', ' ')}", "step") for s in steps.get(c, [])]
    if "metrics_s" not in stages:
        out += extra
    out.append((SUM_STAGE, "sum of stages", "sum"))
    if "total_s" in cols:
        out.append(("total_s", "total", "total"))
    return out


def timing_frame(results: pd.DataFrame, context: dict) -> pd.DataFrame:
    """Tidy timing statistics, one row per (method, stage) with values: the columns of
    :data:`TIMING_COLUMNS`. The 'sum_of_stages' row of a method is the sum of its stage means
    (sub-steps and total excluded); its median and std are NaN."""
    results = check_results(results)
    methods = method_order(results["method"], context["methods"])
    stages = timing_stages(results.columns)
    level = {c: lv for c, _, lv in stages}
    label = {c: lb for c, lb, _ in stages}
    measured = [c for c, _, lv in stages if lv != "sum"]
    ok = results["status"] == "ok"
    use = results[ok | ~ok.groupby(results["method"]).transform("any")]
    long = use.melt(id_vars="method", value_vars=measured, var_name="stage", value_name="s")
    long["s"] = pd.to_numeric(long["s"], errors="coerce")
    stats = (long.dropna(subset=["s"]).groupby(["method", "stage"])["s"]
             .agg(n_jobs="count", mean_s="mean", median_s="median", std_s="std").reset_index())
    stats["level"] = stats["stage"].map(level)
    sums = stats[stats["level"] == "stage"].groupby("method")["mean_s"].sum().reindex(methods, fill_value=0.0)
    sum_rows = pd.DataFrame({"method": methods, "stage": SUM_STAGE, "level": "sum",
                             "n_jobs": use.groupby("method").size().reindex(methods, fill_value=0).to_numpy(),
                             "mean_s": sums.to_numpy(), "median_s": np.nan, "std_s": np.nan})
    frame = pd.concat([stats, sum_rows], ignore_index=True) if len(stats) else sum_rows
    frame["label"] = frame["stage"].map(label)
    frame["device"] = device_text(context)
    frame["execution"] = execution_text(context)
    rank = {c: i for i, (c, _, _) in enumerate(stages)}
    frame = frame.assign(_m=frame["method"].map({m: i for i, m in enumerate(methods)}),
                         _s=frame["stage"].map(rank)).sort_values(["_m", "_s"], kind="stable")
    return frame[TIMING_COLUMNS].reset_index(drop=True)


def timing_table(timing: pd.DataFrame, stat: str, caption: str) -> Table:
    """Stages x methods table of one statistic of :func:`timing_frame` ('mean_s' or 'median_s'),
    seconds; the 'sum of stages' row only for the mean."""
    methods = list(dict.fromkeys(timing["method"]))
    headers = ["stage"] + methods
    title = {"mean_s": "Wall-clock seconds per job (mean)", "median_s": "Wall-clock seconds per job (median)"}[stat]
    table = Table(f"timing-{stat[:-2]}", title, caption, headers, [tex_escape(h) for h in headers],
                  ["l"] + ["r"] * len(methods))
    values = timing.pivot_table(index="stage", columns="method", values=stat, aggfunc="first", dropna=False)
    for stage, label, level in timing_stages(timing["stage"].unique()):
        if stage not in values.index or (level == "sum" and stat != "mean_s"):
            continue
        cells = [Cell(("  " if level == "step" else "") + label, bold=level in ("total", "sum"))]
        cells += [Cell(fmt(values.at[stage, m], 2) if m in values.columns else DASH) for m in methods]
        table.add(cells, level)
    return table


def timing_caption(timing: pd.DataFrame, context: dict, results: pd.DataFrame) -> str:
    """What the timing tables show: jobs per method, the device, cached jobs, how to read them."""
    n = timing.groupby("method", sort=False)["n_jobs"].max()
    jobs = ", ".join(f"{m}: {int(k)}" for m, k in n.items())
    cached = ""
    if "cache" in results.columns:
        n_cached = int((results["cache"].fillna("").astype(str).str.strip() != "").sum())
        if n_cached:
            cached = (f" {n_cached} job(s) reused cached results: their stage times are those of the job that "
                      f"computed them, their total is the time actually spent, so the total can be below the sum.")
    execution = execution_text(context)
    return (f"Wall-clock seconds per job (shape × seed), over successful jobs ({jobs}). Device: "
            f"{device_text(context)}{'; ' + execution if execution else ''}. Extraction sub-steps (indented) are part of extraction and "
            f"not added again; 'sum of stages' adds the stage means; 'total' is the job's wall time "
            f"(includes loading and bookkeeping).{cached} Machines shared with other work give noisy "
            f"absolute times: compare methods within one run.")


def timing_markdown(timing: pd.DataFrame, caption: str, title: str) -> str:
    """timing.md: '# title', the caption, the mean and the median table."""
    parts = [f"# {md_escape(title)}", "", md_escape(caption), ""]
    for stat in ("mean_s", "median_s"):
        parts += table_markdown_section(timing_table(timing, stat, caption))
    return "\n".join(parts)


def write_timing(results: pd.DataFrame, context: dict, out_dir: Path) -> tuple[dict[str, Path], pd.DataFrame]:
    """timing.csv (:func:`timing_frame`) and timing.md in ``out_dir``; returns ({name: path}, frame)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    timing = timing_frame(results, context)
    paths = {"timing.csv": out_dir / "timing.csv", "timing.md": out_dir / "timing.md"}
    timing.to_csv(paths["timing.csv"], index=False, float_format="%.6g")
    text = timing_markdown(timing, timing_caption(timing, context, results), "salsbench timing")
    paths["timing.md"].write_text(text, encoding="utf-8")
    return paths, timing
