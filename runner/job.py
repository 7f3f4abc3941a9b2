"""THE task frame: what every executor calls to run one task (:func:`run_task`).

It sets the worker up (plugins, torch threads, device, memory limit), loads the task's shape
(:mod:`tasks.load`), runs the body its spec names (``spec.body``: a module of
:mod:`tasks` with ``run(context)``) under an active stage timer, and never raises: any
exception becomes a failed :class:`~tasks.context.TaskResult` with a one-line error
(``stage: Type: message``) and the traceback in its own field. Nothing here computes a result,
so none of it enters a task's code digest.
"""

from __future__ import annotations

import datetime as _dt
import importlib
import socket
import time
import traceback as _traceback
from typing import Callable

from foundation.timing import StageTimer, stage
from runner.memory import memory_limit, out_of_memory
from tasks.context import Progress, TaskContext, TaskResult
from tasks.load import load_shape


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def one_line(exc: BaseException, stage_name: str | None = None) -> str:
    """``stage: Type: first line of message`` (at most 400 characters)."""
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    text = f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
    if stage_name:
        text = f"{stage_name}: {text}"
    return text if len(text) <= 400 else text[:397] + "..."


def failed_from_exception(spec, exc: BaseException, attempts: int = 1) -> TaskResult:
    """A failed result for a task whose worker died or whose result never came back."""
    return TaskResult(kind=spec.kind, key=spec.key, spec=spec, error=one_line(exc, "worker"),
                      traceback="".join(_traceback.format_exception(exc)), finished=now_iso(), attempts=attempts)


def timer_sync(device) -> Callable[[], None]:
    """What a stage timer calls before reading the clock: wait for queued CUDA work."""
    from methods.core.device import synchronize

    return lambda: synchronize(device)


def run_task(spec, progress: Callable[..., None] | None = None) -> TaskResult:
    """Run a task end to end (see the module docstring); never raises."""
    from methods.core.device import describe_device, get_device
    from runner.config import import_plugins
    from runner.provenance import package_versions

    result = TaskResult(kind=spec.kind, key=spec.key, spec=spec, started=now_iso(), host=socket.gethostname())
    report = Progress(progress)
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
                shape = load_shape(spec)
            result.shape_hash, result.shape_kind = shape.content_hash, shape.kind
            importlib.import_module(spec.body).run(TaskContext(spec, shape, device, timer, result, report))
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
