"""Per-stage wall-clock timing of a job (the project's one stage timer).

The job opens a :class:`StageTimer`, makes it the active one and wraps each stage::

    timer = StageTimer(sync=lambda: synchronize(device))   # CUDA: wait for queued work first
    with timer.active():
        with stage("query"):            # records query_s
            with stage("normals"):      # nested: records query_normals_s
                ...
        record("extract_qef", 0.12)     # a duration measured elsewhere (e.g. returned by E-DC)

Methods and extractors only call :func:`stage` / :func:`record`; outside an active timer both do
nothing, so the algorithms stay plain functions. Keys are ``<stage>_s`` (sub-stages
``<stage>_<step>_s``), in seconds; a stage entered twice accumulates.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Callable, Iterator

_ACTIVE: ContextVar["StageTimer | None"] = ContextVar("salsbench_stage_timer", default=None)


class StageTimer:
    """Collects ``<stage>_s`` durations; ``sync`` is called before each clock read (CUDA)."""

    def __init__(self, sync: Callable[[], None] | None = None):
        self.sync = sync
        self.seconds: dict[str, float] = {}
        self._path: list[str] = []

    def _now(self) -> float:
        if self.sync is not None:
            self.sync()
        return time.perf_counter()

    def key(self, name: str) -> str:
        return "_".join(self._path + [name]) + "_s"

    def add(self, key: str, seconds: float) -> None:
        self.seconds[key] = self.seconds.get(key, 0.0) + float(seconds)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        key = self.key(name)
        self._path.append(name)
        t0 = self._now()
        try:
            yield
        finally:
            self._path.pop()
            self.add(key, self._now() - t0)

    @contextmanager
    def active(self) -> Iterator["StageTimer"]:
        token = _ACTIVE.set(self)
        try:
            yield self
        finally:
            _ACTIVE.reset(token)


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Time a stage in the active timer (no-op without one)."""
    timer = _ACTIVE.get()
    if timer is None:
        yield
        return
    with timer.stage(name):
        yield


def record(name: str, seconds: float) -> None:
    """Add a duration measured elsewhere under ``<current stage path>_<name>_s`` (no-op without a timer)."""
    timer = _ACTIVE.get()
    if timer is not None:
        timer.add(timer.key(name), seconds)
