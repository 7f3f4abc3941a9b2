"""report.html: one self-contained page (inline CSS, images as base64 data URIs, inline scripts, no
file or network reference), within a size budget (:func:`reports.viewer.size_budget`).

Sections: a sweep run's sweep first (:mod:`reports.sweep`), summary (the best mean per metric with
the methods tied with it, the mean table with its intervals, counts and what each mean is over), a
gallery (per shape: GT and every method rendered headless with :mod:`reports.render`, plus each
method coloured by its distance to the GT surface, with the colour scale; for Markdown and print),
the 3D viewer (:mod:`reports.viewer`: the same meshes in linked WebGL views, the page's only script), per-shape plots
(:mod:`reports.plots`) and tables, validity, timing, failed jobs with their error text, and the
protocol with the run context. Every text from the run is escaped with :func:`html.escape`; the
stylesheet is ``report.css`` beside this module.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from html import escape
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from foundation.errors import one_line
from foundation.metrics import mesh_validity
from foundation.serialize import dumps
import reports.plots as plots
import reports.render as render
from reports.frames import numeric, ok_jobs
from reports.protocol import device_text, execution_text, protocol_items, report_title
from reports.style import method_colors
from reports.statistics import tests_against_best
from reports.summary import Summary
from reports.table import Table, fmt, metric_header
from reports.timing import timing_caption, timing_table
from reports.viewer import size_budget, viewer_html

CSS = Path(__file__).with_name("report.css").read_text(encoding="utf-8")
#: Clip of the error colouring, canonical frame units (= the default protocol's F1@0.01 threshold).
ERROR_VMAX = 0.01
GALLERY_LIMIT = 24
#: Meshes with more faces are drawn from a seeded random subset of this many faces (thumbnails only).
MAX_RENDER_FACES = 300_000
CHIPS = ("dataset", "task", "mode", "budget", "grid", "seed", "seeds", "metric preset")


def esc(text) -> str:
    return escape(str(text), quote=True)


def data_uri(payload: bytes, mime: str) -> str:
    return f"data:{mime};base64," + base64.b64encode(payload).decode("ascii")


def table_html(table: Table, css_class: str = "") -> str:
    """A :class:`reports.table.Table` as an HTML table: bold method cells highlighted as best,
    bold cells of other rows (totals) strong, 'failed' cells red, hover text as ``title``, a cell's
    detail (an interval) muted after its text."""
    head = "".join(f'<th class="{a}">{esc(h)}</th>' for h, a in zip(table.headers, table.align))
    rows = []
    for cells, kind in zip(table.rows, table.row_kinds):
        tds = []
        for cell, align in zip(cells, table.align):
            cls = [align] + (["best" if kind == "method" else "strong"] if cell.bold else [])
            cls += ["fail"] if cell.text == "failed" else []
            title = f' title="{esc(cell.title)}"' if cell.title else ""
            text = esc(cell.text)
            if kind == "step" and align == "l":
                text = "&nbsp;&nbsp;↳ " + esc(cell.text.strip().split(": ", 1)[-1])
            text += f' <span class="muted">{esc(cell.detail)}</span>' if cell.detail else ""
            tds.append(f'<td class="{" ".join(cls)}"{title}>{text}</td>')
        rows.append(f'<tr class="{esc(kind)}">{"".join(tds)}</tr>')
    return (f'<div class="tablewrap"><table class="{css_class}"><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(rows)}</tbody></table></div>')


def notes_html(table: Table) -> str:
    return "".join(f'<p class="note">{esc(n)}</p>' for n in table.notes)


def plot_html(make, *args, alt: str) -> str:
    """An inline SVG image of ``make(*args)`` ('' when it has nothing to plot); a failing plot is a
    one-line note, never a broken report."""
    try:
        svg = make(*args)
    except Exception as exc:  # noqa: BLE001
        return f'<p class="note">Plot unavailable: {esc(one_line(exc))}</p>'
    return f'<img class="plot" src="{data_uri(svg, "image/svg+xml")}" alt="{esc(alt)}">' if svg else ""


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


def topology_text(boundary_edges: float, nonmanifold_edges: float) -> str:
    """'∂ 1,204 · NM 0': boundary and non-manifold edge counts (an open surface keeps its boundary,
    a branching surface its non-manifold edges; a closing method shows 0 and 0)."""
    if not (np.isfinite(boundary_edges) and np.isfinite(nonmanifold_edges)):
        return ""
    return f"∂ {boundary_edges:,.0f} · NM {nonmanifold_edges:,.0f}"


def _metrics_text(summary: Summary, shape: str, method: str) -> str:
    """'CD 4.50 · ECD 2.00 · EF1 0.60 · ∂ 0 · NM 0': the shape's mean over seeds, table units, and
    the prediction's boundary / non-manifold edge counts."""
    ok = ok_jobs(summary.results)
    sel = ok[(ok["shape"] == shape) & (ok["method"] == method)]
    scored = sel[sel.index.isin(summary.scored.index)]
    parts = [f"{m.name} {fmt(numeric(scored, m.column).mean() * m.scale, 2)}"
             for m in summary.metrics if m.column in plots.PLOTTED] if len(scored) or not len(sel) else ["not scored (no GT)"]
    if len(sel) and {"boundary_edges", "nonmanifold_edges"} <= set(sel.columns):
        parts.append(topology_text(numeric(sel, "boundary_edges").mean(), numeric(sel, "nonmanifold_edges").mean()))
    return " · ".join(p for p in parts if p)


