"""The encode task: fit a method's network to one shape (or take the exact field), extract a mesh,
score it.

Stages (each timed as ``<stage>_s``): neural mode: ``sample`` (the shared sampler), ``label``
(``method.training_targets`` on the exact fields), ``fit`` (``methods.core.fitting.fit``, or cached
weights), ``query`` (``method.neural_grid``); oracle mode: ``query`` (``method.oracle_grid`` on the
exact fields); then ``extract`` (``method.extract``) and ``metrics``. With ``--decompose`` the fitted
field's error is split by component (``decompose``); with checkpoints the network is also scored
part-way through its fit (``checkpoints``, not counted in ``fit``). Randomness comes from
:func:`foundation.seeding.job_streams` of (shape content hash, seed). Nothing here branches on a
method's name: everything method-specific goes through :class:`methods.base.FieldMethod`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from foundation.storage import CacheStats
from foundation.timing import StageTimer, stage
from tasks.cache import RunCaches, fit_key, mesh_key
from tasks.context import TaskContext, record_training_overlap, score, scores

#: Timing keys a cached mesh does not store (every job loads and scores for itself).
_NOT_CACHED = ("load_", "metrics_")


@dataclass
class _Encode:
    """One encode job's method, caches and their keys (``weights``: None in oracle mode)."""

    ctx: TaskContext
    method: object
    caches: RunCaches
    weights: str | None
    mesh: str

    @property
    def spec(self):
        return self.ctx.spec


def run(ctx: TaskContext) -> None:
    from methods.base import get_method

    spec, result = ctx.spec, ctx.result
    method = get_method(spec.method, **spec.params)
    record_training_overlap(ctx, method.training_record())
    stats = CacheStats()
    weights = fit_key(method, result.shape_hash, spec.budget, spec.budget_params, spec.seed) \
        if spec.mode == "neural" else None
    job = _Encode(ctx, method, RunCaches(spec.cache_dir, stats), weights,
                  mesh_key(method, result.shape_hash, spec.mode, spec.grid, weights))
    precision = method.budget(spec.budget, spec.budget_params).precision if weights else None
    # checkpoints need the fit, a decomposition the fitted field
    cached = None if spec.checkpoints or spec.decompose else job.caches.load_mesh(spec.method, job.mesh)
    model = fields = grid_field = None
    if cached is not None:
        vertices, faces, timings, info, result.fit_loss = cached
        for key, seconds in timings.items():  # the stage times of the job that computed the mesh
            ctx.timer.add(key, seconds)
        result.info.update(info, fitted=0)  # the facts of the job that computed it, but no fit here
    else:
        grid_field, facts, model, fields = _grid_field(job)
        ctx.report("extracting")
        with stage("extract"):
            extraction = method.extract(grid_field, spec.grid)
        result.info.update(facts)
        result.info.update({k: v for k, v in extraction.info.items() if isinstance(v, (int, float, str, bool))})
        vertices = np.asarray(extraction.vertices, dtype=np.float64)
        faces = np.asarray(extraction.faces, dtype=np.int64)
        timings = {k: v for k, v in ctx.timer.seconds.items() if not k.startswith(_NOT_CACHED)}
        job.caches.save_mesh(spec.method, job.mesh, vertices, faces, timings, result.info, result.fit_loss)
    result.info["precision"] = precision  # the fit's arithmetic, also where the mesh came from the cache
    result.cache, result.cache_rejected = list(stats.hits), list(stats.rejected)
    score(ctx, vertices, faces)
    if spec.decompose:
        _decompose(job, fields, model, grid_field)
    if spec.checkpoints and spec.checkpoints[-1] == 1.0:  # the last checkpoint is the job's own result
        result.checkpoints.append({"fraction": 1.0, "step": result.info.get("fit_steps"),
                                   "fit_elapsed_s": result.info.get("fit_loop_s"), **result.metrics,
                                   **{k: ctx.timer.seconds[k] for k in ("query_s", "extract_s", "metrics_s")}})


def _grid_field(job: _Encode):
    """Neural: sample, label, fit (or cached weights), query; oracle: the exact field on the grid.
    Returns the grid field, its facts, the network (None in oracle mode) and the exact fields."""
    from foundation.fields import ExactFields

    ctx, spec, method = job.ctx, job.spec, job.method
    fields = ExactFields(ctx.shape.vertices, ctx.shape.faces)
    if spec.mode == "oracle":
        ctx.report("querying")
        with stage("query"):
            return (*method.oracle_grid(fields, spec.grid, job.caches.fields), None, fields)
    if spec.checkpoints:  # checkpoints need the fit itself
        model = _fit(job, fields)
    else:
        # jobs that share a fit (a sweep of extraction settings) wait for the one fitting it, then load it
        with job.caches.fit_lock(method, job.weights):
            cached = job.caches.load_weights(method, job.weights, ctx.device)
            if cached is not None:
                model, ctx.result.fit_loss = cached
            else:
                model = _fit(job, fields)
    ctx.result.info.update(_calibrate(job, fields, model))
    ctx.report("querying")
    with stage("query"):
        return (*method.neural_grid(model, spec.grid, ctx.device), model, fields)


