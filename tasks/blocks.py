"""Block-wise reconstruction (``--pc-blocks B``): everything that computes a block-wise job's result.

A reconstruct job with ``pc_blocks > 0`` is computed in three steps. This module is the job's body
(``spec.body``), so its code and what it imports, the steps the run layer runs before the job
included, are the job's code digest; the run layer (:mod:`runner.blocks`) only schedules the steps
and stores what comes back.

1. **Cloud** (:func:`prepare_cloud`, in the driver): the job's input cloud (the shared sampler's, or
   the scan's, with its sensors) is written once to its blocks folder (``cloud.npz``), its scene
   grid (:func:`scene_of`) to ``scene.json``.
2. **Blocks** (:func:`block_tasks`, then :func:`run_block` per block on the run's executor): one
   :class:`~tasks.block_store.BlockTask` per block of the scene grid that input points come near
   (:mod:`methods.pointcloud.blocks`); the others are stored empty at once. A block reads only its
   crop of the cloud (in chunks, :func:`crop_cloud`), so a worker holds the block's points and
   grid, not the scene's. A method with an edge field (``edge_field``) gives its intersected edges;
   any other method the triangles it owns of its reconstruction of the window of ``grid`` points
   centred on the block. A block whose crop missed points its edges need raises
   :class:`~methods.pointcloud.blocks.HaloTooSmall` with the halo it needs.
3. **Merge** (:func:`run`, the job itself): the blocks' edges through one E-DC, or their pieces
   concatenated (:func:`merged_extraction`), then scored like any reconstruct job. The job's timings
   get ``blocks_s`` (the blocks' seconds, summed) and its info the number of blocks, the slowest
   block's seconds and the largest peak resident memory of a block task (``block_peak_rss_mib``).

Stored blocks are kept in a folder named by the job's key and this code digest
(:func:`tasks.block_store.blocks_folder`): blocks computed by other code are never merged.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from foundation.storage import atomic_write
from foundation.timing import stage
from tasks.block_store import (CLOUD_FILE, SCENE_FILE, BlockResult, BlockTask, BlocksMissing, Scene, read_blocks,
                               read_scene, write_block, write_scene)
from tasks.context import TaskContext
from tasks.load import load_dataset
from tasks.reconstruct import finish, job_network, network_arguments
from tasks.spec import JobSpec

#: Rows of the cloud a block task reads at a time while cropping.
CROP_CHUNK = 1 << 20


def by_edges(method) -> bool:
    """Whether the method's blocks give edges (it has an edge field) rather than mesh pieces."""
    return callable(getattr(method, "edge_field", None))


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


def block_tasks(job: JobSpec, folder: Path) -> list[BlockTask]:
    """The job's block tasks whose result is not stored yet. A block no input point comes near (its
    owned box grown by the first halo, or its window) is stored empty here, without a task."""
    from methods.base import get_method
    from methods.pointcloud.blocks import blocks, occupied_blocks

    scene = read_scene(folder)
    N = scene.grid
    method = get_method(job.method, **job.params)
    edges = by_edges(method)
    halo = (method.params["band"] + 1) * 2.0 / (N - 1) if edges else 0.0
    tasks = [BlockTask(job, b, halo, str(folder), scene.input_scale) for b in blocks(N, job.pc_blocks)]
    tasks = [t for t in tasks if not t.result_path.is_file()]
    if not tasks:
        return []
    with np.load(folder / CLOUD_FILE, mmap_mode="r") as data:
        points = np.asarray(data["points"])
    reach = halo if edges else (job.grid - 1) * 2.0 / (N - 1)  # a window spans grid - 1 steps
    near = set(occupied_blocks(points, N, job.pc_blocks, reach))
    empty = ({"ids": np.zeros(0, np.int64), "s": np.zeros(0, np.float32), "queried": np.int64(0)} if edges
             else {"vertices": np.zeros((0, 3)), "faces": np.zeros((0, 3), np.int64)})
    for t in tasks:
        if t.block not in near:
            write_block(BlockResult(t, "ok", {**empty, "points": np.int64(0)}, 0.0, None))
    return [t for t in tasks if t.block in near]


