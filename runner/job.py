"""THE job function: one (shape, method, seed) job, and the floor task of a shape.

:func:`run_task` is what every executor calls. It never raises: any exception becomes a failed
:class:`TaskResult` with a one-line error (``stage: Type: message``) and the traceback in its own
field. It never branches on method names: everything method-specific goes through the
:class:`methods.base.Method` interface.

Stages of a job (each timed by :class:`benchmark.timing.StageTimer` as ``<stage>_s``): ``load`` the
shape; neural mode: ``sample`` (the shared sampler), ``label`` (``method.training_targets`` on the
exact fields), ``fit`` (``methods.core.fitting.fit``, or cached weights), ``query`` (``method.neural_grid``);
oracle mode: ``query`` (``method.oracle_grid`` on the exact fields); then ``extract``
(``method.extract``) and ``metrics`` (``benchmark.metrics.evaluate`` against the GT). A job of the
``reconstruct`` task: ``load``, for a learned method ``network`` (its network, trained once across
shapes or loaded: :mod:`runner.training`), ``sample`` (the input point cloud,
:func:`input_point_cloud`, with its sensors for a method that uses them), ``reconstruct`` (``PointCloudMethod.reconstruct``), ``metrics``. Randomness comes from
:func:`benchmark.seeding.job_streams` of (shape content hash, seed).
"""

from __future__ import annotations

import datetime as _dt
import socket
import time
import traceback as _traceback
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from runner.memory import memory_limit, out_of_memory
from runner.tasks import FloorSpec, JobSpec, digest, load_dataset
from benchmark.storage import CacheStats
from benchmark.timing import StageTimer, stage


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


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def one_line(exc: BaseException, stage_name: str | None = None) -> str:
    """``stage: Type: first line of message`` (at most 400 characters)."""
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    text = f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
    if stage_name:
        text = f"{stage_name}: {text}"
    return text if len(text) <= 400 else text[:397] + "..."


def mesh_to_ply(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary PLY bytes of a triangle mesh (no processing, no merging)."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64),
                           process=False, validate=False)
    return mesh.export(file_type="ply", encoding="binary")


def failed_from_exception(spec, exc: BaseException, attempts: int = 1) -> TaskResult:
    """A failed result for a task whose worker died or whose result never came back."""
    return TaskResult(kind=spec.kind, key=spec.key, spec=spec, error=one_line(exc, "worker"),
                      traceback="".join(_traceback.format_exception(exc)), finished=now_iso(), attempts=attempts)


class _Progress:
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


def timer_sync(device) -> Callable[[], None]:
    """What a stage timer calls before reading the clock: wait for queued CUDA work."""
    from methods.core.device import synchronize

    return lambda: synchronize(device)


def _run(spec, progress: Callable | None, body: Callable) -> TaskResult:
    """Common frame of a task: result, timer, worker set-up, failure capture."""
    from runner.config import import_plugins
    from runner.provenance import package_versions
    from methods.core.device import describe_device, get_device

    result = TaskResult(kind=spec.kind, key=spec.key, spec=spec, started=now_iso(), host=socket.gethostname())
    report = _Progress(progress)
    timer = StageTimer()
    t0 = time.perf_counter()
    try:
        with timer.active(), memory_limit(spec.worker_memory):
            report("loading")
            import_plugins(spec.plugins)
            if spec.threads:
                import torch

                torch.set_num_threads(int(spec.threads))
            result.versions = package_versions()
            device = get_device(spec.device if spec.kind == "job" else None)
            timer.sync = timer_sync(device)
            result.device = describe_device(device)
            with stage("load"):
                dataset = load_dataset(spec.dataset, spec.dataset_options)
                check_stored_size(dataset.stored_files(spec.shape), spec.max_faces, spec.max_points)
                shape = dataset.load(spec.shape)
                check_size(shape, spec.max_faces, spec.max_points)
            result.shape_hash, result.shape_kind = shape.content_hash, shape.kind
            body(spec, shape, device, timer, result, report)
            result.status = "ok"
    except Exception as exc:  # noqa: BLE001 -- every failure becomes a failed row, the run goes on
        result.status = "failed"
        result.error = one_line(exc, report.stage)
        if out_of_memory(exc):
            limit = f" of --worker-memory {spec.worker_memory:g} GiB" if spec.worker_memory else ""
            result.error = one_line(exc, f"{report.stage}: out of memory (past the limit{limit})" if limit
                                    else f"{report.stage}: out of memory")
        result.traceback = _traceback.format_exc()
    timer.add("total_s", time.perf_counter() - t0)
    result.timings = dict(timer.seconds)
    result.finished = now_iso()
    return result


