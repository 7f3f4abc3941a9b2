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




#: The modules that compute a block-wise Poisson job (its body, the block geometry, the method, the
#: shared reconstruct steps, the stored blocks, the input cloud): an edit to any one of them makes the
#: finished job stale.
BLOCK_COMPUTING = ("tasks/blocks.py", "tasks/block_store.py", "tasks/reconstruct.py", "methods/pointcloud/blocks.py",
                   "methods/pointcloud/poisson.py", "foundation/corruptions.py")
#: Modules of the run layer around it: an edit there re-runs nothing.
BLOCK_SCHEDULING = ("runner/blocks.py", "runner/job.py")
PACKAGES = ("foundation", "datasets", "methods", "reports", "runner", "tasks")


def _copy_of_the_code(copy: Path) -> None:
    import shutil

    for name in PACKAGES:
        shutil.copytree(REPO / name, copy / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "run_benchmark.py", copy / "run_benchmark.py")


def _append_an_unused_function(path: Path) -> str:
    """Append a function nothing calls to ``path``; returns its text before."""
    original = path.read_text()
    path.write_text(original + "\n\ndef an_unused_function():\n    return 'nothing calls this'\n")
    return original


def test_an_edit_to_each_computing_module_changes_a_block_wise_jobs_digest_and_a_scheduling_edit_does_not(tmp_path):
    """Each module of BLOCK_COMPUTING, edited in a copy of the code, changes the code digest a
    block-wise job's row is stored with (so the row is stale); each of BLOCK_SCHEDULING leaves it."""
    from runner.plan import build_tasks, resolve
    from tasks.cache import code_digest, task_code_modules

    _, (job,) = build_tasks(resolve(RunConfig(task="reconstruct", dataset="rooms", limit=1, methods=("poisson",),
                                              grid=24, pc_blocks=16, pc_scene_grid=32, pc_points=4000,
                                              eval_points=20000, no_cache=True, gallery=0)))
    modules = task_code_modules(job)
    _copy_of_the_code(tmp_path)
    before = code_digest(*modules, root=tmp_path)
    assert before == code_digest(*modules)
    for module in (*BLOCK_COMPUTING, *BLOCK_SCHEDULING):
        original = _append_an_unused_function(tmp_path / module)
        code_digest.cache_clear()  # it holds a process's digests: its files do not change while it runs
        after = code_digest(*modules, root=tmp_path)
        (tmp_path / module).write_text(original)
        assert (after != before) == (module in BLOCK_COMPUTING), module


#: The module edited end to end: the method of a block-wise job, and the block scheduler.
COMPUTING_MODULE, SCHEDULING_MODULE = "methods/pointcloud/poisson.py", "runner/blocks.py"


@pytest.mark.slow
def test_an_edit_to_a_module_that_computes_a_block_wise_job_makes_it_stale(tmp_path):
    """A finished block-wise run, then copies of the code with an unused function appended to one
    module: the method's edit refuses the run as stale before any work (exit 2, one line), the block
    scheduler's edit re-runs nothing, and --recompute-stale after the method's edit re-makes every
    block in a new folder and removes the old one. (Every other computing module's edit changes the
    same digest: the test above.)"""
    copy = tmp_path / "copy"
    _copy_of_the_code(copy)
    out = tmp_path / "run"

    def run(*extra):
        return subprocess.run([sys.executable, "run_benchmark.py", *ARGS, "--executor", "local", "--out", str(out),
                               *extra], cwd=copy, capture_output=True, text=True, timeout=600)

    first = run()
    assert first.returncode == 0, first.stderr[-2000:]
    (folder,) = out.glob("blocks/*")
    original = _append_an_unused_function(copy / SCHEDULING_MODULE)
    proc = run()
    (copy / SCHEDULING_MODULE).write_text(original)
    assert proc.returncode == 0 and "(0 run now, 2 done before)" in proc.stderr, proc.stderr[-800:]

    _append_an_unused_function(copy / COMPUTING_MODULE)
    proc = run()
    assert proc.returncode == 2, proc.stderr[-800:]
    (line,) = proc.stderr.strip().splitlines()
    assert "1 finished jobs rows (poisson) were computed by other code than today's" in line, line
    again = run("--recompute-stale")
    assert again.returncode == 0 and "8 blocks to run" in again.stderr, again.stderr[-2000:]
    (new_folder,) = out.glob("blocks/*")
    assert new_folder != folder and new_folder.name.split("_")[0] == folder.name.split("_")[0]
    assert len(list(new_folder.glob("b*.npz"))) == 8
