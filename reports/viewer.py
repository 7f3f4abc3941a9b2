"""report.html's 3D viewer: per shape, the GT and every method's mesh in linked WebGL views.

Python side (this module): reads ``meshes_dir/<shape>/gt.ply`` and ``<method>.ply``, makes each
view's GLB (:mod:`reports.glb`: the mesh drawn, its error colours and its sharp-edge points,
:mod:`reports.viewer_data`), fits them into the report's size budget by decimating the largest for
display (stated on the page; the scored files are never touched) and writes the section's markup
with its data and scripts inline: the vendored three.js bundle and Draco decoder
(:mod:`reports.viewer_assets`) and ``viewer.js``, which draws the views, links their cameras and
runs the shape picker and the toggles. No file or network is referenced: the page works from
``file://`` offline.
"""

from __future__ import annotations

import base64
import json
import os
from dataclasses import dataclass, field
from html import escape
from pathlib import Path
from typing import Callable

import numpy as np

import reports.render as render
import reports.viewer_data as vd
from foundation.metrics.presets import get_preset
from datasets.io import read_mesh_file
from foundation.errors import one_line
from reports.glb import draco_glb
from reports.viewer_assets import ViewerAssets, assets

#: The size budget of report.html in bytes when none is given (the whole page, viewer included).
DEFAULT_SIZE_BUDGET = 30_000_000
#: Environment variable that sets the budget in MB (10^6 bytes) when the caller gives none.
SIZE_BUDGET_ENV = "SALSBENCH_REPORT_MAX_MB"
#: Faces a mesh keeps whatever the budget; more than MAX_VIEW_FACES are always decimated (a browser
#: draws a dozen views of that many smoothly).
MIN_VIEW_FACES = 2_000
MAX_VIEW_FACES = 1_000_000
#: Times the views are re-drawn with the caps the bytes per face measured so far allow, before shapes
#: are left out.
_PASSES = 4
#: Below this many bytes left for the meshes, the page has no viewer (a note says why).
MIN_MESH_BYTES = 20_000


def size_budget(value: float | None = None) -> int:
    """The page's size budget in bytes: ``value`` when given, else $SALSBENCH_REPORT_MAX_MB x 10^6,
    else :data:`DEFAULT_SIZE_BUDGET`."""
    if value is not None:
        return int(value)
    text = os.environ.get(SIZE_BUDGET_ENV, "").strip()
    if not text:
        return DEFAULT_SIZE_BUDGET
    try:
        return int(float(text) * 1e6)
    except ValueError:
        raise ValueError(f"${SIZE_BUDGET_ENV}={text!r}: expected a number of MB") from None


@dataclass
class View:
    """One view of a shape: its name ('GT' or a method), caption, and either ``glb`` (base64 text)
    with the faces drawn and the faces of the file, or ``message`` saying why there is no mesh."""

    name: str
    caption: str
    glb: str = ""
    message: str = ""
    faces: int = 0
    file_faces: int = 0

    def payload(self) -> dict:
        return {"name": self.name, "caption": self.caption, "glb": self.glb or None, "message": self.message,
                "faces": self.faces, "fileFaces": self.file_faces}


@dataclass
class ShapeViews:
    """The views of one shape and the first camera (framing the GT, else the first prediction; None
    without either)."""

    shape: str
    views: list[View]
    camera: dict | None = None
    edge_note: str = ""
    caps: dict = field(default_factory=dict)


def _read(path: Path) -> tuple[np.ndarray, np.ndarray]:
    return vd.usable_mesh(*read_mesh_file(path))


def _encode(V, F, cap: int, gt, gt_edges, edges, tau: float, vmax: float) -> tuple[str, int]:
    """(base64 GLB, faces drawn) of a mesh drawn with at most ``cap`` faces: error colours against
    ``gt`` (None: the GT itself, uncoloured) and its edge points ``edges`` coloured by a match within
    ``tau`` in ``gt_edges`` (all the GT's edge points)."""
    shown_V, shown_F = vd.display_mesh(V, F, cap)
    colors = None
    if gt is not None and len(gt[1]):
        colors = render.error_colors(render.distances_to_mesh(shown_V, *gt), vmax)
    edge_rgb = vd.edge_colors(edges, None if gt is None else gt_edges, tau)
    glb = draco_glb((shown_V, shown_F, colors), (edges, edge_rgb))
    return base64.b64encode(glb).decode("ascii"), len(shown_F)


