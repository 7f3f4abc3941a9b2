"""The results database (runner.records): schema, round trips, replacement, WAL, readers."""

from __future__ import annotations

import json
import math
import sqlite3

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from runner.records import DB_NAME, JOB_SQL, ResultsDB, SchemaMismatch, column_name, open_run_db
from tests.loader_fuzz import FLOATS, loads_or_refuses


def _job(hash_, status="ok", **kw):
    row = {"config_hash": hash_, "shape": "cube", "method": "sdf", "mode": "oracle", "seed": 0, "status": status,
           "error": None if status == "ok" else "extracting: RuntimeError: boom", "params": {"level": 0.0},
           "grid": 32, "finished": "2025-01-01T00:00:00.000+00:00"}
    row.update(kw)
    return row


def test_schema_created_with_wal(tmp_path):
    db = ResultsDB(tmp_path / DB_NAME)
    assert set(JOB_SQL) <= set(db.columns("jobs"))
    assert {"floor_hash", "shape", "status"} <= set(db.columns("floor"))
    assert db.conn.execute("PRAGMA journal_mode").fetchone()[0].lower() == "wal"
    assert db.get_meta("schema_version") == "3"
    db.close()


def test_round_trip_adds_metric_and_timing_columns(tmp_path):
    db = ResultsDB(tmp_path / DB_NAME)
    metrics = {"cd": 0.0045, "nc": 0.98, "watertight": True, "ecd": float("nan"), "ecd_flag": np.bool_(True),
               "n_faces": np.int64(1234), "preset": "default", "seed": 0, "n_points": 1000,
               "status": "clash", "per_axis": [1, 2, 3]}
    timings = {"fit_s": 1.5, "extract_qef_s": 0.25}
    db.write_job(_job("a"), metrics, timings)
    df = db.frame("jobs")
    assert len(df) == 1
    row = df.iloc[0]
    assert row["cd"] == pytest.approx(0.0045) and row["nc"] == pytest.approx(0.98)
    assert row["watertight"] == 1 and row["ecd_flag"] == 1          # bools stored as 0/1
    assert math.isnan(row["ecd"])                                     # NaN -> NULL -> NaN
    assert row["n_faces"] == 1234
    assert row["fit_s"] == 1.5 and row["extract_qef_s"] == 0.25
    assert row["metric_status"] == "clash" and row["status"] == "ok"  # clash with a fixed column is prefixed
    assert "n_points" not in df.columns and "preset" not in df.columns  # protocol keys: fixed columns hold them
    assert json.loads(row["extra"]) == {"per_axis": [1, 2, 3]}
    assert json.loads(row["params"]) == {"level": 0.0}
    db.close()


def test_replace_failed_row_and_ok_hashes(tmp_path):
    db = ResultsDB(tmp_path / DB_NAME)
    db.write_job(_job("a"), {"cd": 1.0})
    db.write_job(_job("b", status="failed"))
    assert db.ok_hashes() == {"a"}                      # failed jobs are retried on resume
    db.write_job(_job("b", attempts=2), {"cd": 2.0})    # the retry replaces the failed row
    df = db.frame("jobs")
    assert len(df) == 2 and db.ok_hashes() == {"a", "b"}
    assert df.set_index("config_hash").loc["b", "attempts"] == 2
    db.close()


def test_committed_rows_survive_reopen_and_are_visible_to_readers(tmp_path):
    db = ResultsDB(tmp_path / DB_NAME)
    db.write_job(_job("a"), {"cd": 1.0})
    # another connection (a report reading while the run goes on) sees the committed row at once
    reader = sqlite3.connect(str(tmp_path / DB_NAME))
    assert reader.execute("SELECT count(*) FROM jobs WHERE status='ok'").fetchone()[0] == 1
    reader.close()
    db.conn.close()  # no explicit close/commit beyond write_job
    again = open_run_db(tmp_path, must_exist=True)
    assert again.ok_hashes() == {"a"}
    again.close()


def test_floor_rows(tmp_path):
    db = ResultsDB(tmp_path / DB_NAME)
    db.write_floor({"floor_hash": "f1", "shape": "cube", "status": "ok", "seed": 0}, {"cd": 0.001}, {"metrics_s": 0.5})
    df = db.frame("floor")
    assert df.loc[0, "shape"] == "cube" and df.loc[0, "cd"] == 0.001 and df.loc[0, "metrics_s"] == 0.5
    assert db.ok_hashes("floor") == {"f1"}
    db.close()


