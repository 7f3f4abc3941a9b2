"""report.html: one self-contained page (inline CSS, images as base64 data URIs, no script, no network).

Sections: protocol, accuracy summary (best per column highlighted), per-shape plots (matplotlib SVG),
a gallery (per shape: GT and every method rendered headless with :mod:`reports.render`, plus each
method coloured by its distance to the GT surface, with the colour scale), validity, timing (table and
stacked bars), failed jobs with their error text, and the full configuration.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

import numpy as np
import pandas as pd

from reports import render
from reports.tables import (
    Summary,
    Table,
    check_floor,
    check_results,
    device_text,
    fmt,
    numeric,
    ok_jobs,
    one_line,
    protocol_items,
    timing_caption,
    timing_table,
)

#: Method colours: fixed for the registry's methods, then a qualitative palette.
METHOD_COLORS = {"sals": "#e4572e", "sdf": "#3a7fc1", "bof": "#29a37a", "udf": "#f2a541"}
PALETTE = ["#8367c7", "#6c757d", "#d1495b", "#00798c", "#edae49", "#66a182", "#2e4057", "#b07aa1"]
#: Stage colours, fixed per stage so every run's timing bars read alike.
STAGE_COLORS = {"load_s": "#d9d9d9", "sample_s": "#8dd3c7", "label_s": "#80b1d3", "fit_s": "#3b6fb6",
                "query_s": "#fdb462", "extract_s": "#fb8072", "metrics_s": "#b3de69"}
SPARE_STAGE_COLORS = ["#bebada", "#fccde5", "#ccebc5", "#ffed6f", "#bc80bd"]
DEFAULT_ERROR_VMAX = 0.01  # canonical units; = the default protocol's F1@0.01 threshold
GALLERY_LIMIT = 24


#: Meshes with more faces are drawn from a seeded random subset of this many faces (thumbnails only).
MAX_RENDER_FACES = 300_000


def method_colors(methods: list[str]) -> dict[str, str]:
    spare = iter(PALETTE * 4)
    return {m: METHOD_COLORS.get(m.lower()) or next(spare) for m in methods}


def esc(text) -> str:
    return html.escape(str(text), quote=True)


def data_uri(payload: bytes, mime: str) -> str:
    return f"data:{mime};base64," + base64.b64encode(payload).decode("ascii")


# ---------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------


def table_html(table: Table, css_class: str = "") -> str:
    head = "".join(f'<th class="{"l" if a == "l" else "r"}">{esc(h)}</th>' for h, a in zip(table.headers, table.align))
    rows = []
    for cells, kind in zip(table.rows, table.row_kinds):
        tds = []
        for cell, align in zip(cells, table.align):
            cls = ["l" if align == "l" else "r"]
            if cell.bold and kind in ("method", "run"):
                cls.append("best")
            if cell.bold and kind not in ("method", "run"):
                cls.append("strong")
            if cell.text == "failed":
                cls.append("fail")
            title = f' title="{esc(cell.title)}"' if cell.title else ""
            text = esc(cell.text)
            if kind == "step" and align == "l":
                text = "&nbsp;&nbsp;↳ " + esc(cell.text.strip().split(": ", 1)[-1])
            tds.append(f'<td class="{" ".join(cls)}"{title}>{text}</td>')
        rows.append(f'<tr class="{esc(kind)}">{"".join(tds)}</tr>')
    return (f'<div class="tablewrap"><table class="{css_class}"><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(rows)}</tbody></table></div>')


# ---------------------------------------------------------------------------------------------
# Plots (matplotlib, embedded as SVG data URIs so figures never share element ids)
# ---------------------------------------------------------------------------------------------


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({
        "svg.hashsalt": "salsbench", "font.size": 9, "axes.spines.top": False, "axes.spines.right": False,
        "axes.grid": True, "grid.color": "#e5e7eb", "grid.linewidth": 0.8, "axes.axisbelow": True,
        "axes.edgecolor": "#9ca3af", "axes.titleweight": "bold", "axes.titlesize": 10,
        "font.family": "DejaVu Sans",
    })
    return plt


def figure_uri(fig) -> str:
    plt = _pyplot()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="svg", bbox_inches="tight", metadata={"Date": None})
    plt.close(fig)
    return data_uri(buffer.getvalue(), "image/svg+xml")


def safe_plot(make, *args) -> tuple[str | None, str]:
    """(data URI or None, '' or a one-line note): a failing plot never breaks the report."""
    try:
        return make(*args), ""
    except Exception as exc:  # noqa: BLE001
        return None, f'<p class="note">Plot unavailable: {esc(one_line(exc))}</p>'


def per_shape_plot(results: pd.DataFrame, floor: pd.DataFrame | None, summary: Summary, colors: dict) -> str | None:
    """Dot plot: one panel per key metric (CD, ECD, EF1 when present), a row per shape, a dot per
    method (mean over seeds, a line over the seeds' range), the floor as a black bar. More than 40
    shapes: box plots per method instead."""
    plt = _pyplot()
    wanted = [s for s in summary.specs if s.column in ("cd", "ecd", "ef1")] or summary.specs[:3]
    if not wanted or not summary.methods:
        return None
    ok = ok_jobs(results)
    shapes, methods = summary.shapes, summary.methods
    many = len(shapes) > 40
    height = 0.9 + (0.5 * len(methods) if many else 0.28 * len(shapes) + 0.25)
    fig, axes = plt.subplots(1, len(wanted), figsize=(3.4 * len(wanted) + 1.2, max(height, 2.2)), sharey=True)
    axes = np.atleast_1d(axes)
    y = np.arange(len(shapes))
    offsets = (np.arange(len(methods)) - (len(methods) - 1) / 2) * (0.6 / max(len(methods), 1))
    for ax, spec in zip(axes, wanted):
        if many:
            data = [numeric(ok[ok["method"] == m], spec.column).dropna().to_numpy() * spec.scale for m in methods]
            try:  # matplotlib >= 3.10 names these orientation / tick_labels
                box = ax.boxplot(data, orientation="horizontal", patch_artist=True, widths=0.6, tick_labels=methods)
            except TypeError:
                box = ax.boxplot(data, vert=False, patch_artist=True, widths=0.6, labels=methods)
            ax.invert_yaxis()
            for patch, m in zip(box["boxes"], methods):
                patch.set_facecolor(colors[m]), patch.set_alpha(0.75)
            if floor is not None and spec.column in floor.columns:
                ax.axvline(numeric(floor, spec.column).mean() * spec.scale, color="k", ls="--", lw=1)
        else:
            for k, m in enumerate(methods):
                sel = ok[ok["method"] == m]
                grouped = sel.assign(v=numeric(sel, spec.column) * spec.scale).groupby("shape")["v"]
                mean, lo, hi = grouped.mean(), grouped.min(), grouped.max()
                ys = np.array([i for i, s in enumerate(shapes) if s in mean.index and np.isfinite(mean[s])], dtype=int)
                if not len(ys):
                    continue
                names = [shapes[i] for i in ys]
                ax.hlines(ys + offsets[k], lo[names], hi[names], color=colors[m], lw=1.5, alpha=0.6)
                ax.scatter(mean[names], ys + offsets[k], color=colors[m], s=26, zorder=3, label=m,
                           edgecolor="white", linewidth=0.6)
            if floor is not None and spec.column in floor.columns and "shape" in floor.columns:
                fl = floor.assign(v=numeric(floor, spec.column) * spec.scale).groupby("shape")["v"].mean()
                ys = np.array([i for i, s in enumerate(shapes) if s in fl.index and np.isfinite(fl[s])], dtype=int)
                if len(ys):
                    ax.scatter(fl[[shapes[i] for i in ys]], ys, marker="|", color="#111827", s=140, zorder=4,
                               label="floor", linewidth=1.6)
            ax.set_yticks(y, shapes)
            ax.set_ylim(len(shapes) - 0.5, -0.5)
        ax.set_title(spec.header)
        ax.grid(axis="y", visible=False)
    handles, labels = axes[0].get_legend_handles_labels()
    if handles and not many:
        fig.legend(handles, labels, loc="upper center", ncol=len(labels), frameon=False,
                   bbox_to_anchor=(0.5, 1.0 + 0.35 / max(height, 2.2)))
    fig.tight_layout()
    return figure_uri(fig)


def timing_plot(timing: pd.DataFrame, colors_for_stage=None) -> str | None:
    """Horizontal stacked bars: mean seconds per stage per method (sub-steps not stacked)."""
    plt = _pyplot()
    stages = timing[timing["level"] == "stage"]
    if stages.empty:
        return None
    methods = list(dict.fromkeys(timing["method"]))
    names = list(dict.fromkeys(zip(stages["stage"], stages["label"])))
    fig, ax = plt.subplots(figsize=(8.5, 0.9 + 0.45 * len(methods)))
    left = np.zeros(len(methods))
    spare = iter(SPARE_STAGE_COLORS * 4)
    for stage, label in names:
        vals = np.array([float(stages[(stages["method"] == m) & (stages["stage"] == stage)]["mean_s"].fillna(0).sum())
                         for m in methods])
        ax.barh(methods, vals, left=left, color=STAGE_COLORS.get(stage) or next(spare), label=label, height=0.6,
                edgecolor="white", linewidth=0.6)
        left += vals
    totals = timing[timing["level"] == "total"]
    for i, m in enumerate(methods):
        t = totals[totals["method"] == m]["mean_s"]
        text = f"{left[i]:.1f} s" + (f"  (total {float(t.iloc[0]):.1f} s)" if len(t) and np.isfinite(t.iloc[0]) else "")
        ax.text(left[i], i, "  " + text, va="center", fontsize=8, color="#374151")
    ax.set_xlim(0, max(left.max(), 1e-9) * 1.35)
    ax.invert_yaxis()
    ax.set_xlabel("seconds per job (mean)")
    ax.grid(axis="y", visible=False)
    ax.legend(ncol=len(names), frameon=False, loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=8,
              handlelength=1.2, columnspacing=1.0)
    fig.tight_layout()
    return figure_uri(fig)


# ---------------------------------------------------------------------------------------------
# Gallery
# ---------------------------------------------------------------------------------------------


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(V float64 (n,3), F int64 (m,3)) from a mesh file, as stored (no merging); empty arrays for
    a file without faces. Raises on unreadable files (the caller shows the message)."""
    import trimesh

    loaded = trimesh.load(str(path), force="mesh", process=False)
    V = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=float).reshape(-1, 3)
    F = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    return V, F


