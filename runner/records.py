"""The results database of a run: one SQLite file, ``<run dir>/results.db``.

The driver (:mod:`runner.driver`) is its only writer; every finished task is committed at
once (WAL journal), so killing the process loses at most the tasks in flight. Readers (reports,
``sqlite3``, pandas) may open it at any time.

Tables (:data:`SCHEMA_VERSION`; columns declared in :mod:`foundation.schema`):

* ``jobs`` -- one row per job, primary key ``config_hash`` (the task key, :mod:`tasks`);
  a re-run of a failed job replaces its row.
* ``floor`` -- one row per shape (GT against a resample of itself), primary key ``floor_hash``.
* ``checkpoints`` -- one row per checkpoint of a job's fit (``--checkpoints``), primary key
  ``checkpoint_hash`` (job key @ fraction), written with the job's row.
* ``components`` -- one row per decomposition variant of a neural job (``--decompose``), primary
  key ``component_hash`` (job key @ exact components), written with the job's row.
* ``meta`` -- ``key TEXT PK, value TEXT``: ``schema_version``.

Metric and timing keys not declared in the schema get their own column the first time they
appear (``ALTER TABLE``; REAL for numbers, TEXT for strings). A sweep's values are columns
``sweep.<key>`` (NULL where the key does not apply to the job); ``fitted`` is 1 for a job that
trained its network. Booleans are stored as 0/1. A key
that clashes with a fixed column is stored as ``metric_<key>``; non-scalar values go to ``extra``
(JSON).
"""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
import pandas as pd

from foundation.errors import one_line
from foundation.schema import PRIMARY_KEYS, TABLES, sql_columns
from foundation.serialize import dumps

SCHEMA_VERSION = 3
DB_NAME = "results.db"

#: Each table's SQL column declarations {name: type and constraints}, from foundation.schema's columns.
JOB_SQL: dict[str, str] = sql_columns("jobs")
FLOOR_SQL: dict[str, str] = sql_columns("floor")
CHECKPOINT_SQL: dict[str, str] = sql_columns("checkpoints")
COMPONENT_SQL: dict[str, str] = sql_columns("components")
#: Declared columns that hold measured values (metrics, mesh counts, timings).
MEASURED = {c.name for table in TABLES.values() for c in table if c.role in ("metric", "validity", "timing")}

#: Keys of ``metrics.evaluate``'s result that restate the protocol; recorded by fixed columns instead.
PROTOCOL_KEYS = ("preset", "n_points", "seed")

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
#: Column prefix of a job's sweep values (``sweep.sals.o_threshold``; :mod:`runner.sweep`).
SWEEP_PREFIX = "sweep."


