"""The report's plots (matplotlib, SVG bytes): metrics per shape, timing per stage, runs side by side.

Figures are built with :class:`matplotlib.figure.Figure` (no pyplot, no global backend or style
change) under :data:`STYLE`. Text is drawn in DejaVu Sans (shipped with matplotlib); user text
(shape, method and run names) goes through :func:`plot_label`, which shows a character the font has
no glyph for (CJK, emoji) as '?' and escapes '$' (no mathtext), so plotting never warns about
missing glyphs. The tables of the report show the names in full.
"""

from __future__ import annotations

import io
import math
from functools import lru_cache

import matplotlib
import numpy as np
import pandas as pd
from matplotlib import font_manager, ft2font
from matplotlib.figure import Figure

from reports.frames import numeric, ok_jobs
from reports.style import PALETTE, method_order
from reports.table import metric_header

FONT = "DejaVu Sans"
STYLE = {
    "svg.hashsalt": "salsbench", "font.size": 9, "font.family": FONT, "axes.spines.top": False,
    "axes.spines.right": False, "axes.grid": True, "grid.color": "#e5e7eb", "grid.linewidth": 0.8,
    "axes.axisbelow": True, "axes.edgecolor": "#9ca3af", "axes.titleweight": "bold", "axes.titlesize": 10,
}
#: Stage colours, fixed per stage so every run's timing bars read alike.
STAGE_COLORS = {"load_s": "#d9d9d9", "network_s": "#6a51a3", "sample_s": "#8dd3c7", "label_s": "#80b1d3",
                "fit_s": "#3b6fb6", "reconstruct_s": "#e6850e", "query_s": "#fdb462", "extract_s": "#fb8072",
                "metrics_s": "#b3de69"}
SPARE_STAGE_COLORS = ("#bebada", "#fccde5", "#ccebc5", "#ffed6f", "#bc80bd")
#: Legend entries per row of the timing plot (a reconstruct job has up to ten stages: one row of
#: ten is wider than the figure).
LEGEND_COLUMNS = 5
#: Metrics plotted (when the preset reports them).
PLOTTED = ("cd", "ecd", "ef1")
#: Above this many shapes the per-shape plot shows box plots per method instead of a row per shape.
MAX_SHAPE_ROWS = 40


@lru_cache(maxsize=1)
def _glyphs() -> frozenset[int]:
    path = font_manager.findfont(font_manager.FontProperties(family=FONT), fallback_to_default=False)
    return frozenset(ft2font.FT2Font(path).get_charmap())


def plot_label(text) -> str:
    """``text`` as matplotlib draws it without warnings: characters the plot font lacks -> '?',
    '$' escaped (a literal dollar, not mathtext)."""
    glyphs = _glyphs()
    return "".join(c if ord(c) in glyphs or c == "\n" else "?" for c in str(text)).replace("$", r"\$")


def _svg(fig: Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="svg", bbox_inches="tight", metadata={"Date": None})
    return buffer.getvalue()


def metric_panels(count: int) -> tuple[Figure, np.ndarray, int]:
    """(figure, axes, rows) of a grid of ``count`` panels, at most 3 a row (call inside
    ``matplotlib.rc_context(STYLE)``); :func:`panels_svg` finishes it."""
    ncols = min(3, count)
    nrows = math.ceil(count / ncols)
    fig = Figure(figsize=(3.4 * ncols + 0.6, 2.6 * nrows + 0.3))
    return fig, fig.subplots(nrows, ncols, squeeze=False).ravel(), nrows


def panels_svg(fig: Figure, axes: np.ndarray, used: int, nrows: int) -> bytes:
    """SVG bytes of a :func:`metric_panels` grid: the panels past ``used`` hidden, one legend above
    (the first panel's lines), laid out tight."""
    for ax in axes[used:]:
        ax.set_visible(False)
    handles, names = axes[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, names, loc="upper center", ncol=min(len(names), 7), frameon=False,
                   bbox_to_anchor=(0.5, 1.0 + 0.3 / (2.6 * nrows)))
    fig.tight_layout()
    return _svg(fig)


def _plotted(metrics: list) -> list:
    return [m for m in metrics if m.column in PLOTTED] or metrics[:3]


