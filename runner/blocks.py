"""Block-wise reconstruction as tasks: the blocks of a scene on the executor, merged by the job.

A reconstruct job with ``pc_blocks > 0`` (``--pc-blocks B``) is run in three steps:

1. **Cloud** (:func:`prepare_cloud`, in the driver): the job's input cloud (the shared sampler's, or
   the scan's, with its sensors) is written once to ``OUT/blocks/<job key>/cloud.npz``, its scene
   grid to ``scene.json``.
2. **Blocks** (:func:`run_blocks`): one :class:`BlockTask` per block of the scene grid
   (:func:`scene_of`: ``pc_scene_grid`` points per axis when given, else POCO's rule for a
   learned method and ``grid`` for the others; :mod:`methods.pointcloud.blocks`) runs on the
   run's executor (process pool or Ray: one block per task). A task reads only its block's crop of
   the cloud (in chunks), so a worker holds the block's points and the block's grid, not the
   scene's. A method with an edge field (``edge_field``) gives its intersected edges; any other
   method the triangles it owns of its reconstruction of the window of ``grid`` points centred on
   the block. The driver writes each block's result to ``OUT/blocks/<job key>/<block>.npz`` as it
   arrives (atomically): a run killed between blocks keeps them, and the next run computes only
   the missing ones. A block whose crop missed points its edges need comes back with the halo it
   needs and is run again with it.
3. **Merge** (the job itself, :func:`tasks.block_store.merged_extraction`): the blocks' edges through one E-DC, or
   their pieces concatenated, then scored like any job. The job's timings get ``blocks_s`` (the
   blocks' seconds, summed) and its info the number of blocks, the slowest block's seconds and the
   largest peak resident memory of a block task (``block_peak_rss_mib``).

With Ray on several machines, ``OUT`` must be on a file system every node sees.
"""

from __future__ import annotations

import io
import sys
import time
import traceback as _traceback
from dataclasses import replace
from pathlib import Path

import numpy as np

from foundation.storage import atomic_write
from methods.pointcloud.blocks import HaloTooSmall, blocks, owned_box, window_of
from tasks.block_store import (CLOUD_FILE, BlockResult, BlockTask, Scene, blocks_folder, by_edges, read_scene,
                                write_block, write_scene)
from tasks.load import load_dataset
from tasks.spec import JobSpec

#: Rows of the cloud a block task reads at a time while cropping.
CROP_CHUNK = 1 << 20


def scene_of(job: JobSpec, points: np.ndarray) -> Scene:
    """The job's scene grid: ``pc_scene_grid`` when given; else POCO's rule for a learned method (the
    grid on which ``points`` have its training clouds' density,
    :func:`methods.pointcloud.blocks.density_scale`), and ``grid`` for any other method."""
    from methods.base import get_method
    from methods.pointcloud.blocks import density_scale, mean_neighbour_distance

    if job.pc_scene_grid:
        n = job.pc_scene_grid
        return Scene(n, (n - 1) / (job.grid - 1), "given (--pc-scene-grid)")
    method = get_method(job.method, **job.params)
    if not (method.learned and job.budget is not None):
        return Scene(job.grid, 1.0, "the method's grid (--grid)")
    from methods.pointcloud.training_set import training_neighbour_distance

    reference = training_neighbour_distance(method.training_cloud_points(method.budget(job.budget, job.budget_params)))
    n, scale = density_scale(points, reference, job.grid)
    return Scene(n, scale, "training density (POCO's rule)", mean_neighbour_distance(points), reference)


def prepare_cloud(job: JobSpec, folder: Path) -> None:
    """Write the job's input cloud (and sensors) to ``folder/cloud.npz`` and its scene grid
    (:func:`scene_of`) to ``folder/scene.json``, unless they are there."""
    from tasks.block_store import SCENE_FILE
    from foundation.corruptions import input_point_cloud

    path = folder / CLOUD_FILE
    if path.is_file() and (folder / SCENE_FILE).is_file():
        return
    shape = load_dataset(job.dataset, job.dataset_options).load(job.shape)
    points, sensors = input_point_cloud(shape, job.pc_points, job.pc_noise, job.seed, job.pc_corruption)
    arrays = {"points": points} if sensors is None else {"points": points, "sensors": np.asarray(sensors)}
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write(path, buffer.getvalue())
    write_scene(folder, scene_of(job, points))


def crop_cloud(path: Path, box: tuple[np.ndarray, np.ndarray], halo: float) -> tuple[np.ndarray, np.ndarray | None]:
    """(points, sensors or None) of the cloud file inside ``box`` grown by ``halo``, read in chunks
    of :data:`CROP_CHUNK` rows (memory-mapped: the whole cloud is never in memory)."""
    with np.load(path, mmap_mode="r") as data:
        points = data["points"]
        sensors = data["sensors"] if "sensors" in data.files else None
        lo, hi = box[0] - halo, box[1] + halo
        rows = [start + np.flatnonzero(np.all((chunk >= lo) & (chunk <= hi), axis=1))
                for start in range(0, len(points), CROP_CHUNK)
                for chunk in (np.asarray(points[start:start + CROP_CHUNK]),)]
        rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        return np.asarray(points[rows]), None if sensors is None else np.asarray(sensors[rows])