def shape_views(shape: str, folder: Path, methods: list[str], captions: dict[str, str], caps: dict,
                *, preset: str, up: str, vmax: float, edge_cache: dict) -> ShapeViews:
    """The views of ``shape`` (GT first, then ``methods``, each with ``captions[method]``) with each
    mesh drawn at most ``caps[name]`` faces (all when absent). ``edge_cache`` keeps each mesh's edge
    points between calls."""
    gt_path = folder / "gt.ply"
    gt = gt_edges = None
    views = [View("GT", "")]
    result = ShapeViews(shape, views, caps=caps)
    try:
        gt = _read(gt_path) if gt_path.is_file() else None
    except Exception as exc:  # noqa: BLE001 -- one bad file never breaks the report
        views[0].message = f"unreadable GT: {one_line(exc)}"
    if gt is None and not views[0].message:
        views[0].message = "no GT mesh"
    radius = tau = 0.0
    if gt is not None and len(gt[1]):
        lo, hi = gt[0].min(0), gt[0].max(0)
        radius, tau, result.edge_note = vd.edge_lengths(preset, float(np.linalg.norm(hi - lo)))
        result.camera = vd.initial_camera(lo, hi, up, render.DEFAULT_VIEW)
        dot = get_preset(preset).edge_dot_threshold
        if (shape, "GT") not in edge_cache:
            edge_cache[shape, "GT"] = vd.sharp_edge_samples(*gt, radius, dot, n=vd.GT_EDGE_SAMPLES)
        gt_edges = edge_cache[shape, "GT"]
        views[0].caption = f"ground truth · {len(gt[1]):,} faces"
        views[0].glb, views[0].faces = _encode(*gt, caps.get("GT", MAX_VIEW_FACES), None, None,
                                               vd.point_subset(gt_edges), tau, vmax)
        views[0].file_faces = len(gt[1])
    for method in methods:
        view = View(method, captions[method])
        views.append(view)
        path = folder / f"{method}.ply"
        if not path.is_file():
            view.message = "no mesh"
            continue
        try:
            V, F = _read(path)
            if not len(F):
                view.message = "empty mesh"
                continue
            edges = np.zeros((0, 3))
            if gt_edges is not None:
                if (shape, method) not in edge_cache:
                    edge_cache[shape, method] = vd.point_subset(vd.sharp_edge_samples(
                        V, F, radius, get_preset(preset).edge_dot_threshold))
                edges = edge_cache[shape, method]
            view.glb, view.faces = _encode(V, F, caps.get(method, MAX_VIEW_FACES), gt, gt_edges, edges, tau, vmax)
            view.file_faces = len(F)
            if result.camera is None:  # no GT to frame the shape: the first prediction frames it
                result.camera = vd.initial_camera(V.min(0), V.max(0), up, render.DEFAULT_VIEW)
        except Exception as exc:  # noqa: BLE001
            view.message = f"unreadable: {one_line(exc)}"
    return result


@dataclass(frozen=True)
class _Draw:
    """``build(i, caps)`` as a callable of one ``(i, caps)`` item, for ``map_shapes``."""

    build: Callable[[int, dict], ShapeViews]

    def __call__(self, item: tuple[int, dict]) -> ShapeViews:
        return self.build(*item)


@dataclass
class _ViewBuilder:
    """``builder(i, caps)``: :func:`shape_views` of the ``i``-th of ``names``, picklable (plain
    data), so that several shapes can be drawn in parallel processes. ``edge_cache`` keeps the edge
    points of the meshes this copy has drawn."""

    names: list[str]
    meshes_dir: Path
    methods: list[str]
    captions: dict  # {(shape, method): caption}
    preset: str
    up: str
    vmax: float
    edge_cache: dict = field(default_factory=dict)

    def __call__(self, i: int, caps: dict) -> ShapeViews:
        shape = self.names[i]
        return shape_views(shape, Path(self.meshes_dir) / shape, self.methods,
                           {m: self.captions[shape, m] for m in self.methods}, caps, preset=self.preset, up=self.up,
                           vmax=self.vmax, edge_cache=self.edge_cache)


def _face_counts(shape_list: list[ShapeViews]) -> tuple[list[tuple[int, str]], np.ndarray]:
    keys = [(i, v.name) for i, s in enumerate(shape_list) for v in s.views if v.glb]
    counts = np.array([v.file_faces for s in shape_list for v in s.views if v.glb], dtype=np.int64)
    return keys, counts