def _view_caption(summary: Summary, shape: str, method: str) -> str:
    """A viewer cell's caption: the metrics of :func:`_metrics_text`, or what failed."""
    jobs = summary.results[(summary.results["shape"] == shape) & (summary.results["method"] == method)]
    if len(jobs) and not len(ok_jobs(jobs)):
        err = jobs["error"].dropna()
        return f"{len(jobs)} job(s) failed: " + (one_line(err.iloc[0]) if len(err) else "no error text")
    return _metrics_text(summary, shape, method)


def _gt_caption(vertices: np.ndarray, faces: np.ndarray) -> str:
    """'12,000 faces · ∂ 0 · NM 0' of the GT mesh."""
    validity = mesh_validity(vertices, faces)
    return f"{len(faces):,} faces · " + topology_text(validity["boundary_edges"], validity["nonmanifold_edges"])


@dataclass(frozen=True)
class _FigureFacts:
    """What the run's table says of one prediction, for its thumbnail: why every job failed (None
    when one is ok), the notes under it and its metrics text."""

    failed: str | None
    notes: tuple[str, ...]
    text: str


def _figure_facts(summary: Summary, shape: str, method: str) -> _FigureFacts:
    jobs = summary.results[(summary.results["shape"] == shape) & (summary.results["method"] == method)]
    good = ok_jobs(jobs)
    if len(jobs) and not len(good):
        err = jobs["error"].dropna()
        return _FigureFacts(one_line(err.iloc[0]) if len(err) else "no error text", (f"{len(jobs)} job(s) failed",), "")
    notes = (f"{len(jobs) - len(good)} of {len(jobs)} seeds failed",) if len(jobs) > len(good) else ()
    return _FigureFacts(None, notes, _metrics_text(summary, shape, method))


