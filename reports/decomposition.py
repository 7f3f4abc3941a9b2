"""Where a fitted field loses to the exact one: the tables of an error decomposition
(``run_benchmark.py --decompose``).

A decomposed neural job extracts its fitted field a second time for each set of components taken
from the exact field (the ``components`` table: one row per job and set, ``exact`` naming the set,
e.g. ``flags+s``). The first table has, per method, a row for the fitted field itself (the job
rows), one per set ("exact flags", "exact s+normals", ...) and last the set of every component,
which is the oracle field; its columns are the headline metrics, each the mean over shapes of the
shape's mean over seeds, in the summary tables' units, then the median over shapes, and the mean
face count. A row's gain over the fitted row is what its exact components are worth. The second
table holds the fitted components' own errors (mean over jobs), the columns the methods record.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from reports.frames import numeric, ok_jobs
from reports.table import DASH, Cell, Table, fmt, metric_header, metric_tex_header

FITTED = "fitted"
#: Component error columns the methods record, and their headers (others show their own name).
ERROR_LABELS = {
    "hit_edges": "hit edges", "false_hit_edges": "false hits", "missed_edges": "missed edges",
    "s_error_h": "s error (h)", "normal_error_deg": "normal error (°)", "udf_error_h": "UDF error (h)",
    "gradient_error_deg": "gradient error (°)", "sdf_error_h": "SDF error (h)",
    "wrong_side_points": "wrong-side points",
}


def variant_label(exact: str) -> str:
    """'flags+s' -> 'exact flags, s'; the fitted field itself is 'fitted'."""
    return FITTED if not exact else "exact " + exact.replace("+", ", ")


def _shape_means(frame: pd.DataFrame, columns: list[str], by: list[str]) -> pd.DataFrame:
    """Per (``by``, shape): each column's mean over seeds."""
    values = pd.DataFrame({c: numeric(frame, c) for c in columns}, index=frame.index)
    return values.groupby([frame[k] for k in by] + [frame["shape"]]).mean()


def decomposed_jobs(results: pd.DataFrame, components: pd.DataFrame) -> pd.DataFrame:
    """The successful job rows that have decomposition rows."""
    return ok_jobs(results).merge(components[["shape", "method", "seed"]].drop_duplicates(),
                                  on=["shape", "method", "seed"])


def decomposition_frame(results: pd.DataFrame, components: pd.DataFrame, metrics: list,
                        methods: list[str]) -> pd.DataFrame:
    """One row per (method, variant) in table order: mean and median over shapes of every headline
    metric (table units), the mean face count and the number of shapes. Only shapes whose fitted job
    and every variant succeeded count, so all rows of a method average the same shapes."""
    columns = [m.column for m in metrics] + ["n_faces"]
    scale = pd.Series({m.column: m.scale for m in metrics} | {"n_faces": 1.0})
    components = components.assign(exact=components["exact"].fillna(""))
    rows = pd.concat([decomposed_jobs(results, components).assign(exact=""), components], ignore_index=True)
    per_shape = _shape_means(rows, columns, ["method", "exact"]) * scale
    out = []
    for method in [m for m in methods if m in set(components["method"])]:
        mine = per_shape.xs(method, level="method")
        found = set(mine.index.get_level_values("exact"))
        variants = [v for v in ["", *dict.fromkeys(components.loc[components["method"] == method, "exact"])]
                    if v in found]
        shapes = sorted(set.intersection(*(set(mine.loc[v].index) for v in variants)))
        for v in variants:
            part = mine.loc[v].loc[shapes]
            out.append({"method": method, "variant": variant_label(v), "shapes": len(part),
                        **{f"mean.{c}": part[c].mean() for c in columns},
                        **{f"median.{c}": part[c].median() for c in columns if c != "n_faces"}})
    return pd.DataFrame(out)


def decomposition_table(frame: pd.DataFrame, metrics: list, caption: str) -> Table:
    """The first table of the module docstring (``frame``: :func:`decomposition_frame`)."""
    headers = (["method", "field"] + [f"mean {metric_header(m)}" for m in metrics]
               + [f"median {metric_header(m)}" for m in metrics] + ["faces", "shapes"])
    tex = (["method", "field"] + [f"mean {metric_tex_header(m)}" for m in metrics]
           + [f"median {metric_tex_header(m)}" for m in metrics] + ["faces", "shapes"])
    table = Table("decomposition", "Error decomposition: fitted field with exact components", caption, headers, tex,
                  ["l", "l"] + ["r"] * (len(headers) - 2))
    for values in frame.to_dict("records"):
        cells = [Cell(values["method"]), Cell(values["variant"])]
        cells += [Cell(fmt(values[f"mean.{m.column}"])) for m in metrics]
        cells += [Cell(fmt(values[f"median.{m.column}"])) for m in metrics]
        cells += [Cell(f"{values['mean.n_faces']:,.0f}" if np.isfinite(values["mean.n_faces"]) else DASH),
                  Cell(str(values["shapes"]))]
        table.add(cells, "method" if values["variant"] == FITTED else "step")
    table.notes.append("Each row extracts the same fitted network's field with the named components taken from the "
                       "exact field instead (the last row of a method: every component exact, the oracle field). "
                       "Mean and median over the shapes where every row of the method succeeded (each shape's "
                       "seeds averaged first).")
    return table


def component_error_table(results: pd.DataFrame, components: pd.DataFrame, methods: list[str],
                          caption: str) -> Table | None:
    """The fitted components' errors per method (mean over its decomposed jobs); None without any."""
    jobs = decomposed_jobs(results, components)
    columns = [c for c in ERROR_LABELS if c in jobs.columns and numeric(jobs, c).notna().any()]
    if not columns or jobs.empty:
        return None
    headers = ["method"] + [ERROR_LABELS[c] for c in columns] + ["jobs"]
    table = Table("component-errors", "Errors of the fitted components", caption, headers, headers,
                  ["l"] + ["r"] * (len(headers) - 1))
    for method in [m for m in methods if m in set(jobs["method"])]:
        mine = jobs[jobs["method"] == method]
        means = [numeric(mine, c).mean() for c in columns]
        cells = [Cell(method)]
        cells += [Cell(DASH if not np.isfinite(v) else (f"{v:,.0f}" if c.endswith(("edges", "points")) else fmt(v)))
                  for c, v in zip(columns, means)]
        table.add(cells + [Cell(str(len(mine)))])
    table.notes.append("Against the exact field on the same grid, mean over jobs. SALS: grid edges both fields "
                       "intersect (hit), only the network (false hits), only the exact field (missed); on the hit "
                       "edges the mean |s - s*| in grid spacings h and the median unoriented normal angle. UDF: "
                       "mean |d - d*| / h and the median gradient angle where d* < 2h. SDF and BOF: grid points on "
                       "the wrong side of the level set; SDF: mean |f - f*| / h where |f*| < 2h.")
    return table


def decomposition_tables(results: pd.DataFrame, components: pd.DataFrame | None, metrics: list,
                         methods: list[str], caption: str) -> dict[str, Table]:
    """{key: Table} of a decomposed run ({} without components rows)."""
    if components is None or components.empty:
        return {}
    tables = {"decomposition": decomposition_table(decomposition_frame(results, components, metrics, methods),
                                                   metrics, caption)}
    errors = component_error_table(results, components, methods, caption)
    if errors is not None:
        tables["component-errors"] = errors
    return tables
