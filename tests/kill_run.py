"""Start ``run_benchmark.py`` in a subprocess and kill it with SIGKILL once some jobs are done
(the durability tests of a plain run and of a sweep)."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def kill_after_ok_jobs(args: list[str], out: Path, env: dict, ok_jobs: int = 1, timeout: float = 180) -> None:
    """Run ``run_benchmark.py ARGS --out OUT`` and SIGKILL it as soon as ``ok_jobs`` jobs are
    committed; fails the test if the run ended before it could be killed."""
    proc = subprocess.Popen([sys.executable, "run_benchmark.py", *args, "--out", str(out)], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    db = out / "results.db"
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if db.is_file():
            try:
                with sqlite3.connect(db, timeout=1) as con:
                    if con.execute("SELECT count(*) FROM jobs WHERE status='ok'").fetchone()[0] >= ok_jobs:
                        break
            except sqlite3.Error:
                pass
        time.sleep(0.02)
    assert proc.poll() is None, f"run ended before it could be killed: {proc.stderr.read().decode()[-500:]}"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