def column_name(key: str, fixed: Mapping[str, str]) -> str:
    """SQL column for a metric/timing key: the key itself (declared measured columns included),
    ``metric_<key>`` if it clashes with a fixed non-measured column (e.g. 'status'); anything that
    is not an identifier is rewritten with underscores."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", str(key))
    if not _NAME.match(name):
        name = "m_" + name
    return f"metric_{name}" if name in fixed and name not in MEASURED else name


def scalar(value: Any) -> tuple[bool, Any]:
    """(is a scalar, SQL value): numbers -> float/int, bools -> 0/1, strings as is, None -> NULL."""
    if value is None:
        return True, None
    if isinstance(value, (bool, np.bool_)):
        return True, int(bool(value))
    if isinstance(value, (int, np.integer)):
        return True, int(value)
    if isinstance(value, (float, np.floating)):
        return True, float(value)
    if isinstance(value, str):
        return True, value
    return False, None


class SchemaMismatch(ValueError):
    """A results database this version cannot use, in one line naming the file: written by another
    schema version, not a salsbench results database (no schema version, a table or key column
    missing), or damaged (not a readable SQLite file)."""


class ResultsDB:
    """The results database of one run directory (created on first use).

    >>> db = ResultsDB(run_dir / "results.db")      # doctest: +SKIP
    >>> db.write_job(row)                             # commits at once
    >>> db.ok_hashes()                                # jobs that need not run again

    An existing file is checked before anything is written to it (:meth:`_check`): one that this
    version cannot use raises :class:`SchemaMismatch` and is left as it was. ``create=False`` (a
    reader: the reports) opens an existing database only, and writes nothing to it.
    """

    def __init__(self, path: str | Path, create: bool = True):
        self.path = Path(path)
        self.conn = None
        if self.path.is_file() and self.path.stat().st_size:  # SQLite would take a byte or two for a new database
            with open(self.path, "rb") as f:
                if f.read(16) != b"SQLite format 3\x00":
                    raise SchemaMismatch(f"{self.path}: not a results database (not an SQLite file)")
        try:
            if create:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.conn = sqlite3.connect(str(self.path), timeout=60.0, isolation_level=None)
            else:  # mode=rw: never creates the file
                self.conn = sqlite3.connect(f"{self.path.resolve().as_uri()}?mode=rw", timeout=60.0,
                                            isolation_level=None, uri=True)
            tables = self._tables()
            if tables or not create:
                self._check(tables)
            if create:
                self.conn.execute("PRAGMA journal_mode=WAL")
                self.conn.execute("PRAGMA synchronous=NORMAL")
                self._create()
        except sqlite3.DatabaseError as exc:  # not an SQLite file, or a damaged one
            self.close()
            raise SchemaMismatch(f"{self.path}: not a readable results database ({one_line(exc, with_type=False)})") from None
        except SchemaMismatch:
            self.close()
            raise

    # -- schema -----------------------------------------------------------------------------
    def _tables(self) -> set[str]:
        return {r[0] for r in self.conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}

    def _check(self, tables: set[str]) -> None:
        """Refuse, with :class:`SchemaMismatch`, a file this version cannot use: a damaged one, one of
        another schema version, one without the tables and key columns every results database has
        had since this version (tables added since, as ``components``, may be absent)."""
        problems = [r[0] for r in self.conn.execute("PRAGMA quick_check")]
        if problems != ["ok"]:
            raise SchemaMismatch(f"{self.path}: damaged results database ({' '.join(str(problems[0]).split())[:200]})")
        if "meta" not in tables:
            raise SchemaMismatch(f"{self.path}: not a salsbench results database (no table 'meta' with its schema "
                                 f"version)")
        stored = self.get_meta("schema_version")
        if stored is None:
            raise SchemaMismatch(f"{self.path}: not a salsbench results database (no schema version in table 'meta')")
        if stored != str(SCHEMA_VERSION):
            stored = stored if str(stored).isprintable() else repr(stored)  # a line break stays escaped
            raise SchemaMismatch(f"{self.path}: results database schema {stored}, this version reads {SCHEMA_VERSION}; "
                                 f"start a new --out (or use the salsbench version that wrote it)")
        for table, columns in TABLES.items():
            if table not in tables:
                if table in ("jobs", "floor"):
                    raise SchemaMismatch(f"{self.path}: not a salsbench results database (no table '{table}')")
                continue
            have = set(self.columns(table))
            missing = [c.name for c in columns if c.role in ("key", "status") and c.name not in have]
            if missing:
                raise SchemaMismatch(f"{self.path}: table '{table}' has no column {', '.join(missing)} (not a "
                                     f"salsbench results database of this version)")

    def _create(self) -> None:
        """The tables and the schema version, in one transaction (a kill leaves all or nothing)."""
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            for table in TABLES:
                cols = ", ".join(f'"{k}" {t}' for k, t in sql_columns(table).items())
                self.conn.execute(f'CREATE TABLE IF NOT EXISTS "{table}" ({cols})')
            self.conn.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
            if self.get_meta("schema_version") is None:
                self.set_meta("schema_version", str(SCHEMA_VERSION))
            self.conn.execute("COMMIT")
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise

    def columns(self, table: str) -> list[str]:
        return [r[1] for r in self.conn.execute(f'PRAGMA table_info("{table}")')]

    def _ensure_columns(self, table: str, values: Mapping[str, Any]) -> None:
        have = set(self.columns(table))
        for key, value in values.items():
            if key not in have:
                sql_type = "TEXT" if isinstance(value, str) else "REAL"
                self.conn.execute(f'ALTER TABLE "{table}" ADD COLUMN "{key}" {sql_type}')
                have.add(key)

    # -- meta -------------------------------------------------------------------------------
    def get_meta(self, key: str) -> str | None:
        row = self.conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else row[0]

    def set_meta(self, key: str, value: str) -> None:
        self.conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, value))

    # -- writing ----------------------------------------------------------------------------
    @staticmethod
    def flatten(fixed: Mapping[str, Any], measured: Iterable[Mapping[str, Any]], fixed_columns: Mapping[str, str]) -> dict:
        """One SQL row: the fixed fields (dicts/lists JSON-encoded) plus every scalar of the
        ``measured`` dicts as its own column; non-scalars go to the ``extra`` JSON column."""
        row: dict[str, Any] = {}
        extra: dict[str, Any] = {}
        for key, value in fixed.items():
            if key not in fixed_columns:
                raise KeyError(f"'{key}' is not a fixed column")
            row[key] = dumps(value) if isinstance(value, (dict, list, tuple)) else scalar(value)[1]
        for values in measured:
            for key, value in values.items():
                if key in PROTOCOL_KEYS:
                    continue
                ok, sql_value = scalar(value)
                if ok:
                    row[column_name(key, fixed_columns)] = sql_value
                else:
                    extra[key] = value
        if extra:
            row["extra"] = dumps(extra)
        return row

    def _commit(self, table: str, rows: list[Mapping[str, Any]], delete: tuple[str, str] | None = None) -> None:
        """In one transaction: delete the rows whose ``delete[0]`` column equals ``delete[1]`` (if
        given), then insert-or-replace ``rows``; new measured columns are added first."""
        for row in rows:
            self._ensure_columns(table, row)
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            if delete is not None:
                self.conn.execute(f'DELETE FROM "{table}" WHERE "{delete[0]}" = ?', (delete[1],))
            for row in rows:
                names = ", ".join(f'"{k}"' for k in row)
                marks = ", ".join("?" for _ in row)
                self.conn.execute(f'INSERT OR REPLACE INTO "{table}" ({names}) VALUES ({marks})', tuple(row.values()))
            self.conn.execute("COMMIT")
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise

    def write_job(self, fixed: Mapping[str, Any], metrics: Mapping[str, Any] | None = None,
                  timings: Mapping[str, Any] | None = None, sweep: Mapping[str, Any] | None = None,
                  fitted: int | None = None) -> None:
        """Insert (or replace) one job row and commit. ``fixed`` holds :data:`JOB_SQL` fields;
        ``sweep`` the job's sweep values, each in its column ``sweep.<key>``; ``fitted`` 1 when the
        job trained its network (0: weights from the cache or a cached mesh)."""
        if "config_hash" not in fixed:
            raise KeyError("a job row needs its config_hash")
        row = self.flatten(fixed, [metrics or {}, timings or {}], JOB_SQL)
        row.update({f"{SWEEP_PREFIX}{k}": scalar(v)[1] for k, v in (sweep or {}).items()})
        if fitted is not None:
            row["fitted"] = int(fitted)
        self._commit("jobs", [row])

    def write_floor(self, fixed: Mapping[str, Any], metrics: Mapping[str, Any] | None = None,
                    timings: Mapping[str, Any] | None = None) -> None:
        """Insert (or replace) one floor row and commit. ``fixed`` holds :data:`FLOOR_SQL` fields."""
        if "floor_hash" not in fixed:
            raise KeyError("a floor row needs its floor_hash")
        self._commit("floor", [self.flatten(fixed, [metrics or {}, timings or {}], FLOOR_SQL)])

    def write_checkpoints(self, config_hash: str, fixed: Mapping[str, Any], rows: list[Mapping[str, Any]]) -> None:
        """Replace the checkpoint rows of one job (``rows``: fraction, step, fit_elapsed_s, metrics,
        timings each) in one transaction; ``fixed`` holds the job's shape, method, seed."""
        self._replace_job_rows("checkpoints", config_hash, fixed, rows, ("fraction", "step"),
                               lambda r: f"{config_hash}@{r['fraction']:g}")

    def write_components(self, config_hash: str, fixed: Mapping[str, Any], rows: list[Mapping[str, Any]]) -> None:
        """Replace the decomposition rows of one job (``rows``: exact, metrics, timings each) in one
        transaction; ``fixed`` holds the job's shape, method, seed."""
        self._replace_job_rows("components", config_hash, fixed, rows, ("exact",), lambda r: f"{config_hash}@{r['exact']}")

    def _replace_job_rows(self, table: str, config_hash: str, fixed: Mapping[str, Any], rows: list[Mapping[str, Any]],
                          keys: tuple[str, ...], row_hash) -> None:
        """The rows of ``table`` that belong to one job, replaced by ``rows`` (their ``keys`` are key
        columns, the rest metrics and timings) in one transaction."""
        columns = {"checkpoints": CHECKPOINT_SQL, "components": COMPONENT_SQL}[table]
        flat = [self.flatten({PRIMARY_KEYS[table]: row_hash(r), "config_hash": config_hash,
                              **{k: r[k] for k in keys}, **fixed},
                             [{k: v for k, v in r.items() if k not in keys}], columns)
                for r in rows]
        self._commit(table, flat, delete=("config_hash", config_hash))

    # -- reading ----------------------------------------------------------------------------
    def ok_hashes(self, table: str = "jobs") -> set[str]:
        """Hashes of rows with status 'ok' (jobs or floor rows that need not run again)."""
        key = PRIMARY_KEYS[table]
        return {r[0] for r in self.conn.execute(f'SELECT "{key}" FROM "{table}" WHERE status = ?', ("ok",))}

    def ok_codes(self, table: str = "jobs") -> dict[str, str | None]:
        """{hash: code digest} of the rows with status 'ok': which code computed each finished task."""
        key = PRIMARY_KEYS[table]
        return dict(self.conn.execute(f'SELECT "{key}", code FROM "{table}" WHERE status = ?', ("ok",)))

    def attempts(self) -> dict[str, int]:
        return {h: int(a or 0) for h, a in self.conn.execute("SELECT config_hash, attempts FROM jobs")}

    def frame(self, table: str = "jobs") -> pd.DataFrame:
        """The table as a DataFrame (NULL -> NaN/None), in insertion order; a table the database
        does not have yet (added by a later version, :meth:`_check`) is an empty frame of its
        declared columns."""
        try:
            if table not in self._tables():
                return pd.DataFrame({name: pd.Series(dtype=float if sql == "REAL" else object)
                                     for name, sql in sql_columns(table).items()})
            df = pd.read_sql_query(f'SELECT * FROM "{table}" ORDER BY rowid', self.conn)
            for _, name, sql_type, *_ in self.conn.execute(f'PRAGMA table_info("{table}")'):
                if sql_type.upper() == "REAL" and name in df.columns:  # all-NULL columns come back as None
                    df[name] = pd.to_numeric(df[name], errors="coerce").astype(float)
        except (sqlite3.DatabaseError, pd.errors.DatabaseError) as exc:
            raise SchemaMismatch(f"{self.path}: damaged results database ({one_line(exc, with_type=False)})") from None
        return df

    def close(self) -> None:
        try:
            if self.conn is not None:
                self.conn.close()
        except sqlite3.Error:
            pass

    def __enter__(self) -> "ResultsDB":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_run_db(run_dir: str | Path, must_exist: bool = False) -> ResultsDB:
    """The database of a run directory; ``must_exist`` (a reader) raises FileNotFoundError (one line)
    if absent, and opens it without writing (``ResultsDB(..., create=False)``)."""
    path = Path(run_dir) / DB_NAME
    if must_exist and not path.is_file():
        raise FileNotFoundError(f"{run_dir}: no {DB_NAME} (not a salsbench run directory?)")
    return ResultsDB(path, create=not must_exist)