def _placeholder(kind: str, title: str, text: str) -> str:
    return f'<div class="ph {kind}"><b>{esc(title)}</b><span>{esc(text)}</span></div>'


def _img(png: bytes, alt: str) -> str:
    return f'<img src="{data_uri(png, "image/png")}" alt="{esc(alt)}" width="200" height="200">'


def _shape_metrics_text(results: pd.DataFrame, shape: str, method: str, summary: Summary) -> str:
    sel = ok_jobs(results[(results["shape"] == shape) & (results["method"] == method)])
    parts = []
    for spec in summary.specs:
        if spec.column in ("cd", "ecd", "ef1"):
            v = numeric(sel, spec.column).mean() * spec.scale
            parts.append(f"{spec.name} {fmt(v, 2 if spec.column != 'ef1' else 2)}")
    return " · ".join(parts)


def gallery_html(results: pd.DataFrame, floor, summary: Summary, meshes_dir: Path | None, config: dict,
                 colors: dict, limit: int, size: int, vmax: float) -> str:
    if meshes_dir is None or not Path(meshes_dir).is_dir():
        return '<p class="muted">No meshes directory: thumbnails are not available for this report.</p>'
    meshes_dir = Path(meshes_dir)
    shapes = summary.shapes[:limit]
    cards = []
    for shape in shapes:
        folder = meshes_dir / shape
        gt_path = folder / "gt.ply"
        cells = []
        gt = None
        bounds = None
        if gt_path.is_file():
            try:
                gt = read_mesh(gt_path)
                if len(gt[1]):
                    used = gt[0][gt[1].ravel()]
                    bounds = (used.min(0), used.max(0))
                cells.append(("GT", _img(render.render_mesh(*gt, size=(size, size), bounds=bounds,
                                                            base_color=render.GT_COLOR), f"{shape} GT"),
                              mini_legend(vmax), f"{len(gt[1]):,} faces"))
            except Exception as exc:  # noqa: BLE001
                cells.append(("GT", _placeholder("missing", "unreadable GT", one_line(exc)), "", ""))
        else:
            cells.append(("GT", _placeholder("missing", "no GT mesh", f"{gt_path.name} not found"), "", ""))
        for m in summary.methods:
            jobs = results[(results["shape"] == shape) & (results["method"] == m)]
            good = ok_jobs(jobs)
            note = ""
            if len(jobs) and not len(good):
                err = jobs["error"].dropna()
                cells.append((m, _placeholder("failed", "failed", one_line(err.iloc[0]) if len(err) else "no error text"),
                              "", f"{len(jobs)} job(s) failed"))
                continue
            if len(jobs) > len(good):
                note = f"{len(jobs) - len(good)} of {len(jobs)} seeds failed"
            path = folder / f"{m}.ply"
            if not path.is_file():
                cells.append((m, _placeholder("missing", "no mesh", f"{path.name} not found"), "",
                              _shape_metrics_text(results, shape, m, summary)))
                continue
            try:
                V, F = read_mesh(path)
                if not len(F):
                    cells.append((m, _placeholder("missing", "empty mesh", "the prediction has no faces"), "",
                                  _shape_metrics_text(results, shape, m, summary)))
                    continue
                if len(F) > MAX_RENDER_FACES:  # a thumbnail cannot show more; keeps huge outputs cheap
                    V, F = render.face_subset(V, F, MAX_RENDER_FACES)
                    note = (note + " · " if note else "") + f"thumbnail of a random {MAX_RENDER_FACES:,}-face subset"
                shaded = _img(render.render_mesh(V, F, size=(size, size), bounds=bounds,
                                                 base_color=render.BASE_COLOR), f"{shape} {m}")
                if gt is not None and len(gt[1]):
                    d = render.distances_to_mesh(V, *gt)
                    err = _img(render.render_mesh(V, F, colors=render.error_colors(d, vmax), size=(size, size),
                                                  bounds=bounds), f"{shape} {m} error")
                else:
                    err = _placeholder("missing", "no GT", "distance colouring needs gt.ply")
                text = _shape_metrics_text(results, shape, m, summary)
                cells.append((m, shaded, err, text + (f" · {note}" if note else "")))
            except Exception as exc:  # noqa: BLE001 -- one bad mesh never breaks the report
                cells.append((m, _placeholder("failed", "render failed", one_line(exc)), "", ""))
        figures = []
        for name, top, bottom, caption in cells:
            dot = "" if name == "GT" else f'<i class="dot" style="background:{colors.get(name, "#999")}"></i>'
            figures.append(f'<figure><figcaption class="name">{dot}{esc(name)}</figcaption>{top}{bottom}'
                           f'<figcaption class="m">{esc(caption)}</figcaption></figure>')
        cards.append(f'<div class="shape card" id="shape-{esc(shape)}"><h3>{esc(shape)}</h3>'
                     f'<div class="row">{"".join(figures)}</div></div>')
    more = ""
    if len(summary.shapes) > len(shapes):
        more = f'<p class="muted">Showing the first {len(shapes)} of {len(summary.shapes)} shapes.</p>'
    return "".join(cards) + more


