"""The reconstruct task: a mesh from a raw point cloud (no normals), scored against the GT.

Stages: for a learned method ``network`` (its network, trained once across shapes or loaded:
:mod:`tasks.trained_networks`), ``sample`` (the input point cloud,
:func:`foundation.corruptions.input_point_cloud`, with its sensors for a method that uses them),
``reconstruct`` (``PointCloudMethod.reconstruct``; for a block-wise job the merge of its blocks,
:mod:`tasks.block_store`), ``metrics``.
"""

from __future__ import annotations

from foundation.storage import CacheStats
from foundation.timing import stage
from tasks.context import TaskContext, record_training_overlap, score


def run(ctx: TaskContext) -> None:
    from foundation.corruptions import input_point_cloud
    from methods.base import get_method

    spec, result = ctx.spec, ctx.result
    method = get_method(spec.method, **spec.params)
    network = {}
    budget = method.budget(spec.budget, spec.budget_params) if spec.budget is not None else None
    if budget is not None and not method.learned:  # a per-shape optimisation under its own budget
        network["budget"] = budget
    if budget is not None and method.learned:  # its network, trained once across shapes (cached)
        from tasks.trained_networks import network_training_record, trained_network

        ctx.report("training")
        stats = CacheStats()
        with stage("network"):
            network["model"], facts = trained_network(
                method, budget, spec.train_dirs, spec.cache_dir, ctx.device, stats=stats,
                progress=lambda step, loss, total=None: ctx.report("training", step=step, loss=loss))
        result.info.update(facts)
        record_training_overlap(ctx, network_training_record(method, budget, spec.train_dirs))
        result.cache, result.cache_rejected = list(stats.hits), list(stats.rejected)
    if spec.pc_blocks:
        from tasks.block_store import merged_extraction

        ctx.report("merging blocks")
        with stage("reconstruct"):
            extraction = merged_extraction(spec, method)
        ctx.timer.add("blocks_s", extraction.info.pop("blocks_s"))
    else:
        ctx.report("sampling")
        with stage("sample"):
            points, sensors = input_point_cloud(ctx.shape, spec.pc_points, spec.pc_noise, spec.seed, spec.pc_corruption)
        result.info["input_points"] = int(len(points))
        if method.uses_sensors and sensors is not None:
            network["sensors"] = sensors
        result.info["used_sensors"] = "sensors" in network
        ctx.report("reconstructing")
        with stage("reconstruct"):
            extraction = method.reconstruct(points, spec.grid, ctx.device, seed=spec.seed, **network)
    result.info.update({k: v for k, v in extraction.info.items() if isinstance(v, (int, float, str, bool))})
    score(ctx, extraction.vertices, extraction.faces)
