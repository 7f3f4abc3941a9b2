"""Reports of a salsbench run: paper tables, timing tables and a self-contained HTML page.

Public API
----------
write_reports(results, floor, config, out_dir, meshes_dir=None) -> {name: Path}
    summary.md, summary.tex, timing.csv, timing.md and report.html in ``out_dir``.
compare_runs(run_frames, out_dir) -> {name: Path}
    The same files for several runs side by side; ``run_frames`` items are
    (label, results, floor, config[, meshes_dir]) tuples or dicts with keys name|label, results,
    floor, config (as ``run_benchmark.py report RUN_DIR ...`` builds them).
render_mesh(vertices, faces, colors=None, size=(256, 256), ...) -> PNG bytes (headless, CPU).

Frames: ``results`` one row per (shape, method, seed) job, raw metric units; ``floor`` one row per
shape (GT against a resample of itself). See :mod:`reports.tables` for the columns and statistics.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from reports.render import render_mesh
from reports.tables import (
    MetricSpec,
    as_runs,
    build_summary,
    check_results,
    metric_specs,
    timing_frame,
    write_comparison_tables,
    write_tables,
)

__all__ = ["write_reports", "compare_runs", "render_mesh", "metric_specs", "MetricSpec", "build_summary", "timing_frame"]


def write_reports(results: pd.DataFrame, floor: pd.DataFrame | None, config: dict | None, out_dir: Path,
                  meshes_dir: Path | None = None, *, gallery_limit: int = 24, html: bool = True) -> dict[str, Path]:
    """Write the run's tables and report into ``out_dir``; returns {file name: path}.

    Tables first (cheap, always written), then report.html (renders thumbnails from
    ``meshes_dir/<shape>/gt.ply`` and ``<method>.ply``; the first ``gallery_limit`` shapes).
    A bad frame raises ValueError with a one-line message.
    """
    from reports.html import write_html

    config = dict(config or {})
    out_dir = Path(out_dir)
    summary = build_summary(results, floor, config)
    paths = write_tables(results, floor, config, out_dir, summary=summary)
    if html:
        timing = timing_frame(check_results(results), config)
        paths["report.html"] = write_html(out_dir / "report.html", results, floor, config, summary, timing,
                                          Path(meshes_dir) if meshes_dir is not None else None,
                                          gallery_limit=gallery_limit)
    return paths


def compare_runs(run_frames, out_dir: Path) -> dict[str, Path]:
    """Write summary.md/.tex, timing.csv/.md and report.html comparing several runs in ``out_dir``."""
    from reports.html import write_comparison_html

    runs = as_runs(run_frames)
    paths, tables, timing = write_comparison_tables(runs, Path(out_dir))
    paths["report.html"] = write_comparison_html(Path(out_dir) / "report.html", runs, tables, timing)
    return paths