def mini_legend(vmax: float) -> str:
    """The error scale in a thumbnail-sized box (under the GT, beside the error renders)."""
    return (f'<div class="ph legend"><span class="lt">distance to GT ↓</span>'
            f'<div class="vbar" style="background:{render.error_gradient_css().replace("to right", "to top")}"></div>'
            f'<div class="vt"><span>≥ {vmax:g}</span><span>{vmax / 2:g}</span><span>0</span></div></div>')


def colorbar_html(vmax: float, grid: int | None) -> str:
    ticks = "".join(f"<span>{vmax * t:.4g}</span>" for t in (0, 0.25, 0.5, 0.75, 1.0))
    cells = ""
    if grid:
        h = 2.0 / (int(grid) - 1)
        cells = f" ({vmax / h:.2f} grid cells at {int(grid)}³, h = {h:.4f})"
    return (f'<div class="cbar"><div class="bar" style="background:{render.error_gradient_css()}"></div>'
            f'<div class="ticks">{ticks}</div><p>Second row: distance from each predicted vertex to the GT '
            f'surface (exact, libigl), canonical frame units (a shape\'s largest side is 1.99), clipped at '
            f'{vmax:g}{esc(cells)}. Same camera for every mesh of a shape.</p></div>')


# ---------------------------------------------------------------------------------------------
# Page
# ---------------------------------------------------------------------------------------------