def _prediction_figure(facts: _FigureFacts, shape: str, method: str, path: Path, gt, bounds, size: int,
                       vmax: float, up: str = "") -> tuple[str, str, str]:
    """(shaded thumbnail, error-coloured thumbnail, caption) of one prediction, or placeholders."""
    if facts.failed is not None:
        return _placeholder("failed", "failed", facts.failed), "", " · ".join(facts.notes)
    notes, text = list(facts.notes), facts.text
    if not path.is_file():
        return _placeholder("missing", "no mesh", f"{path.name} not found"), "", text
    try:
        V, F = read_mesh(path)
        if not len(F):
            return _placeholder("missing", "empty mesh", "the prediction has no faces"), "", text
        if len(F) > MAX_RENDER_FACES:  # a thumbnail cannot show more; keeps huge outputs cheap
            V, F = render.face_subset(V, F, MAX_RENDER_FACES)
            notes.append(f"thumbnail of a random {MAX_RENDER_FACES:,}-face subset")
        if gt is not None and len(gt[1]):
            shaded_png, err_png = render.render_mesh_and_error(V, F, *gt, vmax, size=(size, size), bounds=bounds,
                                                               up=up)
            shaded, err = _img(shaded_png, f"{shape} {method}"), _img(err_png, f"{shape} {method} error")
        else:
            shaded = _img(render.render_mesh(V, F, size=(size, size), bounds=bounds, up=up), f"{shape} {method}")
            err = _placeholder("missing", "no GT", "distance colouring needs gt.ply")
    except Exception as exc:  # noqa: BLE001 -- one bad mesh never breaks the report
        return _placeholder("failed", "render failed", one_line(exc)), "", ""
    return shaded, err, " · ".join([text] + notes)


@dataclass(frozen=True)
class _GalleryCard:
    """The gallery card of a shape (``card(shape)``): its GT and every method's prediction from
    ``meshes_dir/<shape>/``, with the facts the run's table gives of each. A plain picklable
    callable, so the cards of several shapes can be drawn in parallel processes."""

    meshes_dir: Path
    methods: tuple[str, ...]
    facts: dict  # {(shape, method): _FigureFacts}
    colors: dict
    size: int
    vmax: float
    up: str

    def __call__(self, shape: str) -> str:
        size, vmax, up = self.size, self.vmax, self.up
        folder = Path(self.meshes_dir) / shape
        gt_path = folder / "gt.ply"
        gt = bounds = None
        if not gt_path.is_file():
            figures = [("GT", _placeholder("missing", "no GT mesh", f"{gt_path.name} not found"), "", "")]
        else:
            try:
                gt = read_mesh(gt_path)
                if len(gt[1]):
                    used = gt[0][gt[1].ravel()]
                    bounds = (used.min(0), used.max(0))
                figures = [("GT", _img(render.render_mesh(*gt, size=(size, size), bounds=bounds, up=up,
                                                          base_color=render.GT_COLOR), f"{shape} GT"),
                            mini_legend(vmax), _gt_caption(*gt))]
            except Exception as exc:  # noqa: BLE001
                gt = None
                figures = [("GT", _placeholder("missing", "unreadable GT", one_line(exc)), "", "")]
        figures += [(m, *_prediction_figure(self.facts[shape, m], shape, m, folder / f"{m}.ply", gt, bounds, size,
                                                vmax, up))
                    for m in self.methods]
        html_figures = []
        for name, top, bottom, caption in figures:
            dot = "" if name == "GT" else f'<i class="dot" style="background:{self.colors[name]}"></i>'
            html_figures.append(f'<figure><figcaption class="name">{dot}{esc(name)}</figcaption>{top}{bottom}'
                                f'<figcaption class="m">{esc(caption)}</figcaption></figure>')
        return (f'<div class="shape card" id="shape-{esc(shape)}"><h3>{esc(shape)}</h3>'
                f'<div class="row">{"".join(html_figures)}</div></div>')