class ShapeTooLarge(ValueError):
    """A shape over the run's size limits (``--max-faces``, ``--max-points``); one line naming its file."""


def check_stored_size(files, max_faces: int | None, max_points: int | None) -> None:
    """Raise :class:`ShapeTooLarge` when one of ``files`` ((path, 'mesh' or 'cloud') pairs:
    ``Dataset.stored_files``) stores more faces (a mesh) or points (a cloud) than the limits, as its
    header or a bounded-memory count says (:func:`datasets.stored_size.stored_count`), before it
    is read. None: no limit."""
    from datasets.stored_size import stored_count

    for path, holds in files:
        what, limit, flag = ("faces", max_faces, "--max-faces") if holds == "mesh" else ("points", max_points,
                                                                                           "--max-points")
        count = stored_count(path, what) if limit is not None else None
        if count is not None and count > limit:
            raise ShapeTooLarge(f"{path}: stores {count:,} {what}, over the limit of {limit:,} ({flag}); not read")


def check_size(shape, max_faces: int | None, max_points: int | None) -> None:
    """Raise :class:`ShapeTooLarge` when ``shape`` has more faces than ``max_faces`` or more input
    points than ``max_points`` (None: no limit)."""
    where = shape.source or shape.name
    if max_faces is not None and len(shape.faces) > max_faces:
        raise ShapeTooLarge(f"{where}: {len(shape.faces):,} faces, over the limit of {max_faces:,} (--max-faces)")
    if max_points is not None and shape.points is not None and len(shape.points) > max_points:
        raise ShapeTooLarge(f"{where}: {len(shape.points):,} points, over the limit of {max_points:,} (--max-points)")


def _score(score: Callable, spec, shape, pred_V, pred_F, result: TaskResult, report: _Progress) -> None:
    """``score`` (metrics.evaluate or metrics.floor) against the GT with the job's metric stream; a
    shape without a GT gets the prediction's validity counts only (``metrics.evaluate_without_gt``)."""
    from benchmark.metrics import evaluate_without_gt
    from benchmark.seeding import job_streams

    report("scoring")
    with stage("metrics"):
        if shape.has_gt:
            scores = score(shape.vertices, shape.faces, pred_V, pred_F, preset=spec.metric_preset,
                           seed=job_streams(shape.content_hash, spec.seed).metrics, n_points=spec.eval_points,
                           metres_per_unit=shape.meta.get("metres_per_unit"))
        else:
            scores = evaluate_without_gt(pred_V, pred_F)
    scores.pop("seconds", None)
    result.metrics = scores
    report("saving")
    result.mesh_ply = mesh_to_ply(pred_V, pred_F)


#: Timing keys a cached mesh does not store (every job loads and scores for itself).
_NOT_CACHED = ("load_s", "metrics_s")


