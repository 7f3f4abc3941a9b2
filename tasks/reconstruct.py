"""The reconstruct task: a mesh from a raw point cloud (no normals), scored against the GT.

Stages: for a learned method ``network`` (its network, trained once across shapes or loaded:
:mod:`tasks.trained_networks`), ``sample`` (the input point cloud,
:func:`foundation.corruptions.input_point_cloud`, with its sensors for a method that uses them),
``reconstruct`` (``PointCloudMethod.reconstruct``), ``metrics``. A block-wise job (``--pc-blocks``)
has its own body, :mod:`tasks.blocks`, which shares :func:`network_arguments` and :func:`finish`.
"""

from __future__ import annotations

from typing import Callable

from foundation.storage import CacheStats
from foundation.timing import stage
from tasks.context import TaskContext, record_training_overlap, score


def network_arguments(method, spec, device, stats: CacheStats | None = None,
                      progress: Callable[..., None] | None = None) -> tuple[dict, dict]:
    """(keyword arguments, facts): what ``method`` reconstructs with besides the cloud under the job
    ``spec``'s budget. A learned method gets ``model``, its network trained once across shapes
    (cached; facts: :func:`tasks.trained_networks.trained_network`'s); a method that optimises per
    cloud gets its ``budget`` record; a method without a budget gets nothing."""
    if spec.budget is None:
        return {}, {}
    budget = method.budget(spec.budget, spec.budget_params)
    if not method.learned:
        return {"budget": budget}, {}
    from tasks.trained_networks import trained_network

    model, facts = trained_network(method, budget, spec.train_dirs, spec.cache_dir, device, stats=stats,
                                   progress=progress)
    return {"model": model}, facts


def job_network(ctx: TaskContext, method) -> dict:
    """:func:`network_arguments` for the job of ``ctx``, with the network's facts, the training
    overlap of the shape and the cache's hits and refusals in its row."""
    spec, result = ctx.spec, ctx.result
    if spec.budget is None or not method.learned:
        return network_arguments(method, spec, ctx.device)[0]
    from tasks.trained_networks import network_training_record

    ctx.report("training")
    stats = CacheStats()
    with stage("network"):
        network, facts = network_arguments(
            method, spec, ctx.device, stats=stats,
            progress=lambda step, loss, total=None: ctx.report("training", step=step, loss=loss))
    result.info.update(facts)
    record_training_overlap(ctx, network_training_record(method, method.budget(spec.budget, spec.budget_params),
                                                         spec.train_dirs))
    result.cache, result.cache_rejected = list(stats.hits), list(stats.rejected)
    return network


def finish(ctx: TaskContext, extraction) -> None:
    """The job's row from its reconstruction: the extraction's scalar facts, then its scores."""
    ctx.result.info.update({k: v for k, v in extraction.info.items() if isinstance(v, (int, float, str, bool))})
    score(ctx, extraction.vertices, extraction.faces)


def run(ctx: TaskContext) -> None:
    from foundation.corruptions import input_point_cloud
    from methods.base import get_method

    spec, result = ctx.spec, ctx.result
    method = get_method(spec.method, **spec.params)
    network = job_network(ctx, method)
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
    finish(ctx, extraction)