def _calibrate(job: _Encode, fields, model) -> dict:
    """The method's calibration of its fitted ``model`` (:meth:`methods.base.FieldMethod.calibrate`)
    with the job's calibration stream."""
    from foundation.seeding import job_streams

    ctx = job.ctx
    rng = np.random.default_rng(job_streams(ctx.shape.content_hash, job.spec.seed).calibration)
    return job.method.calibrate(model, fields, job.spec.grid, rng, ctx.device)


def _decompose(job: _Encode, fields, model, fitted) -> None:
    """The fitted field's error split by component: the component errors as metrics of the job, and
    per set of exact components (:meth:`methods.base.FieldMethod.decompositions`) the hybrid field
    extracted and scored with the job's own metric stream (a row of ``result.components``)."""
    ctx, spec, method = job.ctx, job.spec, job.method
    ctx.report("decomposing")
    with stage("decompose"):
        exact = method.exact_grid(fields, spec.grid, job.caches.fields)
        ctx.result.metrics.update(method.component_errors(fitted, exact, spec.grid))
        for parts in method.decompositions():
            with StageTimer(ctx.timer.sync).active() as inner:
                with stage("extract"):
                    extraction = method.extract(method.hybrid_grid(fitted, exact, parts, model, spec.grid, ctx.device),
                                                spec.grid)
                with stage("metrics"):
                    row = scores(ctx, extraction.vertices, extraction.faces)
            ctx.result.components.append({"exact": "+".join(parts), **row, "extract_s": inner.seconds["extract_s"]})


def _fit(job: _Encode, fields):
    """Sample, label and fit the method's network (``fit``; scored at the spec's checkpoints, whose
    time is the stage ``checkpoints``, not ``fit``); the weights go to the cache."""
    from foundation.sampler import sample_training_data
    from foundation.seeding import job_streams
    from methods.core import fitting
    from methods.core.training_loop import window_means

    ctx, spec, method = job.ctx, job.spec, job.method
    budget = method.budget(spec.budget, spec.budget_params)
    streams = job_streams(ctx.shape.content_hash, spec.seed)
    ctx.report("sampling")
    with stage("sample"):
        samples = sample_training_data(ctx.shape.vertices, ctx.shape.faces, budget.num_samples, streams.sampler_rng())
    ctx.report("labelling")
    with stage("label"):
        targets = method.training_targets(fields, samples)
    steps = {max(1, round(f * budget.steps)): f for f in spec.checkpoints if f < 1.0}
    paused = []

    def checkpoint(step: int, fit_seconds: float, model) -> None:
        """Score the network of a checkpoint: query, extract and metrics under their own timer."""
        t0 = time.perf_counter()
        ctx.report("checkpoint", step=step)
        with StageTimer(ctx.timer.sync).active() as inner:
            _calibrate(job, fields, model)
            with stage("query"):
                grid_field, _ = method.neural_grid(model, spec.grid, ctx.device)
            with stage("extract"):
                extraction = method.extract(grid_field, spec.grid)
            with stage("metrics"):
                row = scores(ctx, extraction.vertices, extraction.faces)
        ctx.result.checkpoints.append({"fraction": steps[step], "step": step, "fit_elapsed_s": fit_seconds, **row,
                                       **{k: v for k, v in inner.seconds.items() if not k.startswith("metrics_")}})
        paused.append(time.perf_counter() - t0)
        ctx.report("fitting")

    ctx.report("fitting")
    t0 = time.perf_counter()
    fit = fitting.fit(method, samples, targets, budget, seed=streams.fitting_seed(), device=ctx.device,
                      progress=lambda step, loss: ctx.report("fitting", step=step, loss=loss),
                      checkpoints=tuple(steps), on_checkpoint=checkpoint)
    ctx.timer.add("fit_s", time.perf_counter() - t0 - sum(paused))
    if paused:
        ctx.timer.add("checkpoints_s", sum(paused))
    ctx.result.fit_loss = fit.final_loss
    ctx.result.info.update(fitted=1, fit_steps=fit.steps, fit_samples_per_s=fit.samples_per_s, fit_loop_s=fit.seconds,
                           fit_loss_curve=window_means(fit.losses, budget.log_every), fit_loss_every=budget.log_every)
    job.caches.save_weights(method, job.weights, fit, budget)
    return fit.model