def test_bad_rows_and_missing_db(tmp_path):
    db = ResultsDB(tmp_path / DB_NAME)
    with pytest.raises(KeyError):
        db.write_job({"shape": "x"})
    with pytest.raises(KeyError):
        db.write_job({"config_hash": "x", "no_such_fixed_column": 1})
    db.close()
    with pytest.raises(FileNotFoundError, match="no results.db"):
        open_run_db(tmp_path / "elsewhere", must_exist=True)


def test_column_names():
    assert column_name("cd", JOB_SQL) == "cd"
    assert column_name("seed", JOB_SQL) == "metric_seed"
    assert column_name("f1@0.005", JOB_SQL) == "f1_0_005"
    assert column_name("1x", JOB_SQL) == "m_1x"


# -- property-based: any results.db gives tables or one SchemaMismatch line (issue 41, item 2) -------
# tests/loader_fuzz.py: the contract each call is held to; the example counts are the Hypothesis
# profile's (tests/conftest.py). A reader (the reports: open_run_db(..., must_exist=True)) never
# writes: the file is the same bytes after the read, whether it was refused or read.

TABLE_NAMES = ("jobs", "floor", "checkpoints", "components")


def _valid_db(folder) -> bytes:
    """The bytes of a results database as a run leaves it: jobs (ok and failed), a floor row,
    checkpoints, a components row."""
    with ResultsDB(folder / DB_NAME) as db:
        for i in range(6):
            db.write_job(_job(f"h{i}", status="ok" if i % 3 else "failed", shape=f"s{i % 2}"),
                         {"cd": 0.01 * i, "nc": 0.9, "n_faces": 100 + i}, {"fit_s": 1.5, "extract_s": 0.1})
        db.write_floor({"floor_hash": "f", "shape": "s0", "status": "ok", "seed": 0}, {"cd": 0.001})
        db.write_checkpoints("h1", {"shape": "s1", "method": "sdf", "seed": 0},
                             [{"fraction": f, "step": int(f * 100), "fit_elapsed_s": f, "cd": 0.1} for f in (0.5, 1.0)])
        db.write_components("h1", {"shape": "s1", "method": "sdf", "seed": 0}, [{"exact": "sign", "cd": 0.02}])
    return (folder / DB_NAME).read_bytes()


def _read_all(path):
    """What a report reads: every table of the database, through a reader that writes nothing."""
    with open_run_db(path.parent, must_exist=True) as db:
        return {table: db.frame(table) for table in TABLE_NAMES}


def _read_or_refuse(path):
    before = path.read_bytes()
    frames = loads_or_refuses(_read_all, path, SchemaMismatch)
    assert path.read_bytes() == before, "reading changed the database"
    if frames is not None:
        for table, frame in frames.items():
            assert {k for k, c in JOB_SQL.items() if "PRIMARY" in c} <= set(frames["jobs"].columns)
            assert "shape" in frame.columns
    return frames


class _DBDir:
    """A folder for the fuzzed database and the bytes of a valid one (short repr: Hypothesis prints it)."""

    def __init__(self, folder, valid: bytes):
        self.folder, self.valid = folder, valid

    def __repr__(self):
        return f"<db_dir {self.folder}>"


@pytest.fixture(scope="module")
def db_dir(tmp_path_factory):
    return _DBDir(tmp_path_factory.mktemp("db"), _valid_db(tmp_path_factory.mktemp("valid")))


def _db_as(db_dir, data: bytes):
    for old in db_dir.folder.iterdir():
        old.unlink()
    (db_dir.folder / DB_NAME).write_bytes(data)
    return db_dir.folder / DB_NAME


@given(data=st.one_of(st.binary(max_size=2000), st.binary(max_size=200).map(lambda b: b"SQLite format 3\x00" + b)))
def test_any_bytes_as_results_db_are_refused_in_one_line_untouched(db_dir, data):
    """Random bytes (an SQLite header included) are refused by the reader and by the writer (the
    driver's ResultsDB): one line, the file as it was; an empty file is a new database to the writer."""
    path = _db_as(db_dir, data)
    assert _read_or_refuse(path) is None

    def open_writer(p):
        ResultsDB(p).close()
        return True

    if loads_or_refuses(open_writer, path, SchemaMismatch) is None:
        assert path.read_bytes() == data
    else:
        assert data == b""