def fit_views(build: Callable[[int, dict], ShapeViews], n_shapes: int, budget: int,
              map_shapes: Callable = map) -> tuple[list[ShapeViews], int]:
    """The views of the first ``n_shapes`` shapes (``build(i, caps)``) within ``budget`` bytes of
    GLB text: drawn in full when they fit (every shape through ``map_shapes``, in order: builtin
    ``map`` or a process pool's, then ``build`` must pickle), else re-drawn with the caps of
    :func:`reports.viewer_data.face_caps` from the bytes per face measured so far, up to
    :data:`_PASSES` times; then shapes are left out from the last one until the rest fits.
    Returns (shapes kept, shapes left out)."""
    draw = _Draw(build)
    shapes = list(map_shapes(draw, [(i, {}) for i in range(n_shapes)]))
    for _ in range(_PASSES):
        keys, counts = _face_counts(shapes)
        total = sum(len(v.glb) for s in shapes for v in s.views)
        if total <= budget or not len(counts):
            break
        drawn = sum(v.faces for s in shapes for v in s.views if v.glb)
        caps = vd.face_caps(np.minimum(counts, MAX_VIEW_FACES), 0.95 * budget, total / max(drawn, 1), MIN_VIEW_FACES)
        again = []
        for i in sorted({i for i, _ in keys}):
            shape_caps = {name: int(c) for (j, name), c in zip(keys, caps) if j == i}
            if any(shape_caps[v.name] < v.faces for v in shapes[i].views if v.glb):
                again.append((i, shape_caps))
        for (i, _), views in zip(again, map_shapes(draw, again)):
            shapes[i] = views
    dropped = 0
    while shapes and sum(len(v.glb) for s in shapes for v in s.views) > budget:
        shapes.pop()
        dropped += 1
    return shapes, dropped


# ---------------------------------------------------------------------------------------------
# Markup
# ---------------------------------------------------------------------------------------------


def inline_script(text: str, kind: str = "", element_id: str = "") -> str:
    """``<script>`` holding ``text`` as it is; ValueError when the text could end the element early
    (``</script`` or ``<!--``, which vendored code never holds; JSON is escaped by :func:`json_script`)."""
    lowered = text.lower()
    if "</script" in lowered or "<!--" in lowered:
        raise ValueError("script text holds '</script' or '<!--': it cannot be inlined as it is")
    attrs = (f' type="{kind}"' if kind else "") + (f' id="{element_id}"' if element_id else "")
    return f"<script{attrs}>{text}</script>"


def json_script(data, element_id: str) -> str:
    """``data`` as JSON in a ``<script type="application/json">``, '<' escaped as \\u003c."""
    text = json.dumps(data, separators=(",", ":"), ensure_ascii=False).replace("<", "\\u003c")
    return inline_script(text, "application/json", element_id)


def _hex(rgb) -> str:
    return "#" + "".join(f"{int(round(float(c) * 255)):02x}" for c in rgb)


def _legend(vmax: float, edge_note: str) -> str:
    swatch = '<i class="dot" style="background:{}"></i>'
    return (f'<div class="vlegend"><span>error: distance to GT</span>'
            f'<span class="vbar" style="background:{render.error_gradient_css()}"></span>'
            f'<span>0 … ≥ {vmax:g} (the gallery\'s scale)</span>'
            f'<span>edges: {swatch.format(_hex(vd.GT_EDGE_COLOR))}GT '
            f'{swatch.format(_hex(vd.MATCHED_EDGE_COLOR))}prediction within the EF1 threshold of a GT edge '
            f'{swatch.format(_hex(vd.UNMATCHED_EDGE_COLOR))}other prediction edges</span></div>'
            + (f'<p class="note">{escape(edge_note)}.</p>' if edge_note else ""))


def _decimation_note(shapes: list[ShapeViews], page_budget: int, dropped: int) -> str:
    cut = [(s.shape, v.name, v.faces, v.file_faces) for s in shapes for v in s.views if v.glb and v.faces < v.file_faces]
    text = f"Size budget of this page: {page_budget / 1e6:g} MB (${SIZE_BUDGET_ENV}). "
    if cut:
        items = "; ".join(f"{escape(s)} / {escape(n)}: {a:,} of {b:,} faces" for s, n, a, b in cut)
        text += (f"To fit it, {len(cut)} mesh(es) are drawn decimated (quadric edge collapse, for display "
                 f"only; the scores and the thumbnails are of the full meshes): {items}.")
    else:
        text += "Every mesh is drawn in full."
    if dropped:
        text += f" The last {dropped} shape(s) are left out of the viewer to stay within it."
    return f'<p class="note">{text}</p>'


