"""What a task's body works with: the :class:`TaskContext` (spec, shape, device, timer, result,
progress) it receives and the :class:`TaskResult` it fills, and the steps every task shares:
scoring a mesh against the shape's GT (:func:`score`) and recording whether the shape was in the
training set of the weights a method used (:func:`record_training_overlap`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from foundation.timing import StageTimer, record, stage


@dataclass
class TaskResult:
    """What a task returns to the driver (picklable; the mesh travels as PLY bytes).

    status : 'ok' or 'failed'; error : one line; metrics : ``evaluate``'s result (raw units);
    timings : ``<stage>_s`` seconds; cache : cache kinds served; cache_rejected : damaged entries
    recomputed; info : scalar facts (fit steps, samples/s, query fraction, intersected edges, ...);
    checkpoints : one dict per checkpoint of the fit (fraction, step, fit_elapsed_s, metrics, timings).
    components : one dict per decomposition variant (exact, metrics, extract_s).
    """

    kind: str
    key: str
    spec: Any
    status: str = "failed"
    error: str | None = None
    traceback: str | None = None
    metrics: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    fit_loss: float | None = None
    shape_hash: str | None = None
    shape_kind: str | None = None
    shape_info: dict = field(default_factory=dict)
    mesh_ply: bytes | None = None
    cache: list = field(default_factory=list)
    cache_rejected: list = field(default_factory=list)
    checkpoints: list = field(default_factory=list)
    components: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
    device: str | None = None
    host: str | None = None
    versions: dict = field(default_factory=dict)
    started: str | None = None
    finished: str | None = None
    attempts: int = 1

    @property
    def ok(self) -> bool:
        return self.status == "ok"


class Progress:
    """The current stage for error messages, forwarded to the executor's progress callback."""

    def __init__(self, callback: Callable | None):
        self.callback = callback
        self.stage = "starting"

    def __call__(self, stage_name: str, **info) -> None:
        self.stage = stage_name
        if self.callback is not None:
            try:
                self.callback(stage_name, **info)
            except Exception:  # noqa: BLE001 -- a progress display must never fail a job
                pass


@dataclass
class TaskContext:
    """One running task: its spec, the loaded shape, the torch device, the stage timer (active
    while the body runs), the result being filled and the progress reporter."""

    spec: Any
    shape: Any
    device: Any
    timer: StageTimer
    result: TaskResult
    report: Progress

    def metric_seed(self):
        """The job's metric stream (:func:`foundation.seeding.job_streams`)."""
        from foundation.seeding import job_streams

        return job_streams(self.shape.content_hash, self.spec.seed).metrics


def mesh_to_ply(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary PLY bytes of a triangle mesh (no processing, no merging)."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64),
                           process=False, validate=False)
    return mesh.export(file_type="ply", encoding="binary")


def scores(ctx: TaskContext, vertices, faces, scorer: Callable | None = None) -> dict:
    """The metrics of a mesh against the shape's GT with the job's metric protocol and stream
    (``scorer``: :func:`foundation.metrics.evaluate`, the default, or ``floor``); the metrics'
    own stages are recorded under the enclosing stage (``<stage>_<step>_s``)."""
    from foundation import metrics

    spec, shape = ctx.spec, ctx.shape
    result = (scorer or metrics.evaluate)(shape.vertices, shape.faces, vertices, faces, preset=spec.metric_preset,
                                          seed=ctx.metric_seed(), n_points=spec.eval_points,
                                          metres_per_unit=shape.meta.get("metres_per_unit"))
    for key, seconds in result.pop("seconds", {}).items():
        if key != "total_s":
            record(key.removesuffix("_s"), seconds)
    return result


def score(ctx: TaskContext, vertices, faces, scorer: Callable | None = None) -> None:
    """The job's result mesh scored (:func:`scores`, in the stage ``metrics``; a shape without a GT
    gets the prediction's validity counts only, ``metrics.evaluate_without_gt``) and kept as PLY."""
    from foundation.metrics import evaluate_without_gt

    ctx.report("scoring")
    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    with stage("metrics"):
        if ctx.shape.has_gt:
            ctx.result.metrics = scores(ctx, vertices, faces, scorer)
        else:
            ctx.result.metrics = evaluate_without_gt(vertices, faces)
            ctx.result.metrics.pop("seconds", None)
    ctx.report("saving")
    ctx.result.mesh_ply = mesh_to_ply(vertices, faces)


def record_training_overlap(ctx: TaskContext, training_record) -> None:
    """Whether the shape was in the training set of the weights the method used (``training_record``:
    :class:`methods.core.training_record.TrainingRecord`, None for a method without trained
    weights), in the job's info as ``seen_in_training`` (True, False, or None: unknown) and
    ``training_record`` (what the weights were trained on)."""
    if training_record is None:
        return
    ctx.result.info["seen_in_training"] = training_record.saw(ctx.shape.name, ctx.shape.content_hash)
    ctx.result.info["training_record"] = training_record.description
