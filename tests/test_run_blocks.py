"""runner/blocks.py: the blocks of a scene as executor tasks, stored as they finish, merged by the job."""

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

from tasks.block_store import CLOUD_FILE, BlockResult, BlockTask, Scene, write_block, write_scene
from runner.blocks import crop_cloud
from runner.config import ConfigError, RunConfig
from tasks.spec import ReconstructJob
from methods.pointcloud.blocks import Block

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


def test_crop_cloud_reads_the_box_in_chunks(tmp_path, monkeypatch):
    import runner.blocks as blocks

    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (1000, 3))
    np.savez(tmp_path / CLOUD_FILE, points=points, sensors=points + 5)
    monkeypatch.setattr(blocks, "CROP_CHUNK", 64)
    box = (np.array([-0.5, -0.5, -0.5]), np.array([0.0, 0.5, 0.5]))
    got, sensors = crop_cloud(tmp_path / CLOUD_FILE, box, 0.1)
    inside = np.all((points >= box[0] - 0.1) & (points <= box[1] + 0.1), axis=1)
    np.testing.assert_array_equal(got, points[inside])
    np.testing.assert_array_equal(sensors, points[inside] + 5)


def test_a_stored_block_round_trips(tmp_path):
    from tasks.block_store import read_blocks

    job = _job(grid=8, pc_blocks=8, blocks_dir=str(tmp_path))
    write_scene(tmp_path, Scene(8, 1.0, "given"))
    task = BlockTask(job, Block(8, (0, 0, 0), (8, 8, 8)), 0.0, str(tmp_path))
    faces = np.array([[0, 1, 2]])
    write_block(BlockResult(task, "ok", {"vertices": np.eye(3), "faces": faces, "points": np.int64(3)}, 1.5, 200.0))
    found, missing = read_blocks(job)
    assert missing == [] and len(found) == 1
    block, arrays = found[0]
    assert block == task.block and arrays["meta"]["seconds"] == 1.5 and arrays["meta"]["peak_rss_mib"] == 200.0
    np.testing.assert_array_equal(arrays["faces"], faces)


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


def test_the_scene_grid_of_a_learned_method_follows_its_training_density():
    """POCO's rule: a cloud twice as dense as the training clouds gets a grid of 2 (grid - 1) + 1
    points; a method without a network keeps --grid; a given grid is kept."""
    from methods.base import get_method
    from methods.pointcloud.training_set import training_neighbour_distance
    from runner.blocks import scene_of

    job = dataclasses.replace(_job(grid=33, pc_blocks=8), method="sals-knn", budget="tiny")
    method = get_method("sals-knn")
    reference = training_neighbour_distance(method.training_cloud_points(method.budget("tiny")))
    spacing = reference / 2
    lattice = spacing * np.stack(np.meshgrid(np.arange(60.0), np.arange(60.0), [0.0], indexing="ij"), -1).reshape(-1, 3)
    scene = scene_of(job, lattice)
    assert (scene.grid, scene.input_scale) == (65, 2.0)
    assert scene.cloud_neighbour_distance == pytest.approx(spacing) and scene.training_neighbour_distance == reference
    assert scene_of(_job(grid=33, pc_blocks=8), lattice).grid == 33  # poisson: its own grid
    assert scene_of(_job(grid=33, pc_blocks=8, pc_scene_grid=40), lattice).grid == 40
