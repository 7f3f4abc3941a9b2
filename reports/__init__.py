"""Reports of a salsbench run: paper tables, timing tables and a self-contained HTML page.

Public API
----------
write_reports(results, floor, context, out_dir, meshes_dir=None) -> {name: Path}
    summary.md, summary.tex, statistics.csv, timing.csv, timing.md and report.html in ``out_dir``;
    for a sweep run (``context['sweep']``) also sweep.md, sweep.tex and sweep.csv, and for a sweep of
    ``pc_corruption`` robustness.md and robustness.csv.
compare_runs(runs, out_dir) -> {name: Path}
    The same files for several runs side by side; ``runs`` is a list of dicts with keys name,
    results, floor, context, meshes_dir.
render_mesh(vertices, faces, colors=None, size=(256, 256), ...) -> PNG bytes (headless, CPU).

Inputs: ``results`` one row per (shape, method, seed) job, raw metric units, and ``floor`` one
row per shape (:mod:`reports.frames`); ``context`` the run's settings (:mod:`reports.protocol`).
A bad frame or context raises ValueError with a one-line message.

Modules: ``table`` (table model, Markdown/LaTeX writers), ``frames`` (input checks), ``protocol``
(context, preset text), ``style`` (method order and colours), ``statistics`` (per-method
statistics and their table), ``significance`` (bootstrap intervals, paired tests, the tie rule),
``summary`` (the run's tables, summary.md/.tex), ``sweep`` (a sweep run's tables and plots),
``robustness`` (a sweep of input corruptions: a table per kind, a plot per metric),
``timing``, ``compare`` (several runs), ``plots``, ``render`` (thumbnails), ``html`` (report.html),
``viewer`` (its 3D viewer; ``viewer_data`` its geometry, ``glb`` its mesh files, ``viewer_assets`` the
vendored JavaScript in ``reports/vendor/``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pandas as pd

from reports.compare import build_comparison, write_comparison
from reports.frames import check_results
from reports.html import GALLERY_LIMIT, write_comparison_html, write_html
from reports.protocol import check_context
from reports.render import render_mesh
from reports.robustness import build_robustness, robustness_html, write_robustness
from reports.summary import build_summary, write_summary
from reports.sweep import build_sweep, run_mode_results, sweep_html, write_sweep
from reports.timing import write_timing

__all__ = ["write_reports", "compare_runs", "render_mesh"]


def write_reports(results: pd.DataFrame, floor: pd.DataFrame | None, context: dict, out_dir: Path,
                  meshes_dir: Path | None = None, *, gallery_limit: int = GALLERY_LIMIT,
                  checkpoints: pd.DataFrame | None = None,
                  components: pd.DataFrame | None = None, max_bytes: int | None = None,
                  map_shapes: Callable = map) -> dict[str, Path]:
    """Write the run's tables and report into ``out_dir``; returns {file name: path}.

    Tables first (cheap), then report.html, which renders thumbnails from
    ``meshes_dir/<shape>/gt.ply`` and ``<method>.ply`` for the first ``gallery_limit`` shapes.
    ``checkpoints`` (one row per checkpoint of a fit: method, shape, seed, fraction,
    fit_elapsed_s, metrics) adds the anytime curves to the report. A sweep run's tables and plots
    (:mod:`reports.sweep`) come first; the ordinary tables get only the jobs of the run's mode
    (a neural sweep's oracle ceiling jobs are left out of them). ``components`` (one row per
    decomposition variant of a job: method, shape, seed, exact, metrics) adds the decomposition
    tables (:mod:`reports.decomposition`) to summary.md and the report. ``max_bytes``: report.html's
    size budget (default 30 MB or $SALSBENCH_REPORT_MAX_MB; :func:`reports.viewer.size_budget`).
    ``map_shapes(fn, shapes)``: how report.html's per-shape drawings are made, in order (builtin
    ``map``; the run layer passes its worker pool's, so several shapes are drawn at once).
    """
    out_dir = Path(out_dir)
    context, results = check_context(context), check_results(results)
    sweep = build_sweep(results, context)
    summary = build_summary(run_mode_results(results, context), floor, context, components)
    paths = write_summary(summary, context, out_dir)
    paths.update(write_sweep(sweep, context, out_dir) if sweep is not None else {})
    robustness = build_robustness(results, context)
    paths.update(write_robustness(robustness, context, out_dir) if robustness is not None else {})
    timing_paths, timing = write_timing(summary.own_results(), context, out_dir)  # a reference's seconds are another machine's
    paths.update(timing_paths)
    paths["report.html"] = write_html(out_dir / "report.html", summary, timing, context,
                                      Path(meshes_dir) if meshes_dir is not None else None,
                                      gallery_limit=gallery_limit, checkpoints=checkpoints,
                                      sweep_html=sweep_html(sweep) if sweep is not None else "",
                                      robustness_html=robustness_html(robustness) if robustness is not None else "",
                                      max_bytes=max_bytes, map_shapes=map_shapes)
    return paths


def compare_runs(runs: list[dict], out_dir: Path) -> dict[str, Path]:
    """Write summary.md/.tex, statistics.csv, timing.csv/.md and report.html comparing several runs in
    ``out_dir``."""
    comparison = build_comparison(runs)
    paths = write_comparison(comparison, Path(out_dir))
    paths["report.html"] = write_comparison_html(Path(out_dir) / "report.html", comparison)
    return paths