def per_shape_plot(results: pd.DataFrame, floor: pd.DataFrame | None, summary, colors: dict) -> bytes | None:
    """Dot plot: one panel per key metric (CD, ECD, EF1 when present), a row per shape, a dot per
    method (mean over seeds, a line over the seeds' range), the floor as a black bar. More than
    :data:`MAX_SHAPE_ROWS` shapes: box plots per method instead. None when there is nothing to plot."""
    wanted = _plotted(summary.metrics)
    if not wanted or not summary.methods:
        return None
    ok = ok_jobs(results)
    shapes, methods = [s for s in summary.shapes if s in set(results["shape"])], summary.methods
    labels = [plot_label(m) for m in methods]
    many = len(shapes) > MAX_SHAPE_ROWS
    height = max(0.9 + (0.5 * len(methods) if many else 0.28 * len(shapes) + 0.25), 2.2)
    offsets = (np.arange(len(methods)) - (len(methods) - 1) / 2) * (0.6 / len(methods))
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(3.4 * len(wanted) + 1.2, height))
        axes = np.atleast_1d(fig.subplots(1, len(wanted), sharey=True))
        for ax, metric in zip(axes, wanted):
            if many:
                data = [numeric(ok[ok["method"] == m], metric.column).dropna().to_numpy() * metric.scale
                        for m in methods]
                try:  # matplotlib >= 3.10 names these orientation / tick_labels
                    box = ax.boxplot(data, orientation="horizontal", patch_artist=True, widths=0.6, tick_labels=labels)
                except TypeError:
                    box = ax.boxplot(data, vert=False, patch_artist=True, widths=0.6, labels=labels)
                ax.invert_yaxis()
                for patch, m in zip(box["boxes"], methods):
                    patch.set_facecolor(colors[m]), patch.set_alpha(0.75)
                if floor is not None and metric.column in floor.columns:
                    ax.axvline(numeric(floor, metric.column).mean() * metric.scale, color="k", ls="--", lw=1)
            else:
                row = {s: i for i, s in enumerate(shapes)}
                for k, (m, label) in enumerate(zip(methods, labels)):
                    sel = ok[ok["method"] == m]
                    g = (numeric(sel, metric.column) * metric.scale).groupby(sel["shape"]).agg(["mean", "min", "max"])
                    g = g[np.isfinite(g["mean"])]
                    if g.empty:
                        continue
                    ys = g.index.map(row).to_numpy(dtype=float) + offsets[k]
                    ax.hlines(ys, g["min"], g["max"], color=colors[m], lw=1.5, alpha=0.6)
                    ax.scatter(g["mean"], ys, color=colors[m], s=26, zorder=3, label=label, edgecolor="white",
                               linewidth=0.6)
                if floor is not None and metric.column in floor.columns and "shape" in floor.columns:
                    fl = (numeric(floor, metric.column) * metric.scale).groupby(floor["shape"]).mean()
                    fl = fl[np.isfinite(fl) & fl.index.isin(shapes)]
                    if len(fl):
                        ax.scatter(fl, fl.index.map(row), marker="|", color="#111827", s=140, zorder=4,
                                   label="floor", linewidth=1.6)
                ax.set_yticks(np.arange(len(shapes)), [plot_label(s) for s in shapes])
                ax.set_ylim(len(shapes) - 0.5, -0.5)
            ax.set_title(metric_header(metric))
            ax.grid(axis="y", visible=False)
        handles, names = axes[0].get_legend_handles_labels()
        if handles and not many:
            fig.legend(handles, names, loc="upper center", ncol=len(names), frameon=False,
                       bbox_to_anchor=(0.5, 1.0 + 0.35 / height))
        fig.tight_layout()
        return _svg(fig)