def _job_body(spec: JobSpec, shape, device, timer: StageTimer, result: TaskResult, report: _Progress) -> None:
    from benchmark import metrics
    from runner.cache import RunCaches, extraction_code_digest, fit_code_digest
    from methods.base import get_method

    method = get_method(spec.method, **spec.params)
    _record_training_overlap(method.training_record(), shape, result)
    stats = CacheStats()
    caches = RunCaches(spec.cache_dir, stats)
    weights_key = None
    if spec.mode == "neural":
        from methods.core.budgets import budget_values

        weights_key = digest({"shape": result.shape_hash, "method": method.fit_name, "input": method.input_kind,
                              "output_dim": method.output_dim,
                              "budget": budget_values(method.budget(spec.budget, spec.budget_params)),
                              "seed": spec.seed, "code": fit_code_digest(method), "fit_params": method.fit_params()})
    mesh_key = digest({"shape": result.shape_hash, "method": spec.method, "params": method.params, "mode": spec.mode,
                       "grid": spec.grid, "weights": weights_key, "code": extraction_code_digest(method),
                       "data": method.extraction_data_digest()})
    # checkpoints need the fit, a decomposition the fitted field
    cached = None if spec.checkpoints or spec.decompose else caches.load_mesh(spec.method, mesh_key)
    if cached is not None:
        pred_V, pred_F, timings, info, result.fit_loss = cached
        for key, seconds in timings.items():  # the stage times of the job that computed the mesh
            timer.add(key, seconds)
        result.info.update(info, fitted=0)  # the facts of the job that computed it, but no fit here
    else:
        grid_field, facts, model, fields = _grid_field(spec, method, shape, device, caches, weights_key, result, report)
        report("extracting")
        with stage("extract"):
            extraction = method.extract(grid_field, spec.grid)
        result.info.update(facts)
        result.info.update({k: v for k, v in extraction.info.items() if isinstance(v, (int, float, str, bool))})
        pred_V = np.asarray(extraction.vertices, dtype=np.float64)
        pred_F = np.asarray(extraction.faces, dtype=np.int64)
        timings = {k: v for k, v in timer.seconds.items() if k not in _NOT_CACHED}
        caches.save_mesh(spec.method, mesh_key, pred_V, pred_F, timings, result.info, result.fit_loss)
    result.cache, result.cache_rejected = list(stats.hits), list(stats.rejected)
    _score(metrics.evaluate, spec, shape, pred_V, pred_F, result, report)
    if spec.decompose:
        _decompose(spec, method, shape, fields, model, grid_field, device, caches, result, report)
    if spec.checkpoints and spec.checkpoints[-1] == 1.0:  # the last checkpoint is the job's own result
        result.checkpoints.append({"fraction": 1.0, "step": result.info.get("fit_steps"),
                                   "fit_elapsed_s": result.info.get("fit_loop_s"), **result.metrics,
                                   **{k: timer.seconds[k] for k in ("query_s", "extract_s", "metrics_s")}})


def _grid_field(spec: JobSpec, method, shape, device, caches, weights_key, result: TaskResult, report: _Progress):
    """Neural: sample, label, fit (or cached weights), query; oracle: the exact field on the grid.
    Returns the grid field, its facts, the network (None in oracle mode) and the exact fields."""
    from benchmark.fields import ExactFields

    fields = ExactFields(shape.vertices, shape.faces)
    if spec.mode == "oracle":
        report("querying")
        with stage("query"):
            return (*method.oracle_grid(fields, spec.grid, caches.fields), None, fields)
    if spec.checkpoints:  # checkpoints need the fit itself
        model = _fit(spec, method, shape, fields, device, caches, weights_key, result, report)
    else:
        # jobs that share a fit (a sweep of extraction settings) wait for the one fitting it, then load it
        with caches.fit_lock(method, weights_key):
            cached = caches.load_weights(method, weights_key, device)
            if cached is not None:
                model, result.fit_loss = cached
            else:
                model = _fit(spec, method, shape, fields, device, caches, weights_key, result, report)
    result.info.update(_calibrate(spec, method, shape, fields, model, device))
    report("querying")
    with stage("query"):
        return (*method.neural_grid(model, spec.grid, device), model, fields)


def _calibrate(spec: JobSpec, method, shape, fields, model, device) -> dict:
    """The method's calibration of its fitted ``model`` (:meth:`methods.base.Method.calibrate`)
    with the job's calibration stream."""
    from benchmark.seeding import job_streams

    rng = np.random.default_rng(job_streams(shape.content_hash, spec.seed).calibration)
    return method.calibrate(model, fields, spec.grid, rng, device)


def _decompose(spec: JobSpec, method, shape, fields, model, fitted, device, caches, result: TaskResult,
               report: _Progress) -> None:
    """The fitted field's error split by component: the component errors as metrics of the job, and
    per set of exact components (:meth:`methods.base.Method.decompositions`) the hybrid field
    extracted and scored with the job's own metric stream (a row of ``result.components``)."""
    from benchmark import metrics
    from benchmark.seeding import job_streams

    report("decomposing")
    with stage("decompose"):
        exact, _ = method.oracle_grid(fields, spec.grid, caches.fields)
        result.metrics.update(method.component_errors(fitted, exact, spec.grid))
        for parts in method.decompositions():
            with StageTimer(timer_sync(device)).active() as inner:
                with stage("extract"):
                    extraction = method.extract(method.hybrid_grid(fitted, exact, parts, model, spec.grid, device),
                                                spec.grid)
                scores = metrics.evaluate(shape.vertices, shape.faces, extraction.vertices, extraction.faces,
                                          preset=spec.metric_preset,
                                          seed=job_streams(shape.content_hash, spec.seed).metrics,  # fresh: evaluate spawns from it
                                          n_points=spec.eval_points)
            scores.pop("seconds", None)
            result.components.append({"exact": "+".join(parts), **scores, "extract_s": inner.seconds["extract_s"]})


