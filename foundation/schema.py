"""The result schema: one declaration from which every table of results derives.

``results.db`` columns (:mod:`runner.records`), the lead columns of ``results.csv`` (a
contract: scripts read them), the validity columns of the reports and the columns the CI regression
compares all come from :data:`JOB_COLUMNS` / :data:`FLOOR_COLUMNS` below. Metric and timing keys
that a preset or a method adds (``f1_003``, ``extract_qef_s``, ...) are stored as extra columns when
they first appear (REAL for numbers, TEXT for strings); the declared ones fix the order and types.

Roles: ``key`` (what identifies a row), ``status``, ``setup`` (the job's settings), ``metric``
(raw units, never scaled: tables apply the preset's multipliers), ``validity`` (mesh counts of the
prediction as given), ``timing`` (wall-clock seconds, name ends in ``_s``), ``bookkeeping``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Column:
    """One result column.

    name : column name (SQL, CSV, pandas). sql : SQLite type. role : see module docstring.
    label : short header for reports (validity columns). csv : part of results.csv's lead columns.
    regression : compared by the CI regression (``runner.regression``).
    """

    name: str
    sql: str
    role: str
    label: str = ""
    csv: bool = False
    regression: bool = False


def _c(name, sql, role, label="", csv=False, regression=False) -> Column:
    return Column(name, sql, role, label, csv, regression)


JOB_COLUMNS: tuple[Column, ...] = (
    _c("config_hash", "TEXT PRIMARY KEY", "key"),
    _c("shape", "TEXT", "key", csv=True),
    _c("method", "TEXT", "key", csv=True),
    _c("mode", "TEXT", "setup", csv=True),
    _c("seed", "INTEGER", "key", csv=True),
    _c("status", "TEXT", "status", csv=True),
    _c("error", "TEXT", "status", csv=True),
    _c("cd", "REAL", "metric", csv=True, regression=True),
    _c("nc", "REAL", "metric", csv=True, regression=True),
    _c("f1_005", "REAL", "metric", csv=True, regression=True),
    _c("f1_01", "REAL", "metric", csv=True, regression=True),
    _c("ecd", "REAL", "metric", csv=True, regression=True),
    _c("ef1", "REAL", "metric", csv=True, regression=True),
    _c("n_vertices", "INTEGER", "validity", "#V", csv=True, regression=True),
    _c("n_faces", "INTEGER", "validity", "#F", csv=True, regression=True),
    _c("boundary_edges", "INTEGER", "validity", "boundary edges", csv=True, regression=True),
    _c("nonmanifold_edges", "INTEGER", "validity", "non-manifold edges", csv=True, regression=True),
    _c("components", "INTEGER", "validity", "components", csv=True, regression=True),
    _c("watertight", "INTEGER", "validity", "watertight %"),
    _c("empty_prediction", "INTEGER", "metric"),
    _c("ecd_flag", "INTEGER", "metric"),
    _c("scored", "INTEGER", "metric"),
    _c("fit_s", "REAL", "timing", csv=True),
    _c("query_s", "REAL", "timing", csv=True),
    _c("extract_s", "REAL", "timing", csv=True),
    _c("metrics_s", "REAL", "timing", csv=True),
    _c("traceback", "TEXT", "status"),
    _c("params", "TEXT", "setup"),
    _c("budget", "TEXT", "setup"),
    _c("grid", "INTEGER", "setup"),
    _c("eval_points", "INTEGER", "setup"),
    _c("metric_preset", "TEXT", "setup"),
    _c("used_sensors", "INTEGER", "setup", "sensors", csv=True),
    _c("seen_in_training", "INTEGER", "setup", "seen in training", csv=True),
    # added after the columns above: declared here so that the earlier results.csv lead columns keep
    # their positions (foundation.metrics: distance distribution, volumetric IoU, topology, self-intersections)
    _c("iou", "REAL", "metric", csv=True),
    _c("dist_median", "REAL", "metric", csv=True),
    _c("dist_p90", "REAL", "metric", csv=True),
    _c("dist_p99", "REAL", "metric", csv=True),
    _c("hausdorff", "REAL", "metric", csv=True),
    _c("euler_characteristic", "INTEGER", "validity", "Euler char."),
    _c("genus", "REAL", "validity", "genus", csv=True),
    _c("self_intersecting_pairs", "INTEGER", "validity", "self-int. pairs", csv=True),
    _c("self_intersecting_faces", "INTEGER", "validity", "self-int. faces"),
    _c("precision", "TEXT", "setup", csv=True),
    _c("shape_hash", "TEXT", "bookkeeping"),
    _c("shape_kind", "TEXT", "bookkeeping"),
    _c("fit_loss", "REAL", "bookkeeping"),
    _c("attempts", "INTEGER", "bookkeeping"),
    _c("cache", "TEXT", "bookkeeping"),
    _c("cache_rejected", "INTEGER", "bookkeeping"),
    _c("mesh_path", "TEXT", "bookkeeping"),
    _c("device", "TEXT", "bookkeeping"),
    _c("host", "TEXT", "bookkeeping"),
    _c("versions", "TEXT", "bookkeeping"),
    _c("info", "TEXT", "bookkeeping"),
    _c("started", "TEXT", "bookkeeping"),
    _c("finished", "TEXT", "bookkeeping"),
    _c("code", "TEXT", "bookkeeping"),
    _c("extra", "TEXT", "bookkeeping"),
)

FLOOR_COLUMNS: tuple[Column, ...] = (
    _c("floor_hash", "TEXT PRIMARY KEY", "key"),
    _c("shape", "TEXT", "key", csv=True),
    _c("seed", "INTEGER", "key", csv=True),
    _c("status", "TEXT", "status", csv=True),
    _c("error", "TEXT", "status", csv=True),
    *(c for c in JOB_COLUMNS if c.role == "metric"),
    _c("shape_hash", "TEXT", "bookkeeping"),
    _c("shape_kind", "TEXT", "bookkeeping"),
    _c("source", "TEXT", "bookkeeping"),
    _c("gt_vertices", "INTEGER", "bookkeeping"),
    _c("gt_faces", "INTEGER", "bookkeeping"),
    _c("eval_points", "INTEGER", "setup"),
    _c("metric_preset", "TEXT", "setup"),
    _c("mesh_path", "TEXT", "bookkeeping"),
    _c("finished", "TEXT", "bookkeeping"),
    _c("code", "TEXT", "bookkeeping"),
    _c("extra", "TEXT", "bookkeeping"),
)

def _per_job_columns(key: str, own: tuple[Column, ...]) -> tuple[Column, ...]:
    """The columns of a table with several rows per job: its primary key, the job's shape, method and
    seed, the table's ``own`` columns, the job table's metric and validity columns, the job key."""
    return (_c(key, "TEXT PRIMARY KEY", "key"), _c("shape", "TEXT", "key", csv=True),
            _c("method", "TEXT", "key", csv=True), _c("seed", "INTEGER", "key", csv=True), *own,
            *(c for c in JOB_COLUMNS if c.role in ("metric", "validity")),
            _c("config_hash", "TEXT", "bookkeeping"), _c("extra", "TEXT", "bookkeeping"))


#: One row per checkpoint of a job's fit (``--checkpoints``): the anytime curves.
CHECKPOINT_COLUMNS = _per_job_columns("checkpoint_hash", (
    _c("fraction", "REAL", "key", csv=True),
    _c("step", "INTEGER", "key", csv=True),
    _c("fit_elapsed_s", "REAL", "timing", csv=True),
))

#: One row per decomposition variant of a neural job (``--decompose``): the job's fitted field with
#: the components ``exact`` (e.g. 'flags+s') taken from the exact field, extracted and scored.
COMPONENT_COLUMNS = _per_job_columns("component_hash", (
    _c("exact", "TEXT", "key", csv=True),
    _c("extract_s", "REAL", "timing"),
))

TABLES = {"jobs": JOB_COLUMNS, "floor": FLOOR_COLUMNS, "checkpoints": CHECKPOINT_COLUMNS,
          "components": COMPONENT_COLUMNS}
PRIMARY_KEYS = {"jobs": "config_hash", "floor": "floor_hash", "checkpoints": "checkpoint_hash",
                "components": "component_hash"}

#: Columns of the traceback/JSON kind that results.csv leaves out (they live in results.db).
CSV_EXCLUDED = ("traceback", "versions", "info", "extra")


def sql_columns(table: str) -> dict[str, str]:
    """{column: SQLite type} of the fixed columns of ``table`` (a key of :data:`TABLES`)."""
    return {c.name: c.sql for c in TABLES[table]}


def csv_lead(table: str = "jobs") -> list[str]:
    """The contract columns that lead results.csv (or floor.csv), in order."""
    return [c.name for c in TABLES[table] if c.csv]


def columns(role: str, table: str = "jobs") -> list[Column]:
    """The declared columns of one role, in declaration order."""
    return [c for c in TABLES[table] if c.role == role]


def regression_columns() -> list[str]:
    """Columns the CI regression compares with its baselines (headline metrics and mesh counts)."""
    return [c.name for c in JOB_COLUMNS if c.regression]
