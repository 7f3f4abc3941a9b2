"""Durability: kill -9 during a run, resume twice, then resume with a changed flag. The
table equals an uninterrupted run's, finished jobs are never recomputed, the changed flag is refused."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from tests.fake_methods import PLUGIN
from tests.kill_run import kill_after_ok_jobs

REPO = Path(__file__).resolve().parents[1]
METRICS = ["shape", "method", "seed", "status", "cd", "nc", "f1_005", "f1_01", "ecd", "ef1", "n_vertices", "n_faces"]


def _run(args, cache, **kw):
    return subprocess.run([sys.executable, "run_benchmark.py", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "SALSBENCH_CACHE": str(cache)}, **kw)


@pytest.mark.slow
def test_kill9_resume_twice_then_a_changed_flag_is_refused(tmp_path):
    cache = tmp_path / "cache"
    args = ["--methods", "test_sdf", "test_occ", "--mode", "oracle", "--grid", "24", "--eval-points", "5000",
            "--seed", "0", "1", "2", "--no-cache", "--plugin", PLUGIN, "--quiet", "--executor", "local", "--gallery", "0"]
    killed = tmp_path / "killed"
    kill_after_ok_jobs(args, killed, {**os.environ, "SALSBENCH_CACHE": str(cache)})
    db = killed / "results.db"
    with sqlite3.connect(db) as con:
        before = dict(con.execute("SELECT config_hash, finished FROM jobs WHERE status='ok'").fetchall())
    assert 1 <= len(before) < 24                        # 4 shapes x 2 methods x 3 seeds in all
    assert not (killed / "results.csv").exists()         # the kill came before the end

    first = _run(["--resume", "--out", str(killed)], cache)     # the lock died with the killed process
    assert first.returncode == 0, first.stderr[-2000:]
    second = _run(["--resume", "--out", str(killed)], cache)
    assert second.returncode == 0, second.stderr[-2000:]
    assert "28 ok, 0 failed (0 run now, 28 done before)" in second.stderr  # 24 jobs + 4 floors, nothing rerun
    with sqlite3.connect(db) as con:
        after = dict(con.execute("SELECT config_hash, finished FROM jobs").fetchall())
    assert len(after) == 24 and all(after[h] == t for h, t in before.items())  # finished jobs never recomputed

    changed = _run(["--resume", "--out", str(killed), "--grid", "32"], cache)
    assert changed.returncode == 2 and "grid=24 there, 32 now" in changed.stderr
    assert len(changed.stderr.strip().splitlines()) == 1

    straight = tmp_path / "straight"
    assert _run([*args, "--out", str(straight)], cache).returncode == 0
    pd.testing.assert_frame_equal(pd.read_csv(killed / "results.csv")[METRICS],
                                  pd.read_csv(straight / "results.csv")[METRICS])