def timing_plot(timing: pd.DataFrame) -> bytes | None:
    """Horizontal stacked bars: mean seconds per stage per method (sub-steps not stacked), the
    sum and the job's total written at the end of each bar. None without stage timings."""
    stages = timing[timing["level"] == "stage"]
    if stages.empty:
        return None
    methods = list(dict.fromkeys(timing["method"]))
    means = stages.pivot_table(index="method", columns="stage", values="mean_s", aggfunc="first")
    means = means.reindex(index=methods, columns=list(dict.fromkeys(stages["stage"]))).fillna(0.0)
    label = dict(zip(stages["stage"], stages["label"]))
    total = timing[timing["level"] == "total"].set_index("method")["mean_s"].reindex(methods)
    spare = iter(SPARE_STAGE_COLORS * 4)
    with matplotlib.rc_context(STYLE):
        ncol = min(len(means.columns), LEGEND_COLUMNS)
        legend_rows = math.ceil(len(means.columns) / ncol)
        fig = Figure(figsize=(8.5, 0.65 + 0.25 * legend_rows + 0.45 * len(methods)))
        ax = fig.subplots()
        y = np.arange(len(methods))
        left = np.zeros(len(methods))
        for stage in means.columns:
            ax.barh(y, means[stage].to_numpy(), left=left, color=STAGE_COLORS.get(stage) or next(spare),
                    label=label[stage], height=0.6, edgecolor="white", linewidth=0.6)
            left += means[stage].to_numpy()
        for i, t in enumerate(total):
            text = f"{left[i]:.1f} s" + (f"  (total {t:.1f} s)" if np.isfinite(t) else "")
            ax.text(left[i], i, "  " + text, va="center", fontsize=8, color="#374151")
        ax.set_yticks(y, [plot_label(m) for m in methods])
        ax.set_xlim(0, max(left.max(), 1e-9) * 1.35)
        ax.invert_yaxis()
        ax.set_xlabel("seconds per job (mean)")
        ax.grid(axis="y", visible=False)
        ax.legend(ncol=ncol, frameon=False, loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=8,
                  handlelength=1.2, columnspacing=1.0)
        fig.tight_layout()
        return _svg(fig)


def comparison_plot(runs) -> bytes | None:
    """Grouped bars of each key metric's mean: a group per method, a bar per run (colours of
    :data:`reports.style.PALETTE` by run). ``runs``: :class:`reports.compare.Run` s. None when
    there is nothing to plot."""
    metrics = _plotted(runs[0].summary.metrics)
    methods = method_order(m for r in runs for m in r.summary.methods)
    if not metrics or not methods:
        return None
    width = 0.8 / len(runs)
    x = np.arange(len(methods))
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(3.6 * len(metrics) + 1, 2.8))
        axes = np.atleast_1d(fig.subplots(1, len(metrics)))
        for ax, metric in zip(axes, metrics):
            for k, run in enumerate(runs):
                mean = run.summary.stats.values["mean"]
                values = (mean[metric.column] if metric.column in mean.columns else pd.Series(dtype=float))
                ax.bar(x + (k - (len(runs) - 1) / 2) * width, values.reindex(methods).to_numpy(), width, label=plot_label(run.label),
                       color=PALETTE[k % len(PALETTE)])
            ax.set_xticks(x, [plot_label(m) for m in methods])
            ax.set_title(metric_header(metric))
            ax.grid(axis="x", visible=False)
        axes[0].legend(frameon=False, fontsize=8)
        fig.tight_layout()
        return _svg(fig)


def anytime_plot(checkpoints: pd.DataFrame, metrics: list, colors: dict) -> bytes | None:
    """Anytime curves: one panel per key metric (CD, ECD, EF1 when present) against fit seconds,
    one line per method through its checkpoints (mean over shapes and seeds of the metric and of
    the elapsed fit seconds at each checkpoint fraction); each shape's own curve is drawn thin.
    ``checkpoints``: the checkpoints frame (method, shape, seed, fraction, fit_elapsed_s, metrics).
    None when there is nothing to plot."""
    wanted = _plotted(metrics)
    if checkpoints is None or checkpoints.empty or not wanted:
        return None
    methods = method_order(checkpoints["method"])
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(3.6 * len(wanted) + 0.8, 3.2))
        axes = np.atleast_1d(fig.subplots(1, len(wanted)))
        for ax, metric in zip(axes, wanted):
            for m in methods:
                sel = checkpoints[checkpoints["method"] == m]
                x, y = numeric(sel, "fit_elapsed_s"), numeric(sel, metric.column) * metric.scale
                for _, idx in sel.groupby(["shape", "seed"]).groups.items():
                    order = sel.loc[idx, "fraction"].sort_values().index
                    ax.plot(x[order], y[order], color=colors[m], lw=0.6, alpha=0.25)
                mean = pd.DataFrame({"x": x, "y": y, "f": sel["fraction"]}).groupby("f").mean().sort_index()
                ax.plot(mean["x"], mean["y"], color=colors[m], lw=2, marker="o", ms=4, label=plot_label(m))
            ax.set_title(metric_header(metric))
            ax.set_xlabel("fit seconds")
        handles, names = axes[0].get_legend_handles_labels()
        if handles:
            fig.legend(handles, names, loc="upper center", ncol=len(names), frameon=False, bbox_to_anchor=(0.5, 1.08))
        fig.tight_layout()
        return _svg(fig)