def gallery_html(summary: Summary, meshes_dir: Path | None, colors: dict, limit: int, size: int,
                 vmax: float, up: str = "", map_shapes: Callable = map) -> str:
    """One card per shape (the first ``limit``): ``meshes_dir/<shape>/gt.ply`` and ``<method>.ply``,
    rendered with the dataset's ``up`` axis ('x', 'y', 'z'; '': y) up in the image. ``map_shapes(fn,
    shapes)``: how the cards are drawn, in order (builtin ``map``, or a process pool's ``map``)."""
    if meshes_dir is None or not Path(meshes_dir).is_dir():
        return '<p class="muted">No meshes directory: thumbnails are not available for this report.</p>'
    if limit == 0:
        return (f'<p class="muted">No thumbnails in this report (gallery limit 0); the meshes of its '
                f'{len(summary.shapes)} shapes are in {esc(str(meshes_dir))}.</p>')
    shapes = summary.shapes[:limit]
    facts = {(s, m): _figure_facts(summary, s, m) for s in shapes for m in summary.own_methods}
    card = _GalleryCard(Path(meshes_dir), tuple(summary.own_methods), facts, dict(colors), size, vmax, up)
    cards = list(map_shapes(card, shapes))
    more = ""
    if len(summary.shapes) > len(shapes):
        more = f'<p class="muted">Showing the first {len(shapes)} of {len(summary.shapes)} shapes.</p>'
    return "".join(cards) + more


def mini_legend(vmax: float) -> str:
    """The error scale in a thumbnail-sized box (under the GT, beside the error renders)."""
    return (f'<div class="ph legend"><span class="lt">distance to GT ↓</span>'
            f'<div class="vbar" style="background:{render.error_gradient_css().replace("to right", "to top")}"></div>'
            f'<div class="vt"><span>≥ {vmax:g}</span><span>{vmax / 2:g}</span><span>0</span></div></div>')


def colorbar_html(vmax: float, grid: int) -> str:
    """The error colour scale, in canonical units and in grid cells of the run's grid."""
    ticks = "".join(f"<span>{vmax * t:.4g}</span>" for t in (0, 0.25, 0.5, 0.75, 1.0))
    h = 2.0 / (int(grid) - 1)
    cells = f" ({vmax / h:.2f} grid cells at {int(grid)}³, h = {h:.4f})"
    return (f'<div class="cbar"><div class="bar" style="background:{render.error_gradient_css()}"></div>'
            f'<div class="ticks">{ticks}</div><p>Second row: distance from each predicted vertex to the GT '
            f'surface (exact, libigl), canonical frame units (a shape\'s largest side is 1.99), clipped at '
            f'{vmax:g}{esc(cells)}. Same camera for every mesh of a shape. Captions: ∂ = boundary edges, NM = '
            f'non-manifold edges (an open or branching GT keeps them only where a method can represent '
            f'them).</p></div>')


# ---------------------------------------------------------------------------------------------
# Page
# ---------------------------------------------------------------------------------------------


def _highlights(summary: Summary, colors: dict) -> str:
    """A box per metric naming the best method's mean and the methods tied with it (the mean table's bold)."""
    mean = summary.stats.values["mean"].reindex(summary.methods)
    tied = tests_against_best(summary.stats, summary.metrics, "mean").bold.reindex(summary.methods)
    out = []
    for metric in summary.metrics:
        values = mean[metric.column].dropna()
        if not len(values):
            continue
        best = values.idxmin() if metric.lower_is_better else values.idxmax()
        ties = [m for m in values.index if m != best and tied.at[m, metric.column]]
        tie = f'<div class="muted">tied with {esc(", ".join(ties))}</div>' if ties else ""
        out.append(f'<div class="hl"><div class="k">best {esc(metric_header(metric))}</div><div class="v">'
                   f'<i class="dot" style="background:{colors[best]}"></i>{esc(best)} '
                   f'<span class="muted">{fmt(values[best])}</span></div>{tie}</div>')
    return f'<div class="highlights">{"".join(out)}</div>' if out else ""