def _fit(spec, method, shape, fields, device, caches, weights_key, result: TaskResult, report: _Progress):
    from benchmark import metrics
    from benchmark.sampler import sample_training_data
    from benchmark.seeding import job_streams
    from methods.core import fitting

    budget = method.budget(spec.budget, spec.budget_params)
    streams = job_streams(shape.content_hash, spec.seed)
    report("sampling")
    with stage("sample"):
        samples = sample_training_data(shape.vertices, shape.faces, budget.num_samples, streams.sampler_rng())
    report("labelling")
    with stage("label"):
        targets = method.training_targets(fields, samples)
    steps = {max(1, round(f * budget.iterations)): f for f in spec.checkpoints if f < 1.0}

    pauses = []

    def checkpoint(step: int, fit_seconds: float, model) -> None:
        """Score the network of a checkpoint: query, extract and metrics under their own timer."""
        t0 = time.perf_counter()
        report("checkpoint", step=step)
        with StageTimer(timer_sync(device)).active() as inner:
            _calibrate(spec, method, shape, fields, model, device)
            with stage("query"):
                grid_field, _ = method.neural_grid(model, spec.grid, device)
            with stage("extract"):
                extraction = method.extract(grid_field, spec.grid)
            with stage("metrics"):
                scores = metrics.evaluate(shape.vertices, shape.faces, extraction.vertices, extraction.faces,
                                          preset=spec.metric_preset, seed=streams.metrics, n_points=spec.eval_points)
        scores.pop("seconds", None)
        result.checkpoints.append({"fraction": steps[step], "step": step, "fit_elapsed_s": fit_seconds, **scores,
                                   **inner.seconds})
        pauses.append(time.perf_counter() - t0)
        report("fitting")

    report("fitting")
    with stage("fit"):
        fit = fitting.fit(method, samples, targets, budget, seed=streams.fitting_seed(), device=device,
                          progress=lambda step, loss: report("fitting", step=step, loss=loss),
                          checkpoints=tuple(steps), on_checkpoint=checkpoint)
    if pauses:  # the fit stage's time without the checkpoints' scoring, which is a stage of its own
        from benchmark.timing import record

        record("fit", -sum(pauses))
        record("checkpoints", sum(pauses))
    result.fit_loss = fit.final_loss
    result.info.update(fitted=1, fit_steps=fit.iterations, fit_samples_per_s=fit.samples_per_s, fit_loop_s=fit.seconds)
    caches.save_weights(method, weights_key, fit, budget)
    return fit.model


def _floor_body(spec: FloorSpec, shape, device, timer: StageTimer, result: TaskResult, report: _Progress) -> None:
    from benchmark import metrics

    result.shape_info = {"source": str(shape.source), "gt_vertices": int(len(shape.vertices)),
                         "gt_faces": int(len(shape.faces))}
    if not shape.has_gt:  # a point cloud alone: no floor, no gt.ply
        result.metrics = {"scored": False}
        return
    _score(lambda V, F, _V, _F, **kw: metrics.floor(V, F, **kw), spec, shape, shape.vertices, shape.faces,
           result, report)


def input_point_cloud(shape, n: int, noise: float, seed: int,
                      corruption: str = "uniform") -> tuple[np.ndarray, np.ndarray | None]:
    """(points (P, 3), sensors (P, 3) or None): the reconstruct task's input. The shape's own cloud
    and sensors (a dataset of point-cloud files), else ``n`` points of the GT surface made as
    ``corruption`` names (:func:`benchmark.corruptions.input_cloud`: ``uniform`` area-uniform
    samples, ``scan`` and its corruptions a virtual range scan with a sensor per point), on the
    job's sampler stream (the same cloud for every method of a (shape, seed, corruption)); plus
    Gaussian noise of sigma ``noise`` (canonical units) from the same stream; no normals."""
    from benchmark.corruptions import input_cloud
    from benchmark.seeding import job_streams

    rng = job_streams(shape.content_hash, seed).sampler_rng()
    if shape.points is not None:
        points, sensors = np.asarray(shape.points, dtype=np.float64), shape.sensors
    else:
        cloud = input_cloud(shape.vertices, shape.faces, n, corruption, rng)
        points, sensors = cloud.points, cloud.sensors
    if noise > 0:
        points = points + rng.normal(scale=noise, size=points.shape)
    return np.asarray(points, dtype=np.float64), sensors


