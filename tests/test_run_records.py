"""The results database (runner.records): schema, round trips, replacement, WAL, readers."""

from __future__ import annotations

import json
import math
import sqlite3

import numpy as np
import pytest

from runner.records import DB_NAME, JOB_COLUMNS, ResultsDB, column_name, open_run_db


def _job(hash_, status="ok", **kw):
    row = {"config_hash": hash_, "shape": "cube", "method": "sdf", "mode": "oracle", "seed": 0, "status": status,
           "error": None if status == "ok" else "extracting: RuntimeError: boom", "params": {"level": 0.0},
           "grid": 32, "finished": "2025-01-01T00:00:00.000+00:00"}
    row.update(kw)
    return row


def test_schema_created_with_wal(tmp_path):
    db = ResultsDB(tmp_path / DB_NAME)
    assert set(JOB_COLUMNS) <= set(db.columns("jobs"))
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
    assert column_name("cd", JOB_COLUMNS) == "cd"
    assert column_name("seed", JOB_COLUMNS) == "metric_seed"
    assert column_name("f1@0.005", JOB_COLUMNS) == "f1_0_005"
    assert column_name("1x", JOB_COLUMNS) == "m_1x"
