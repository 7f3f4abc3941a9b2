"""tasks/blocks.py and tasks/block_store.py: what a block-wise job computes (cloud, scene grid,
blocks, merge) and where its blocks are kept."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from methods.pointcloud.blocks import Block
from tasks.block_store import (CLOUD_FILE, BlockResult, BlockTask, Scene, blocks_folder, other_code_folders,
                               read_blocks, write_block, write_scene)
from tasks.blocks import block_tasks, crop_cloud, scene_of
from tasks.spec import ReconstructJob


def _job(**kw) -> ReconstructJob:
    return ReconstructJob(dataset="rooms", dataset_options={}, shape="a", eval_points=100, metric_preset="default",
                          seed=0, method="poisson", pc_points=100, pc_noise=0.0, **kw)


def test_a_block_wise_job_is_computed_by_its_own_body():
    assert _job().body == "tasks.reconstruct" and _job(pc_blocks=8).body == "tasks.blocks"


def test_crop_cloud_reads_the_box_in_chunks(tmp_path, monkeypatch):
    import tasks.blocks as blocks

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


def test_blocks_are_kept_by_job_and_code(tmp_path):
    """A job's blocks folder is named by its key and its code digest: blocks of other code are
    another folder, found as such, never read as this code's."""
    job = _job(pc_blocks=8)
    today, before = blocks_folder(tmp_path, job, "c0de"), blocks_folder(tmp_path, job, "01d")
    assert today != before and today.name == f"{job.key}_c0de"
    for folder in (today, before, blocks_folder(tmp_path, _job(pc_blocks=4), "01d")):
        folder.mkdir(parents=True)
    assert other_code_folders(tmp_path, job, "c0de") == [before]
    (tmp_path / "blocks" / job.key).mkdir()  # the folder of earlier versions, which named no code
    assert other_code_folders(tmp_path, job, "c0de") == [tmp_path / "blocks" / job.key, before]


def test_blocks_no_point_comes_near_are_stored_empty_without_a_task(tmp_path):
    """A scene grid of 16 points in blocks of 8 (8 blocks), points within 0.1 of its lowest corner:
    a window of --grid 8 points reaches 7 steps (0.93) beyond a block, and the other blocks start
    0.97 away, so the corner's block is the one task and the other 7 are stored empty at once."""
    job = _job(grid=8, pc_blocks=8, pc_scene_grid=16)
    points = np.random.default_rng(0).uniform(-1.0, -0.9, (50, 3))  # near the grid's lowest corner
    np.savez(tmp_path / CLOUD_FILE, points=points)
    write_scene(tmp_path, Scene(16, 1.0, "given"))
    tasks = block_tasks(job, tmp_path)
    stored = sorted(p.stem for p in tmp_path.glob("b*.npz"))
    assert [t.block.name for t in tasks] == ["b0-0-0"] and len(stored) == 7 and "b0-0-0" not in stored
    found, missing = read_blocks(dataclasses.replace(job, blocks_dir=str(tmp_path)))
    assert missing == ["b0-0-0"] and all(len(a["faces"]) == 0 and a["points"] == 0 for _, a in found)
    assert block_tasks(job, tmp_path) == tasks  # the stored ones are not asked for again


def test_the_scene_grid_of_a_learned_method_follows_its_training_density():
    """POCO's rule: a cloud twice as dense as the training clouds gets a grid of 2 (grid - 1) + 1
    points; a method without a network keeps --grid; a given grid is kept."""
    from methods.base import get_method
    from methods.pointcloud.training_set import training_neighbour_distance

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