def _notices(bundle: ViewerAssets) -> str:
    items = "".join(f"<h4>{escape(title)} ({escape(name)})</h4><pre>{escape(text)}</pre>"
                    for title, name, text in bundle.notices)
    return f"<details><summary>Embedded libraries and their licences</summary>{items}</details>"


def viewer_html(shapes: list[str], methods: list[str], meshes_dir: Path | None, caption: Callable[[str, str], str],
                colors: dict[str, str], *, preset: str, up: str, vmax: float, page_budget: int, page_bytes: int,
                limit: int, map_shapes: Callable = map) -> str:
    """The viewer section's HTML: controls, legend, the data of the first ``limit`` shapes' views and
    the scripts, within what ``page_budget`` bytes leave beside the ``page_bytes`` of the rest of
    the page (UTF-8), else a note saying why there is no viewer. ``caption(shape, method)`` is a
    method's caption (its metrics); ``colors`` {method: '#rrggbb'}; ``map_shapes`` as in :func:`fit_views`."""
    if meshes_dir is None or not Path(meshes_dir).is_dir():
        return '<p class="muted">No meshes directory: the 3D viewer is not available for this report.</p>'
    if limit == 0 or not shapes:
        return '<p class="muted">No 3D viewer in this report (gallery limit 0).</p>'
    bundle = assets()
    scripts = (inline_script(bundle.draco_wrapper, "text/plain", "viewer-draco") + inline_script(bundle.three)
               + inline_script(bundle.viewer))
    wasm = base64.b64encode(bundle.draco_wasm).decode("ascii")
    fixed = page_bytes + len(scripts.encode("utf-8")) + len(wasm) + 20_000  # + markup, captions, licences
    if page_budget - fixed < MIN_MESH_BYTES:
        return (f'<p class="muted">No 3D viewer: the page\'s size budget ({page_budget / 1e6:g} MB, '
                f'${SIZE_BUDGET_ENV}) leaves {max(page_budget - fixed, 0):,} bytes for its meshes.</p>')
    names = shapes[:limit]
    build = _ViewBuilder(names, Path(meshes_dir), list(methods), {(s, m): caption(s, m) for s in names for m in methods},
                         preset, up, vmax)
    fitted, dropped = fit_views(build, len(names), page_budget - fixed, map_shapes)
    data = {"vmax": vmax, "gtColor": _hex(render.GT_COLOR), "baseColor": _hex(render.BASE_COLOR),
            "dots": {m: colors.get(m, "#888888") for m in methods}, "dracoWasm": wasm,
            "shapes": [{"name": s.shape, "camera": s.camera, "views": [v.payload() for v in s.views]} for s in fitted]}
    options = "".join(f'<option value="{i}">{escape(s.shape)}</option>' for i, s in enumerate(fitted))
    controls = (f'<div class="vcontrols"><label>shape <select id="viewer-shape">{options}</select></label>'
                '<label><input type="checkbox" id="viewer-error"> error colouring</label>'
                '<label><input type="checkbox" id="viewer-edges"> sharp edges</label>'
                '<label><input type="checkbox" id="viewer-wire"> wireframe</label>'
                '<button type="button" id="viewer-reset">reset view</button></div>')
    more = (f'<p class="muted">Showing the first {len(fitted)} of {len(shapes)} shapes.</p>'
            if len(fitted) < len(shapes) else "")
    edge_note = next((s.edge_note for s in fitted if s.edge_note), "")
    return (f'<p class="note">Drag to turn, scroll to zoom, right-drag to pan: every view follows. '
            f'Same first camera as the thumbnails{"; z up" if up == "z" else ""}.</p>'
            f'{controls}{_legend(vmax, edge_note)}'
            '<div class="vgrid" id="viewer-grid"><noscript>The 3D viewer needs JavaScript.</noscript></div>'
            f'{more}{_decimation_note(fitted, page_budget, dropped)}{_notices(bundle)}'
            f'{json_script(data, "viewer-data")}{scripts}')