@given(data=st.data())
def test_a_truncated_results_db_gives_its_tables_or_one_line_untouched(db_dir, data):
    valid = db_dir.valid
    page = 4096
    near_a_page_end = st.tuples(st.integers(1, len(valid) // page), st.integers(-2, 2)).map(lambda t: t[0] * page + t[1])
    cut = data.draw(st.one_of(st.integers(0, len(valid) - 1), near_a_page_end))
    _read_or_refuse(_db_as(db_dir, valid[:max(0, min(cut, len(valid) - 1))]))


#: Changes a foreign tool, an older version or a damaged run may have made to a results database.
EDITS = st.one_of(
    st.tuples(st.sampled_from(TABLE_NAMES), st.sampled_from(["status", "shape", "method", "seed", "cd", "config_hash",
                                                              "floor_hash", "fraction", "exact", "error"])).map(
        lambda t: f'ALTER TABLE "{t[0]}" DROP COLUMN "{t[1]}"'),
    st.tuples(st.sampled_from(TABLE_NAMES), st.sampled_from(["status", "shape", "cd", "seed"])).map(
        lambda t: f'ALTER TABLE "{t[0]}" RENAME COLUMN "{t[1]}" TO "{t[1]}_old"'),
    st.sampled_from(TABLE_NAMES + ("meta",)).map(lambda t: f'DROP TABLE "{t}"'),
    st.one_of(st.text(max_size=5), st.integers(-2**63, 2**63 - 1), st.none()).map(
        lambda v: ("UPDATE meta SET value = ? WHERE key = 'schema_version'", (v,))),
    st.just("DELETE FROM meta"),
    st.tuples(st.sampled_from(["cd", "nc", "n_faces", "seed", "status", "shape", "params", "extra"]),
              st.one_of(st.binary(max_size=8), st.text(max_size=8), st.integers(-2**63, 2**63 - 1), FLOATS,
                        st.none())).map(lambda t: (f'UPDATE jobs SET "{t[0]}" = ?', (t[1],))),
    st.just("CREATE VIEW v AS SELECT 1"), st.just("ALTER TABLE jobs RENAME TO jobs_old"))


@given(edits=st.lists(EDITS, min_size=1, max_size=3))
def test_an_edited_results_db_gives_its_tables_or_one_line_untouched(db_dir, edits):
    """Columns dropped or renamed, tables dropped, the schema version changed or gone, values of any
    type in any column: the tables, or one SchemaMismatch line; the file is not changed by reading."""
    path = _db_as(db_dir, db_dir.valid)
    with sqlite3.connect(path) as con:
        for edit in edits:
            sql, args = edit if isinstance(edit, tuple) else (edit, ())
            try:
                con.execute(sql, args)
            except sqlite3.Error:  # an edit an earlier one made impossible (a column of a dropped table)
                pass
    con.close()
    frames = _read_or_refuse(path)
    if frames is not None:
        assert len(frames["jobs"]) in (0, 6)


@pytest.mark.parametrize("damage", ["random", "truncated", "no status", "version 2", "config.json"])
def test_report_of_a_damaged_run_is_one_line_and_writes_nothing(tmp_path, capsys, damage):
    """`run_benchmark.py report RUN` on a run whose results.db or config.json this version cannot
    read: exit status 2, one line on stderr, nothing written (no results.csv, the db unchanged)."""
    from runner.report_cli import report_main

    run = tmp_path / "run"
    run.mkdir()
    valid = _valid_db(run)
    data = {"random": bytes(range(256)) * 8, "truncated": valid[:5000]}.get(damage, valid)
    (run / DB_NAME).write_bytes(data)
    if damage in ("no status", "version 2"):
        with sqlite3.connect(run / DB_NAME) as con:
            con.execute('ALTER TABLE jobs DROP COLUMN "status"' if damage == "no status"
                        else "UPDATE meta SET value = '2' WHERE key = 'schema_version'")
        con.close()
    (run / "config.json").write_bytes(b"\xff{not json" if damage == "config.json" else b"{}")
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    assert report_main([str(run), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("run_benchmark.py report: error: ")
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before and not (tmp_path / "out").exists()