CSS = """
*{box-sizing:border-box}
body{margin:0;font:14px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;
 color:#1f2937;background:#f3f4f6}
header{background:linear-gradient(120deg,#111827 0%,#1e3a5f 60%,#23527c 100%);color:#f9fafb;padding:28px 0 22px}
.wrap{max-width:1240px;margin:0 auto;padding:0 24px}
header h1{margin:0 0 4px;font-size:26px;letter-spacing:.2px}
header .sub{color:#cbd5e1;font-size:13px}
.chips{margin-top:14px;display:flex;flex-wrap:wrap;gap:8px}
.chip{background:rgba(255,255,255,.1);border:1px solid rgba(255,255,255,.18);border-radius:999px;padding:3px 11px;
 font-size:12.5px}
.chip b{color:#93c5fd;font-weight:600;margin-right:4px}
nav{position:sticky;top:0;z-index:5;background:#fff;border-bottom:1px solid #e5e7eb}
nav .wrap{display:flex;gap:18px;overflow-x:auto;padding-top:9px;padding-bottom:9px}
nav a{color:#374151;text-decoration:none;font-size:13px;white-space:nowrap}
nav a:hover{color:#1d4ed8}
main{padding:18px 0 40px}
section.card,.card{background:#fff;border-radius:12px;box-shadow:0 1px 2px rgba(0,0,0,.06),0 4px 14px rgba(0,0,0,.04);
 padding:18px 22px;margin:18px 0}
h2{font-size:18px;margin:0 0 10px}
h3{font-size:15px;margin:0 0 10px}
.shape h3{font-family:ui-monospace,SFMono-Regular,Menlo,Consolas,monospace}
h4{font-size:13.5px;margin:18px 0 6px;color:#374151}
table.compact{width:auto;min-width:420px}
.muted,.note{color:#6b7280;font-size:12.5px}
.highlights{display:flex;flex-wrap:wrap;gap:10px;margin:4px 0 14px}
.hl{border:1px solid #e5e7eb;border-radius:10px;padding:8px 12px;min-width:130px}
.hl .k{font-size:11.5px;color:#6b7280;letter-spacing:.2px}
.hl .v{font-size:17px;font-weight:650}
.tablewrap{overflow-x:auto}
table{border-collapse:collapse;width:100%;font-variant-numeric:tabular-nums;font-size:13px}
th{font-weight:600;color:#374151;background:#f9fafb;border-bottom:2px solid #d1d5db;padding:7px 10px;white-space:nowrap}
td{padding:6px 10px;border-bottom:1px solid #eef0f3;white-space:nowrap}
th.r,td.r{text-align:right}th.l,td.l{text-align:left}
tbody tr:hover td{background:#f8fafc}
td.best{font-weight:700;color:#065f46;background:#d1fae5}
tbody tr:hover td.best{background:#a7f3d0}
td.strong{font-weight:700}
td.fail{color:#b91c1c;font-weight:600}
tr.floor td{font-style:italic;color:#4b5563;background:#f9fafb;border-top:2px solid #e5e7eb}
tr.total td,tr.sum td{border-top:2px solid #e5e7eb;background:#fafafa}
tr.step td{color:#6b7280;font-size:12px}
dl.proto{display:grid;grid-template-columns:max-content 1fr;gap:4px 18px;margin:0;font-size:13px}
dl.proto dt{color:#6b7280}dl.proto dd{margin:0}
img.plot{max-width:100%;height:auto;display:block;margin:6px auto}
.shape .row{display:flex;flex-wrap:wrap;gap:14px}
figure{margin:0;width:202px}
figure img{display:block;border:1px solid #e5e7eb;border-radius:8px;background:#fff;margin-bottom:6px}
figcaption.name{font-weight:650;font-size:13px;margin-bottom:4px}
figcaption.m{font-size:11.5px;color:#4b5563;font-variant-numeric:tabular-nums}
.dot{display:inline-block;width:9px;height:9px;border-radius:50%;margin-right:6px;vertical-align:middle}
.ph{width:200px;height:200px;border-radius:8px;display:flex;flex-direction:column;justify-content:center;
 align-items:center;text-align:center;padding:12px;margin-bottom:6px;font-size:12px;overflow:hidden;word-break:break-word}
.ph b{font-size:13px;margin-bottom:6px}
.ph.failed{background:#fef2f2;border:1px solid #fecaca;color:#991b1b}
.ph.failed span{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:11px}
.ph.missing{background:#f9fafb;border:1px dashed #d1d5db;color:#6b7280}
.ph.blank{background:transparent;border:0}
.ph.legend{flex-direction:row;gap:10px;background:#fafafa;border:1px solid #eef0f3;position:relative;padding-top:30px}
.ph.legend .lt{position:absolute;top:8px;left:0;right:0;font-size:11.5px;color:#6b7280}
.ph.legend .vbar{width:16px;height:140px;border-radius:4px;border:1px solid #d1d5db}
.ph.legend .vt{height:140px;display:flex;flex-direction:column;justify-content:space-between;font-size:11px;color:#4b5563;text-align:left}
.shape.card{box-shadow:none;border:1px solid #e5e7eb;margin:14px 0}
.cbar{max-width:520px;margin:4px 0 12px}
.cbar .bar{height:14px;border-radius:4px;border:1px solid #d1d5db}
.cbar .ticks{display:flex;justify-content:space-between;font-size:11.5px;color:#4b5563;font-variant-numeric:tabular-nums}
.cbar p{font-size:12px;color:#6b7280;margin:6px 0 0}
.errors td.err{white-space:normal;font-family:ui-monospace,Menlo,Consolas,monospace;font-size:12px;color:#991b1b}
pre{background:#0f172a;color:#e2e8f0;padding:14px;border-radius:8px;overflow:auto;font-size:12px}
details summary{cursor:pointer;color:#1d4ed8}
footer{color:#9ca3af;font-size:12px;text-align:center;padding:10px 0 30px}
"""


