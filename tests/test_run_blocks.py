"""runner/blocks.py: the blocks of a scene as executor tasks, stored as they finish, merged by the job,
and kept only while the code that computed them is today's."""

from __future__ import annotations

import dataclasses
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tasks.block_store import CLOUD_FILE
from runner.config import ConfigError, RunConfig
from tasks.spec import ReconstructJob

REPO = Path(__file__).resolve().parents[1]
ARGS = ["--task", "reconstruct", "--dataset", "rooms", "--limit", "1", "--methods", "poisson", "--grid", "24",
        "--pc-blocks", "16", "--pc-scene-grid", "32", "--pc-points", "4000", "--eval-points", "20000",
        "--quiet", "--gallery", "0", "--no-cache"]
POOL = ["--executor", "process", "--workers", "2"]


def _run(args, out: Path, **kw):
    return subprocess.run([sys.executable, "run_benchmark.py", *args, "--out", str(out)], cwd=REPO,
                          capture_output=True, text=True, timeout=600, **kw)


def test_block_settings_are_checked():
    with pytest.raises(ConfigError, match="--pc-blocks applies to --task reconstruct, not to --task encode"):
        RunConfig(pc_blocks=8)
    with pytest.raises(ConfigError, match="give --pc-blocks too"):
        RunConfig(task="reconstruct", pc_scene_grid=256)
    with pytest.raises(ConfigError, match="at least 2 points"):
        RunConfig(task="reconstruct", pc_blocks=8, pc_scene_grid=1)


def _job(**kw) -> ReconstructJob:
    return ReconstructJob(dataset="rooms", dataset_options={}, shape="a", eval_points=100, metric_preset="default",
                          seed=0, method="poisson", pc_points=100, pc_noise=0.0, **kw)


def test_a_block_wise_job_has_its_own_key():
    assert _job().key != _job(pc_blocks=8).key != _job(pc_blocks=8, pc_scene_grid=256).key
    assert _job(pc_blocks=8, blocks_dir="/x").key == _job(pc_blocks=8).key  # where the blocks are is no identity


@pytest.mark.slow
def test_a_killed_block_wise_run_resumes_without_recomputing_finished_blocks(tmp_path):
    """Kill -9 once 3 of the 8 blocks are stored; the rerun runs only the others and keeps the stored files;
    the merged mesh is the one the same windows give in one process."""
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "run_benchmark.py", *ARGS, *POOL, "--out", str(killed)], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300
    stored: list[Path] = []
    while time.monotonic() < deadline and proc.poll() is None:
        stored = [p for p in killed.glob("blocks/*/b*.npz")]
        if len(stored) >= 3:
            break
        time.sleep(0.02)
    assert proc.poll() is None, f"run ended before it could be killed: {proc.stderr.read().decode()[-800:]}"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    before = {p: p.stat().st_mtime_ns for p in killed.glob("blocks/*/b*.npz")}
    assert 3 <= len(before) < 8  # scene grid 32 in blocks of 16: 2^3 blocks

    resumed = _run(["--resume"], killed)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert f"{8 - len(before)} blocks to run" in resumed.stderr
    assert all(p.stat().st_mtime_ns == t for p, t in before.items())  # finished blocks never recomputed
    assert len(list(killed.glob("blocks/*/b*.npz"))) == 8

    with sqlite3.connect(killed / "results.db") as con:
        status, n_faces, info = con.execute("SELECT status, n_faces, info FROM jobs").fetchone()
    assert status == "ok" and '"blocks": 8' in info and '"block_peak_rss_mib"' in info
    # the merged mesh is the one the windows give in one process from the same stored cloud
    from methods.base import get_method
    from methods.pointcloud.blocks import reconstruct_by_windows

    (cloud,) = killed.glob(f"blocks/*/{CLOUD_FILE}")
    with np.load(cloud) as data:
        points = data["points"]
    assert n_faces == len(reconstruct_by_windows(get_method("poisson"), points, 32, 16, 24).faces) > 0




#: A module that computes a block-wise Poisson job (the method): an edit makes the finished job stale.
#: That every module such a job runs is inside its digest is the code probe's test
#: (tests/test_tasks_code_probe.py); this one checks what a stale job does, end to end.
COMPUTING_MODULE = "methods/pointcloud/poisson.py"
#: A module of the run layer around it: an edit there re-runs nothing.
SCHEDULING_MODULE = "runner/blocks.py"


@pytest.mark.slow
def test_an_edit_to_a_module_that_computes_a_block_wise_job_makes_it_stale(tmp_path):
    """A finished block-wise run, then copies of the code with an unused function appended to one
    module: the method's edit refuses the run as stale before any work (exit 2, one line), the block
    scheduler's edit re-runs nothing, and --recompute-stale after the method's edit re-makes every
    block in a new folder and removes the old one."""
    import shutil

    copy = tmp_path / "copy"
    for name in ("foundation", "datasets", "methods", "reports", "runner", "tasks"):
        shutil.copytree(REPO / name, copy / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "run_benchmark.py", copy / "run_benchmark.py")
    out = tmp_path / "run"

    def run(*extra):
        return subprocess.run([sys.executable, "run_benchmark.py", *ARGS, "--executor", "local", "--out", str(out),
                               *extra], cwd=copy, capture_output=True, text=True, timeout=600)

    def edit(module):
        path = copy / module
        original = path.read_text()
        path.write_text(original + "\n\ndef an_unused_function():\n    return 'nothing calls this'\n")
        return path, original

    first = run()
    assert first.returncode == 0, first.stderr[-2000:]
    (folder,) = out.glob("blocks/*")
    path, original = edit(SCHEDULING_MODULE)
    proc = run()
    path.write_text(original)
    assert proc.returncode == 0 and "(0 run now, 2 done before)" in proc.stderr, proc.stderr[-800:]

    edit(COMPUTING_MODULE)
    proc = run()
    assert proc.returncode == 2, proc.stderr[-800:]
    (line,) = proc.stderr.strip().splitlines()
    assert "1 finished jobs rows (poisson) were computed by other code than today's" in line, line
    again = run("--recompute-stale")
    assert again.returncode == 0 and "8 blocks to run" in again.stderr, again.stderr[-2000:]
    (new_folder,) = out.glob("blocks/*")
    assert new_folder != folder and new_folder.name.split("_")[0] == folder.name.split("_")[0]
    assert len(list(new_folder.glob("b*.npz"))) == 8
