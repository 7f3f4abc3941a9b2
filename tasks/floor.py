"""The floor task of a shape: its GT scored against an independent resample of itself (the
protocol's noise floor, :func:`foundation.metrics.floor`); it also exports the GT mesh."""

from __future__ import annotations

from tasks.context import TaskContext, score


def run(ctx: TaskContext) -> None:
    from foundation import metrics

    shape = ctx.shape
    ctx.result.shape_info = {"source": str(shape.source), "gt_vertices": int(len(shape.vertices)),
                             "gt_faces": int(len(shape.faces))}
    if not shape.has_gt:  # a point cloud alone: no floor, no gt.ply
        ctx.result.metrics = {"scored": False}
        return
    score(ctx, shape.vertices, shape.faces, lambda V, F, _V, _F, **kw: metrics.floor(V, F, **kw))