def _highlights(summary: Summary, colors: dict) -> str:
    out = []
    mean = summary.stats["mean"]
    for spec in summary.specs:
        vals = {m: mean.at[m, spec.column] for m in summary.methods if np.isfinite(mean.at[m, spec.column])}
        if not vals:
            continue
        best = (min if spec.lower_is_better else max)(vals, key=vals.get)
        out.append(f'<div class="hl"><div class="k">best {esc(spec.header)}</div><div class="v">'
                   f'<i class="dot" style="background:{colors[best]}"></i>{esc(best)} '
                   f'<span class="muted">{fmt(vals[best])}</span></div></div>')
    return f'<div class="highlights">{"".join(out)}</div>' if out else ""


def _failed_html(summary: Summary) -> str:
    if not len(summary.failed):
        return '<p class="muted">No failed jobs.</p>'
    rows = "".join(f'<tr><td class="l">{esc(r.shape)}</td><td class="l">{esc(r.method)}</td><td class="r">{esc(r.seed)}</td>'
                   f'<td class="l err">{esc(one_line(r.error))}</td></tr>' for r in summary.failed.itertuples())
    return (f'<div class="tablewrap"><table class="errors"><thead><tr><th class="l">shape</th><th class="l">method</th>'
            f'<th class="r">seed</th><th class="l">error</th></tr></thead><tbody>{rows}</tbody></table></div>')


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    return str(value)