def _record_training_overlap(record, shape, result: TaskResult) -> None:
    """Whether the shape was in the training set of the weights the method used (``record``:
    :class:`methods.core.training_record.TrainingRecord`, None for a method without trained
    weights), in the job's info as ``seen_in_training`` (True, False, or None: unknown) and
    ``training_record`` (what the weights were trained on)."""
    if record is None:
        return
    result.info["seen_in_training"] = record.saw(shape.name, shape.content_hash)
    result.info["training_record"] = record.description


def _reconstruct_body(spec: JobSpec, shape, device, timer: StageTimer, result: TaskResult, report: _Progress) -> None:
    """The reconstruct task: sample the input cloud, reconstruct, score against the GT."""
    from benchmark import metrics
    from methods.base import get_method

    method = get_method(spec.method, **spec.params)
    network = {}
    budget = method.budget(spec.budget, spec.budget_params) if spec.budget is not None else None
    if budget is not None and not method.learned:  # a per-shape optimisation under its own budget
        network["budget"] = budget
    if budget is not None and method.learned:  # its network, trained once across shapes (cached)
        from runner.training import network_training_record, trained_network

        report("training")
        stats = CacheStats()

        def training_progress(step, loss, total=None):
            report("training", step=step, loss=loss)

        with stage("network"):
            network["model"], facts = trained_network(method, budget, spec.train_dirs, spec.cache_dir, device,
                                                      stats=stats, progress=training_progress)
        result.info.update(facts)
        _record_training_overlap(network_training_record(method, budget, spec.train_dirs), shape, result)
        result.cache, result.cache_rejected = list(stats.hits), list(stats.rejected)
    if spec.pc_blocks:
        from runner.block_store import merged_extraction

        report("merging blocks")
        with stage("reconstruct"):
            extraction = merged_extraction(spec, method)
        timer.add("blocks_s", extraction.info.pop("blocks_s"))
    else:
        report("sampling")
        with stage("sample"):
            points, sensors = input_point_cloud(shape, spec.pc_points, spec.pc_noise, spec.seed, spec.pc_corruption)
        result.info["input_points"] = int(len(points))
        if method.uses_sensors and sensors is not None:
            network["sensors"] = sensors
        result.info["used_sensors"] = "sensors" in network
        report("reconstructing")
        with stage("reconstruct"):
            extraction = method.reconstruct(points, spec.grid, device, seed=spec.seed, **network)
    result.info.update({k: v for k, v in extraction.info.items() if isinstance(v, (int, float, str, bool))})
    _score(metrics.evaluate, spec, shape, np.asarray(extraction.vertices, dtype=np.float64),
           np.asarray(extraction.faces, dtype=np.int64), result, report)


def _score_body(spec: JobSpec, shape, device, timer: StageTimer, result: TaskResult, report: _Progress) -> None:
    """The score task: read the shape's prediction made elsewhere (:mod:`runner.external`), move it
    into the canonical frame, score it against the GT."""
    from benchmark import metrics
    from datasets.io import read_mesh_file
    from runner.external import external_seconds, prediction_file

    pred_dir, frame = spec.params["pred_dir"], spec.params["pred_frame"]
    with stage("read"):
        path = prediction_file(pred_dir, spec.shape, spec.method)
        vertices, faces = read_mesh_file(path)
    if frame == "original":
        vertices = shape.transform.apply(vertices)
    result.info["prediction"] = str(path)
    seconds = external_seconds(pred_dir).get(spec.shape)
    if seconds is not None:
        timer.add("external_s", seconds)
    _score(metrics.evaluate, spec, shape, vertices, faces, result, report)


#: The job body of each task (``RunConfig.task``).
_JOB_BODIES = {"encode": _job_body, "reconstruct": _reconstruct_body, "score": _score_body}


def run_task(spec, progress: Callable[..., None] | None = None) -> TaskResult:
    """Run a job or a floor task end to end; never raises (the single entry point of every executor)."""
    return _run(spec, progress, _floor_body if isinstance(spec, FloorSpec) else _JOB_BODIES[spec.task])