def run_block(task: BlockTask, device) -> dict[str, np.ndarray]:
    """The arrays of one block's result (module docstring, step 2); raises
    :class:`~methods.pointcloud.blocks.HaloTooSmall` when its crop needs a larger halo."""
    from methods.base import get_method
    from methods.pointcloud.blocks import block_edges, owned_box, window_of, window_piece

    job = task.job
    method = get_method(job.method, **job.params)
    network, _ = network_arguments(method, job, device)
    cloud = Path(task.folder) / CLOUD_FILE
    if by_edges(method):
        points, _ = crop_cloud(cloud, owned_box(task.block), task.halo)
        edges = block_edges(method, points, task.block, task.halo, network["model"], device, task.input_scale)
        arrays = {"ids": edges.ids, "s": edges.s, "queried": np.int64(edges.queried), "points": np.int64(edges.points)}
        if edges.normals is not None:
            arrays["normals"] = edges.normals
        return arrays
    _, box = window_of(task.block, job.grid)
    points, sensors = crop_cloud(cloud, box, 0.0)
    V, F = window_piece(method, points, task.block, job.grid, device, job.seed,
                        sensors if method.uses_sensors else None, **network)
    return {"vertices": V, "faces": F, "points": np.int64(len(points))}


def merged_extraction(job: JobSpec, method):
    """The job's mesh from its stored blocks (module docstring, step 3), with the blocks' facts."""
    from methods.base import Extraction
    from methods.pointcloud.blocks import BlockEdges, merge_edges, merge_pieces

    if job.blocks_dir is None:
        raise BlocksMissing("a block-wise job needs its blocks run first (runner.blocks.run_blocks)")
    found, missing = read_blocks(job)
    if missing:
        raise BlocksMissing(f"{len(missing)} of {len(missing) + len(found)} blocks did not finish "
                            f"(first: {missing[0]}; see the run's log)")
    scene = read_scene(job.blocks_dir)
    N = scene.grid
    if by_edges(method):
        parts = [BlockEdges(b, a["ids"], a["s"], a.get("normals"), int(a["queried"]), int(a["points"]))
                 for b, a in found]
        out = merge_edges(parts, N, qef_cutoff=method.params["qef_cutoff"], faces=method.params["faces"])
    else:
        V, F = merge_pieces((a["vertices"], a["faces"]) for _, a in found)
        out = Extraction(V, F, info={"blocks": len(found)})
    with np.load(Path(job.blocks_dir) / CLOUD_FILE, mmap_mode="r") as cloud:
        out.info.update(input_points=int(cloud["points"].shape[0]), used_sensors=bool(
            method.uses_sensors and "sensors" in cloud.files))
    seconds = [a["meta"]["seconds"] for _, a in found]
    peaks = [a["meta"]["peak_rss_mib"] for _, a in found if a["meta"]["peak_rss_mib"] is not None]
    out.info.update(blocks=len(found), block_points_max=int(max((int(a["points"]) for _, a in found), default=0)),
                    blocks_s=float(sum(seconds)), block_s_max=float(max(seconds, default=0.0)),
                    block_peak_rss_mib=float(max(peaks)) if peaks else float("nan"),
                    scene_grid=N, input_scale=scene.input_scale, scene_rule=scene.rule)
    return out


def run(ctx: TaskContext) -> None:
    """The body of a block-wise job: its network's facts, the merge of its stored blocks, the scores."""
    from methods.base import get_method

    method = get_method(ctx.spec.method, **ctx.spec.params)
    job_network(ctx, method)
    ctx.report("merging blocks")
    with stage("reconstruct"):
        extraction = merged_extraction(ctx.spec, method)
    ctx.timer.add("blocks_s", extraction.info.pop("blocks_s"))
    finish(ctx, extraction)