def _failed_html(summary: Summary) -> str:
    if not len(summary.failed):
        return '<p class="muted">No failed jobs.</p>'
    rows = "".join(f'<tr><td class="l">{esc(r.shape)}</td><td class="l">{esc(r.method)}</td><td class="r">{esc(r.seed)}</td>'
                   f'<td class="l err">{esc(one_line(r.error))}</td></tr>' for r in summary.failed.itertuples())
    return (f'<div class="tablewrap"><table class="errors"><thead><tr><th class="l">shape</th><th class="l">method</th>'
            f'<th class="r">seed</th><th class="l">error</th></tr></thead><tbody>{rows}</tbody></table></div>')


def _protocol_html(context: dict) -> str:
    items = protocol_items(context) + [("device", device_text(context))]
    if execution_text(context):
        items.append(("execution", execution_text(context)))
    return '<dl class="proto">' + "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>" for k, v in items) + "</dl>"


def _timing_html(timing: pd.DataFrame, context: dict, results: pd.DataFrame) -> str:
    caption = timing_caption(timing, context, results)
    return (plot_html(plots.timing_plot, timing, alt="timing per stage per method")
            + table_html(timing_table(timing, "mean_s", caption)) + f'<p class="note">{esc(caption)}</p>')


def _anytime_html(checkpoints: pd.DataFrame, summary: Summary, colors: dict) -> str:
    return (plot_html(plots.anytime_plot, checkpoints, summary.metrics, colors, alt="metric against fit seconds")
            + '<p class="note">Each checkpoint pauses the fit at a fraction of its budget and scores the network '
              'as it is then (same grid, extractor and metric samples); thick lines: mean over shapes and seeds, '
              'thin lines: one shape. Fit seconds exclude the checkpoints themselves.</p>')


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