def _page(title: str, subtitle: str, chips: list[tuple[str, str]], sections: list[tuple[str, str, str]]) -> str:
    chip_html = "".join(f'<span class="chip"><b>{esc(k)}</b>{esc(v)}</span>' for k, v in chips)
    nav = "".join(f'<a href="#{sid}">{esc(name)}</a>' for sid, name, _ in sections)
    body = "".join(f'<section class="card" id="{sid}"><h2>{esc(name)}</h2>{content}</section>'
                   for sid, name, content in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{esc(title)}</title><style>{CSS}</style></head><body>"
        f'<header><div class="wrap"><h1>{esc(title)}</h1><div class="sub">{esc(subtitle)}</div>'
        f'<div class="chips">{chip_html}</div></div></header>'
        f'<nav><div class="wrap">{nav}</div></nav><main><div class="wrap">{body}</div></main>'
        '<footer>Generated by salsbench · self-contained page (no network access needed)</footer>'
        "</body></html>\n"
    )


def write_html(path: Path, results: pd.DataFrame, floor: pd.DataFrame | None, config: dict, summary: Summary,
               timing: pd.DataFrame, meshes_dir: Path | None = None, *, gallery_limit: int = GALLERY_LIMIT,
               thumb_size: int = 256) -> Path:
    """Write report.html for one run (see the module docstring)."""
    config = config or {}
    results = check_results(results)
    floor = check_floor(floor)
    colors = method_colors(summary.methods)
    vmax = float(config.get("error_vmax") or DEFAULT_ERROR_VMAX)
    items = protocol_items(config, results)
    proto = "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>" for k, v in items)
    proto_html = f'<dl class="proto">{proto}<dt>device</dt><dd>{esc(device_text(config, results))}</dd></dl>'
    n_jobs, n_failed = len(results), int((results["status"] != "ok").sum())

    t = summary.tables
    summary_html = (_highlights(summary, colors) + table_html(t["mean"])
                    + "".join(f'<p class="note">{esc(n)}</p>' for n in t["mean"].notes)
                    + f'<p class="note">{esc(summary.caption)} <a href="#protocol">Details</a>.</p>'
                    + '<details><summary>Median and standard deviation</summary>'
                    + f'<h4>{esc(t["median"].title)}</h4>' + table_html(t["median"])
                    + f'<h4>{esc(t["std"].title)}</h4>' + table_html(t["std"]) + "</details>")
    plot, plot_note = safe_plot(per_shape_plot, results, floor, summary, colors)
    per_shape = (f'<img class="plot" src="{plot}" alt="metric per shape per method">' if plot else plot_note)
    shape_tables = "".join(f'<h4>{esc(tb.title)}</h4>' + table_html(tb, "compact") for k, tb in t.items() if k.startswith("shape-"))
    if len(summary.shapes) > 40:
        shape_tables = f"<details><summary>Per-shape tables ({len(summary.shapes)} shapes)</summary>{shape_tables}</details>"
    per_shape += shape_tables
    gallery = colorbar_html(vmax, config.get("grid")) + gallery_html(
        results, floor, summary, meshes_dir, config, colors, gallery_limit, thumb_size, vmax)
    cap = timing_caption(timing, config, results)
    tplot, tplot_note = safe_plot(timing_plot, timing)
    timing_html = ((f'<img class="plot" src="{tplot}" alt="timing per stage per method">' if tplot else tplot_note)
                   + table_html(timing_table(timing, "mean_s", cap)) + f'<p class="note">{esc(cap)}</p>')
    config_html = ('<details><summary>Full configuration (config.json)</summary><pre>'
                   + esc(json.dumps(config, indent=2, sort_keys=True, default=_json_default)) + "</pre></details>")
    sections = [
        ("summary", "Summary", summary_html),
        ("gallery", "Gallery", gallery),
        ("per-shape", "Per shape", per_shape),
        ("validity", "Mesh validity", table_html(t["validity"])),
        ("timing", "Timing", timing_html),
        ("failed", f"Failed jobs ({n_failed})", _failed_html(summary)),
        ("protocol", "Protocol", proto_html + config_html),
    ]
    chips = [(k, v) for k, v in items if k in ("dataset", "mode", "budget", "grid", "seeds", "metric preset")]
    chips.append(("jobs", f"{n_jobs} ({n_failed} failed)"))
    subtitle = " · ".join(str(x) for x in (
        ", ".join(summary.methods), device_text(config, results),
        config.get("created") or config.get("started") or "",
        f"commit {str(config['git_commit'])[:10]}" if config.get("git_commit") else "") if x)
    page = _page(f"salsbench report: {config.get('dataset') or 'run'}", subtitle, chips, sections)
    path = Path(path)
    path.write_text(page, encoding="utf-8")
    return path