def _reset_peak_rss() -> None:
    """Start a new peak of resident memory for this process (Linux: /proc/self/clear_refs)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _peak_rss_mib() -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def run_block_task(task: BlockTask, progress=None) -> BlockResult:
    """Run one block (never raises: a failure is a failed result with one line)."""
    from methods.base import get_method
    from methods.core.device import get_device
    from runner.config import import_plugins
    from runner.job import one_line
    from runner.memory import memory_limit

    job = task.job
    result = BlockResult(task)
    _reset_peak_rss()
    t0 = time.perf_counter()
    stage = "loading"
    try:
        with memory_limit(job.worker_memory):
            import_plugins(job.plugins)
            if job.threads:
                import torch

                torch.set_num_threads(int(job.threads))
            device = get_device(job.device)
            method = get_method(job.method, **job.params)
            network = {}
            if job.budget is not None and method.learned:
                from tasks.trained_networks import trained_network

                stage = "network"
                network["model"], _ = trained_network(method, method.budget(job.budget, job.budget_params),
                                                      job.train_dirs, job.cache_dir, device)
            elif job.budget is not None:
                network["budget"] = method.budget(job.budget, job.budget_params)
            stage = "block"
            cloud = Path(task.folder) / CLOUD_FILE
            if by_edges(method):
                from methods.pointcloud.blocks import block_edges

                points, _ = crop_cloud(cloud, owned_box(task.block), task.halo)
                edges = block_edges(method, points, task.block, task.halo, network["model"], device, task.input_scale)
                result.arrays = {"ids": edges.ids, "s": edges.s, "queried": np.int64(edges.queried),
                                 "points": np.int64(edges.points)}
                if edges.normals is not None:
                    result.arrays["normals"] = edges.normals
            else:
                from methods.pointcloud.blocks import window_piece

                _, box = window_of(task.block, job.grid)
                points, sensors = crop_cloud(cloud, box, 0.0)
                V, F = window_piece(method, points, task.block, job.grid, device, job.seed,
                                    sensors if method.uses_sensors else None, **network)
                result.arrays = {"vertices": V, "faces": F, "points": np.int64(len(points))}
            result.status = "ok"
    except HaloTooSmall as exc:
        result.status, result.needed_halo = "halo", exc.radius
    except Exception as exc:  # noqa: BLE001 -- a failed block fails its job, not the run
        result.error, result.traceback = one_line(exc, stage), _traceback.format_exc()
    result.seconds = time.perf_counter() - t0
    result.peak_rss_mib = _peak_rss_mib()
    return result


def block_tasks(job: JobSpec, folder: Path) -> list[BlockTask]:
    """The job's block tasks whose result is not stored yet. A block no input point comes near (its
    owned box grown by the first halo, or its window) is stored empty here, without a task."""
    from methods.base import get_method
    from methods.pointcloud.blocks import occupied_blocks

    scene = read_scene(folder)
    N = scene.grid
    method = get_method(job.method, **job.params)
    halo = (method.params["band"] + 1) * 2.0 / (N - 1) if by_edges(method) else 0.0
    tasks = [BlockTask(job, b, halo, str(folder), scene.input_scale) for b in blocks(N, job.pc_blocks)]
    tasks = [t for t in tasks if not t.result_path.is_file()]
    if not tasks:
        return []
    with np.load(folder / CLOUD_FILE, mmap_mode="r") as data:
        points = np.asarray(data["points"])
    reach = halo if by_edges(method) else (job.grid - 1) * 2.0 / (N - 1)  # a window spans grid - 1 steps
    near = set(occupied_blocks(points, N, job.pc_blocks, reach))
    for t in tasks:
        if t.block not in near:
            empty = ({"ids": np.zeros(0, np.int64), "s": np.zeros(0, np.float32), "queried": np.int64(0)}
                     if by_edges(method) else {"vertices": np.zeros((0, 3)), "faces": np.zeros((0, 3), np.int64)})
            write_block(BlockResult(t, "ok", {**empty, "points": np.int64(0)}, 0.0, None))
    return [t for t in tasks if t.block in near]


def run_blocks(jobs: list[JobSpec], run_dir: Path, executor) -> list[JobSpec]:
    """Run the missing blocks of the block-wise ``jobs`` on ``executor`` (module docstring); returns
    the jobs with their ``blocks_dir`` set. A job whose cloud cannot be made is returned as is: it
    fails in its own task with that reason."""
    ready, tasks = [], []
    for job in jobs:
        folder = blocks_folder(run_dir, job)
        try:
            prepare_cloud(job, folder)
            tasks += block_tasks(job, folder)
        except Exception as exc:  # noqa: BLE001 -- the job reports it when it runs
            print(f"salsbench: {job.label}: no blocks ({type(exc).__name__}: {exc})", file=sys.stderr, flush=True)
        ready.append(replace(job, blocks_dir=str(folder)))
    rounds = 0
    while tasks:
        rounds += 1
        print(f"salsbench: {len(tasks)} blocks to run (round {rounds})", file=sys.stderr, flush=True)
        again = []
        for task, outcome in executor.run(run_block_task, tasks):
            if isinstance(outcome, BaseException):
                print(f"salsbench: {task.label}: worker lost ({type(outcome).__name__}: {outcome})",
                      file=sys.stderr, flush=True)
            elif outcome.status == "ok":
                write_block(outcome)
            elif outcome.status == "halo":
                again.append(replace(task, halo=max(outcome.needed_halo, 2.0 * task.halo)))
            else:
                print(f"salsbench: {task.label}: {outcome.error}", file=sys.stderr, flush=True)
        tasks = again
    return ready