def write_html(path: Path, summary: Summary, timing: pd.DataFrame, context: dict, meshes_dir: Path | None = None,
               *, gallery_limit: int = GALLERY_LIMIT, thumb_size: int = 256,
               checkpoints: pd.DataFrame | None = None, sweep_html: str = "", robustness_html: str = "",
               max_bytes: int | None = None, map_shapes: Callable = map) -> Path:
    """Write report.html for one run (see the module docstring); returns ``path``. ``robustness_html``
    (:func:`reports.robustness.robustness_html`) and ``sweep_html`` (:func:`reports.sweep.sweep_html`),
    when given, are the first sections. ``max_bytes``: the page's size budget
    (:func:`reports.viewer.size_budget`), which the 3D viewer's meshes are fitted into. ``map_shapes(fn,
    shapes)`` draws the gallery's cards and the viewer's meshes shape by shape, in order (builtin
    ``map``, or a process pool's ``map`` to draw several shapes at once)."""
    results = summary.results
    colors = method_colors(summary.methods)
    n_jobs, n_failed = len(results), int((results["status"] != "ok").sum())
    t = summary.tables
    summary_html = (_highlights(summary, colors) + table_html(t["mean"]) + notes_html(t["mean"])
                    + (f'<h4>{esc(t["mean-unseen"].title)}</h4>' + table_html(t["mean-unseen"])
                       + notes_html(t["mean-unseen"]) if "mean-unseen" in t else "")
                    + f'<p class="note">{esc(summary.caption)} <a href="#protocol">Details</a>.</p>'
                    + '<details><summary>Median and standard deviation</summary>'
                    + f'<h4>{esc(t["median"].title)}</h4>' + table_html(t["median"])
                    + f'<h4>{esc(t["std"].title)}</h4>' + table_html(t["std"]) + "</details>")
    per_shape = plot_html(plots.per_shape_plot, summary.scored, summary.floor, summary, colors,
                          alt="metric per shape per method")
    shape_tables = "".join(f'<h4>{esc(tb.title)}</h4>' + table_html(tb, "compact")
                           for k, tb in t.items() if k.startswith("shape-"))
    if len(summary.shapes) > plots.MAX_SHAPE_ROWS:
        shape_tables = f"<details><summary>Per-shape tables ({len(summary.shapes)} shapes)</summary>{shape_tables}</details>"
    gallery = colorbar_html(ERROR_VMAX, context["grid"]) + gallery_html(
        summary, meshes_dir, colors, gallery_limit, thumb_size, ERROR_VMAX, context.get("up_axis") or "",
        map_shapes)
    context_html = ('<details><summary>Run context</summary><pre>'
                    + esc(dumps(context, indent=2)) + "</pre></details>")
    sections = [
        *([("robustness", "Robustness to input corruptions", robustness_html)] if robustness_html else []),
        *([("sweep", "Sweep", sweep_html)] if sweep_html else []),
        ("summary", "Summary", summary_html),
        ("gallery", "Gallery", gallery),
        ("viewer", "3D viewer", ""),
        ("per-shape", "Per shape", per_shape + shape_tables),
        ("validity", "Mesh validity", table_html(t["validity"])
         + (f'<h4>{esc(t["unscored"].title)}</h4>' + table_html(t["unscored"], "compact") + notes_html(t["unscored"])
            if "unscored" in t else "")),
        *([("anytime", "Anytime curves", _anytime_html(checkpoints, summary, colors))] if checkpoints is not None else []),
        *([("decomposition", "Error decomposition", table_html(t["decomposition"]) + notes_html(t["decomposition"])
            + (table_html(t["component-errors"]) + notes_html(t["component-errors"]) if "component-errors" in t else ""))]
          if "decomposition" in t else []),
        ("timing", "Timing", _timing_html(timing, context, summary.own_results())),
        ("failed", f"Failed jobs ({n_failed})", _failed_html(summary)),
        ("protocol", "Protocol", _protocol_html(context) + context_html),
    ]
    chips = [(k, v) for k, v in protocol_items(context) if k in CHIPS] + [("jobs", f"{n_jobs} ({n_failed} failed)")]
    commit = f"commit {str(context['git_commit'])[:10]}" if context["git_commit"] else ""
    facts = (", ".join(summary.methods), device_text(context), execution_text(context), commit)
    subtitle = " · ".join(x for x in facts if x)
    title = report_title(context, "report")
    page_bytes = len(_page(title, subtitle, chips, sections).encode("utf-8"))
    viewer = viewer_html(summary.shapes, summary.own_methods, meshes_dir, lambda s, m: _view_caption(summary, s, m),
                         colors, preset=context["metric_preset"], up=context.get("up_axis") or "", vmax=ERROR_VMAX,
                         page_budget=size_budget(max_bytes), page_bytes=page_bytes, limit=gallery_limit,
                         map_shapes=map_shapes)
    sections = [(sid, name, viewer if sid == "viewer" else content) for sid, name, content in sections]
    path = Path(path)
    path.write_text(_page(title, subtitle, chips, sections), encoding="utf-8")
    return path


def write_comparison_html(path: Path, comparison) -> Path:
    """report.html for several runs (a :class:`reports.compare.Comparison`): the side-by-side
    tables, a grouped bar plot of each key metric (method x run), then per run its protocol, mean
    table, timing and failed jobs."""
    body = "".join(table_html(tb) + notes_html(tb) for tb in comparison.tables)
    body += plot_html(plots.comparison_plot, comparison.runs, alt="metrics per method per run")
    sections = [("summary", "Runs side by side", body)]
    for i, run in enumerate(comparison.runs):
        timing = comparison.timing[comparison.timing["run"] == run.label].drop(columns="run")
        content = (_protocol_html(run.context) + table_html(run.summary.tables["mean"])
                   + _timing_html(timing, run.context, run.summary.results)
                   + f"<h3>Failed jobs</h3>{_failed_html(run.summary)}")
        sections.append((f"run-{i + 1}", f"Run {run.label}", content))
    labels = " · ".join(r.label for r in comparison.runs)
    page = _page("salsbench comparison", labels, [("runs", str(len(comparison.runs)))], sections)
    path = Path(path)
    path.write_text(page, encoding="utf-8")
    return path