def write_comparison_html(path: Path, runs, tables: list[Table], timing: pd.DataFrame) -> Path:
    """report.html for several runs side by side: the comparison tables, a grouped bar plot of each
    key metric (method x run) and each run's timing."""
    from reports.tables import build_summary

    plt = _pyplot()
    sections = []
    body = "".join(table_html(tb) + "".join(f'<p class="note">{esc(n)}</p>' for n in tb.notes) for tb in tables)
    summaries = [(run, build_summary(run.results, run.floor, run.config)) for run in runs]
    specs = [s for s in summaries[0][1].specs if s.column in ("cd", "ecd", "ef1")]
    methods = list(dict.fromkeys(m for _, s in summaries for m in s.methods))
    if specs and methods:
        fig, axes = plt.subplots(1, len(specs), figsize=(3.6 * len(specs) + 1, 2.8))
        axes = np.atleast_1d(axes)
        width = 0.8 / len(summaries)
        for ax, spec in zip(axes, specs):
            for k, (run, s) in enumerate(summaries):
                vals = [s.stats["mean"].at[m, spec.column] if m in s.stats["mean"].index and spec.column in s.stats["mean"].columns
                        else np.nan for m in methods]
                ax.bar(np.arange(len(methods)) + (k - (len(summaries) - 1) / 2) * width, vals, width, label=run.label,
                       color=PALETTE[k % len(PALETTE)])
            ax.set_xticks(np.arange(len(methods)), methods)
            ax.set_title(spec.header)
            ax.grid(axis="x", visible=False)
        axes[0].legend(frameon=False, fontsize=8)
        fig.tight_layout()
        body += f'<img class="plot" src="{figure_uri(fig)}" alt="metrics per method per run">'
    sections.append(("summary", "Runs side by side", body))
    for run, s in summaries:
        proto = "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>" for k, v in protocol_items(run.config, check_results(run.results)))
        sel = timing[timing["run"] == run.label].drop(columns="run")
        cap = timing_caption(sel, run.config, check_results(run.results))
        tplot, _ = safe_plot(timing_plot, sel)
        content = (f'<dl class="proto">{proto}</dl>' + table_html(s.tables["mean"])
                   + (f'<img class="plot" src="{tplot}" alt="timing">' if tplot else "")
                   + table_html(timing_table(sel, "mean_s", cap)) + f'<p class="note">{esc(cap)}</p>'
                   + f"<h3>Failed jobs</h3>{_failed_html(s)}")
        sections.append((f"run-{len(sections)}", f"Run {run.label}", content))
    page = _page("salsbench comparison", " · ".join(r.label for r in runs), [("runs", str(len(runs)))], sections)
    path = Path(path)
    path.write_text(page, encoding="utf-8")
    return path
