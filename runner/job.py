"""THE task frame: what every executor calls to run one task (:func:`run_task`) or one block of a
block-wise job (:func:`run_block_task`).

It sets the worker up (memory limit, plugins, torch threads, device), runs what the task's spec
names (a task: its body, ``spec.body``, a module of :mod:`tasks` with ``run(context)``, on its
loaded shape (:mod:`tasks.load`) under an active stage timer; a block: :func:`tasks.blocks.run_block`),
measures the peak resident memory of the process while it runs, and never raises: any exception
becomes a failed result with a one-line error (``stage: Type: message``,
:func:`foundation.errors.one_line`) and the traceback in its own field. Nothing here computes a
result, so none of it enters a task's code digest.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import importlib
import socket
import time
import traceback as _traceback
from typing import Callable, Iterator

from foundation.errors import one_line
from foundation.timing import StageTimer, stage
from runner.memory import memory_limit, out_of_memory, peak_rss_mib, reset_peak_rss
from tasks.block_store import BlockResult, BlockTask
from tasks.context import Progress, TaskContext, TaskResult
from tasks.load import load_shape


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def failed_from_exception(spec, exc: BaseException, attempts: int = 1) -> TaskResult:
    """A failed result for a task whose worker died or whose result never came back."""
    return TaskResult(kind=spec.kind, key=spec.key, spec=spec, error=one_line(exc, "worker"),
                      traceback="".join(_traceback.format_exception(exc)), finished=now_iso(), attempts=attempts)


def timer_sync(device) -> Callable[[], None]:
    """What a stage timer calls before reading the clock: wait for queued CUDA work."""
    from methods.core.device import synchronize

    return lambda: synchronize(device)


@contextlib.contextmanager
def worker(spec) -> Iterator[None]:
    """This process set up for a task of ``spec`` (a task's or a block's job spec): its memory limit
    (``worker_memory``) for the block's duration, its plugins and its torch threads."""
    from runner.config import import_plugins

    with memory_limit(spec.worker_memory):
        import_plugins(spec.plugins)
        if spec.threads:
            import torch

            torch.set_num_threads(int(spec.threads))
        yield


def failure_text(exc: BaseException, stage_name: str | None, worker_memory: float | None) -> str:
    """The one-line error of a task that raised ``exc`` in ``stage_name``; a failed allocation says so,
    with the ``--worker-memory`` limit it went past."""
    if out_of_memory(exc):
        limit = f" of --worker-memory {worker_memory:g} GiB" if worker_memory else ""
        return one_line(exc, f"{stage_name}: out of memory (past the limit{limit})" if limit
                        else f"{stage_name}: out of memory")
    return one_line(exc, stage_name)


def run_task(spec, progress: Callable[..., None] | None = None) -> TaskResult:
    """Run a task end to end (see the module docstring); never raises. Its info gets the peak
    resident memory of the process while it ran (``peak_rss_mib``)."""
    from methods.core.device import describe_device, get_device
    from runner.provenance import package_versions

    result = TaskResult(kind=spec.kind, key=spec.key, spec=spec, started=now_iso(), host=socket.gethostname())
    report = Progress(progress)
    timer = StageTimer()
    reset_peak_rss()
    t0 = time.perf_counter()
    try:
        with timer.active():
            report("loading")
            with worker(spec):
                result.versions = package_versions()
                device = get_device(spec.device if spec.kind == "job" else None)
                timer.sync = timer_sync(device)
                result.device = describe_device(device)
                with stage("load"):
                    shape = load_shape(spec)
                result.shape_hash, result.shape_kind = shape.content_hash, shape.kind
                importlib.import_module(spec.body).run(TaskContext(spec, shape, device, timer, result, report))
                result.status = "ok"
    except Exception as exc:  # noqa: BLE001 -- every failure becomes a failed row, the run goes on
        result.status = "failed"
        result.error = failure_text(exc, report.stage, spec.worker_memory)
        result.traceback = _traceback.format_exc()
    timer.add("total_s", time.perf_counter() - t0)
    result.timings = dict(timer.seconds)
    peak = peak_rss_mib()
    if peak is not None:
        result.info["peak_rss_mib"] = peak
    result.finished = now_iso()
    return result


def run_block_task(task: BlockTask, progress: Callable[..., None] | None = None) -> BlockResult:
    """Run one block of a block-wise job (:func:`tasks.blocks.run_block`); never raises: a block whose
    crop needs a larger halo comes back with status 'halo' and the radius, a failure with one line."""
    from methods.core.device import get_device
    from methods.pointcloud.blocks import HaloTooSmall
    from tasks.blocks import run_block

    job = task.job
    result = BlockResult(task)
    reset_peak_rss()
    t0 = time.perf_counter()
    stage_name = "loading"
    try:
        with worker(job):
            device = get_device(job.device)
            stage_name = "block"
            result.arrays = run_block(task, device)
            result.status = "ok"
    except HaloTooSmall as exc:
        result.status, result.needed_halo = "halo", exc.radius
    except Exception as exc:  # noqa: BLE001 -- a failed block fails its job, not the run
        result.error, result.traceback = failure_text(exc, stage_name, job.worker_memory), _traceback.format_exc()
    result.seconds = time.perf_counter() - t0
    result.peak_rss_mib = peak_rss_mib()
    return result
