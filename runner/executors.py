"""Executors: where a run's tasks run. One job function (``runner.job.run_task``) serves all.

Every executor has the same two methods::

    for spec, outcome in executor.run(fn, specs, on_stage=None):   # as tasks finish
        ...                                                          # outcome: fn's result, or an exception
    executor.close()

``fn(spec, progress)`` must be a picklable module-level function that never raises for a job's own
errors (``run_task`` turns them into failed results); an *exception* outcome therefore means the
infrastructure lost the task (its worker process died, or Ray gave up after ``retries`` retries).
The driver records it as a failed row with that error: nothing is lost silently.

* ``auto`` (the default) -- :func:`auto_executor`: on a CPU, a run of two or more tasks gets a
  :class:`ProcessExecutor` with one worker per physical core and one torch thread each (two jobs
  side by side on 2 cores finish more steps per second than one job on both cores: docs/PERFORMANCE.md,
  section 3); a single task,
  or a CUDA device (one GPU), gets the :class:`LocalExecutor` with all threads.
* :class:`LocalExecutor` -- in-process, sequential, in the given order (stage progress).
* :class:`ProcessExecutor` -- ``concurrent.futures.ProcessPoolExecutor`` with the *spawn* context,
  ``workers`` processes, torch threads per worker ``max(1, cores // workers)``; stage progress comes
  back through a queue. At most ``workers`` tasks are in flight, so a crashed worker (the pool is
  then broken) costs only the in-flight tasks one attempt each: they are resubmitted to a fresh pool
  up to ``retries`` times, then reported failed.
* :class:`RayExecutor` -- Ray tasks. ``address=None`` starts a local instance (``workers`` CPUs),
  ``'auto'`` joins a running cluster (``ray start --head`` / ``ray start --address=HEAD:6379``).
  Resources per task: ``cpus_per_job`` CPUs; a fitting job (``spec.uses_fitting``) also asks for
  ``gpus_per_job`` GPUs (fractions allowed) when the cluster has GPUs, while oracle/floor tasks ask
  for CPUs only. Ray retries a task whose worker died ``retries`` times (``max_retries``).

Results are identical whichever executor ran a task, up to floating-point reduction order: oracle
mode and the metrics are bit-identical (no thread-count-dependent reductions); neural fitting on the
CPU is deterministic for a given torch thread count, and the thread count differs between executors
(local: all cores; process: cores // workers), which may change the last bits of the fitted weights.
"""

from __future__ import annotations

import os
import signal
import time
import queue as _queue
import sys
from collections import deque
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator, Sequence

from foundation.registry import Registry
from runner.provenance import REPO


StageCallback = Callable[..., None]


class WorkerLost(RuntimeError):
    """A task's worker process died (killed, out of memory, segfault) and the retries are used up."""


def available_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def physical_cores() -> int:
    """Physical cores among the CPUs this process may use: distinct (package, core) pairs of
    ``/proc/cpuinfo`` (SMT siblings count once); :func:`available_cores` where that is not readable."""
    allowed = None
    try:
        allowed = os.sched_getaffinity(0)
    except (AttributeError, OSError):
        pass
    cores, cpu, package = set(), None, None
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                key, value = key.strip(), value.strip()
                if key == "processor":
                    cpu, package = int(value), None
                elif key == "physical id":
                    package = value
                elif key == "core id" and (allowed is None or cpu in allowed):
                    cores.add((package, value))
    except (OSError, ValueError):
        return available_cores()
    return len(cores) or available_cores()


def threads_per_worker(workers: int, cores: int | None = None) -> int:
    """Torch threads per worker process: ``max(1, cores // workers)``."""
    return max(1, (cores or available_cores()) // max(1, int(workers)))


def _stage_forwarder(on_stage: StageCallback | None, label: str):
    if on_stage is None:
        return None

    def progress(stage: str, **info: Any) -> None:
        on_stage(label, stage, **info)

    return progress


# =============================================================================================
# local
# =============================================================================================


class LocalExecutor:
    """Runs tasks one after the other in this process, in the given order, with ``threads`` torch
    threads (None: torch's default, every core)."""

    name = "local"
    workers = 1

    def __init__(self, threads: int | None = None):
        self.threads = int(threads) if threads else None

    def run(self, fn: Callable, specs: Sequence, on_stage: StageCallback | None = None) -> Iterator[tuple[Any, Any]]:
        for spec in specs:
            if on_stage is not None:
                on_stage(spec.label, "starting")
            try:
                outcome = fn(spec, _stage_forwarder(on_stage, spec.label))
            except Exception as exc:  # noqa: BLE001 -- fn should not raise; if it does, report it
                outcome = exc
            yield spec, outcome

    def map(self, fn: Callable, items: Sequence) -> list:
        """``[fn(x) for x in items]`` in this process."""
        return [fn(x) for x in items]

    def close(self) -> None:
        pass


# =============================================================================================
# process
# =============================================================================================

_WORKER_QUEUE = None


def _process_init(threads: int, progress_queue) -> None:
    """Pool initializer: pin thread counts before any heavy import, keep the progress queue, and
    end the worker when the run's process is gone."""
    global _WORKER_QUEUE
    _WORKER_QUEUE = progress_queue
    progress_queue.cancel_join_thread()  # progress is best effort: a worker's exit never waits to send it
    pin_threads(threads)
    exit_with_parent()


def exit_with_parent(poll_s: float = 1.0) -> None:
    """End this process (exit status 1) within ``poll_s`` seconds of its parent's death, so a run
    that is killed leaves no worker fitting on for nobody."""
    import threading
    import time

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def pin_threads(threads: int) -> None:
    """Use ``threads`` CPU threads in this process: the OpenMP/BLAS variables (read by torch and the
    KD-tree's OpenMP runtime when they are first loaded) and torch's intra-op pool if already loaded."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(threads)  # torch reads OMP_NUM_THREADS when it is first imported
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)


def _process_call(fn: Callable, spec, index: int):
    def progress(stage: str, **info: Any) -> None:
        if _WORKER_QUEUE is not None:
            clean = {k: v for k, v in info.items() if isinstance(v, (int, float, str, type(None)))}
            try:
                _WORKER_QUEUE.put_nowait((index, stage, clean))
            except Exception:  # noqa: BLE001 -- progress is best effort
                pass

    return fn(spec, progress)


def worker_death(processes) -> str:
    """How the dead worker among ``processes`` (every worker a broken process pool started: the
    pool forgets its workers as it breaks, so the caller keeps them) ended, in words: killed by a
    signal (SIGKILL is what the kernel's out-of-memory killer sends) or an exit status. The pool's
    own termination of its other workers (SIGTERM) is not the cause and is left out."""
    deadline = time.monotonic() + 30  # a broken pool ends all its workers: wait (bounded) for each exit code
    codes = [code for code in (_exit_code(p, deadline) for p in processes) if code not in (None, 0, -signal.SIGTERM)]
    if not codes:
        return "cause unknown"
    code = codes[0]
    if code == -signal.SIGKILL:
        return "killed by SIGKILL: out of memory (the kernel's OOM killer) or killed by hand"
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit status {code}"


def _exit_code(process, deadline: float) -> int | None:
    """``process``'s exit code, waiting until ``deadline`` (``time.monotonic``) at most. The pool's own
    thread reaps its dead workers too: when it wins the race for the exit status, this process's
    wait comes back empty-handed and the code appears only once that thread has recorded it on the
    shared process object, so the code is polled, not read once."""
    process.join(timeout=max(0.0, deadline - time.monotonic()))
    while process.exitcode is None and time.monotonic() < deadline:
        time.sleep(0.02)
    return process.exitcode


class ProcessExecutor:
    """Runs tasks in ``workers`` spawned processes (see module docstring)."""

    name = "process"

    def __init__(self, workers: int | None = None, retries: int = 1, threads: int | None = None):
        self.workers = max(1, int(workers or available_cores()))
        self.retries = max(0, int(retries))
        self.threads = int(threads) if threads else threads_per_worker(self.workers)
        import multiprocessing as mp

        self._ctx = mp.get_context("spawn")
        self._queue = self._ctx.Queue()
        self._pool = None

    def _new_pool(self):
        from concurrent.futures import ProcessPoolExecutor

        return ProcessPoolExecutor(max_workers=self.workers, mp_context=self._ctx, initializer=_process_init,
                                   initargs=(self.threads, self._queue))

    def _drain(self, specs, on_stage) -> None:
        while True:
            try:
                index, stage, info = self._queue.get_nowait()
            except (_queue.Empty, EOFError, OSError):
                return
            if on_stage is not None:
                on_stage(specs[index].label, stage, **info)

    def run(self, fn: Callable, specs: Sequence, on_stage: StageCallback | None = None) -> Iterator[tuple[Any, Any]]:
        """Run every spec; yield (spec, outcome) as each finishes.

        A crashing worker breaks the whole pool, and the pool cannot say which task crashed it. So
        the tasks in flight at that moment become *suspects*: each is re-run alone, and only a
        crash while running alone counts against a task's retries. Innocent tasks are never
        charged for another task's crash.
        """
        specs = list(specs)
        todo = deque(range(len(specs)))
        suspects: deque = deque()
        attempts = [0] * len(specs)
        running: dict = {}
        workers: dict = {}  # every process of the current pool, kept to say how a dead one ended
        while todo or suspects or running:
            if self._pool is None:
                self._pool = self._new_pool()
                workers = {}
            if suspects:
                if not running:  # a suspect runs alone, so its crash is its own
                    i = suspects.popleft()
                    attempts[i] += 1
                    running[self._pool.submit(_process_call, fn, specs[i], i)] = i
            else:
                while todo and len(running) < self.workers:
                    i = todo.popleft()
                    attempts[i] += 1
                    running[self._pool.submit(_process_call, fn, specs[i], i)] = i
            workers.update(self._pool._processes or {})
            done, _ = wait(list(running), timeout=0.25, return_when=FIRST_COMPLETED)
            self._drain(specs, on_stage)
            alone = len(running) == 1
            broken = []
            for fut in done:
                i = running.pop(fut)
                try:
                    outcome = fut.result()
                except BrokenProcessPool:
                    broken.append(i)
                    continue
                except Exception as exc:  # noqa: BLE001 -- e.g. an unpicklable result
                    outcome = exc
                yield specs[i], outcome
            if not broken:
                continue
            for fut, i in list(running.items()):  # the rest of the broken pool's tasks are lost too
                running.pop(fut)
                try:
                    outcome = fut.result(timeout=30)
                except BrokenProcessPool:
                    broken.append(i)
                    continue
                except Exception as exc:  # noqa: BLE001
                    outcome = exc
                yield specs[i], outcome
            workers.update(self._pool._processes or {})
            death = worker_death(workers.values())
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
            # A worker that died while sending progress holds the queue's write lock for ever, and
            # every later send would wait on it: the next pool gets a fresh queue.
            self._queue = self._ctx.Queue()
            for i in broken:
                if not alone:  # not known to be the culprit: refund the attempt and isolate it
                    attempts[i] -= 1
                    suspects.append(i)
                elif attempts[i] <= self.retries:
                    suspects.append(i)
                else:
                    yield specs[i], WorkerLost(f"worker process died {attempts[i]} time(s) while running "
                                               f"{specs[i].label} ({death})")

    def map(self, fn: Callable, items: Sequence) -> list:
        """``[fn(x) for x in items]`` over the pool's workers (``fn`` and the items must pickle; the
        pool is started when there is none), in order; in this process when there is one item or
        the pool broke (a worker died)."""
        items = list(items)
        if len(items) < 2:
            return [fn(x) for x in items]
        if self._pool is None:
            self._pool = self._new_pool()
        try:
            return list(self._pool.map(fn, items))
        except BrokenProcessPool:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
            return [fn(x) for x in items]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        try:
            self._queue.close()
        except (OSError, ValueError):
            pass


# =============================================================================================
# ray
# =============================================================================================


def _ray_call(fn: Callable, spec, threads: int):
    """Body of a Ray task: pin the threads to the task's CPU share, run the job function."""
    pin_threads(threads)
    return fn(spec, None)


def _pythonpath_with_repo() -> str:
    return os.pathsep.join([str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])


def start_local_ray(num_cpus: int, **init_kwargs) -> None:
    """Start a local Ray instance of ``num_cpus`` CPUs whose workers import the suite: its raylet is
    started with the suite on ``PYTHONPATH`` (restored here afterwards), and its workers inherit that
    environment. No runtime environment is asked for: with one, Ray starts its workers again through
    a set-up process, besides those it starts with the instance."""
    before = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = _pythonpath_with_repo()
    try:
        import ray

        ray.init(num_cpus=int(num_cpus), **init_kwargs)
    finally:
        if before is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = before


class RayExecutor:
    """Runs tasks as Ray tasks (see module docstring). Joins or starts Ray; shuts down only what it started."""

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None, retries: int = 1,
                 gpus_per_job: float = 1.0, cpus_per_job: float = 1.0):
        import logging

        import ray

        self.ray = ray
        self.retries = max(0, int(retries))
        self.gpus_per_job = float(gpus_per_job)
        self.cpus_per_job = float(cpus_per_job)
        self._started = False
        if not ray.is_initialized():
            common = dict(include_dashboard=False, ignore_reinit_error=True, log_to_driver=False,
                          logging_level=logging.WARNING)
            if address:
                pythonpath = _pythonpath_with_repo()
                # a cluster may run on other machines: ship the suite's packages with the tasks
                modules = [str(REPO / m) for m in ("foundation", "methods", "datasets", "reports", "tasks", "runner")
                           if (REPO / m).is_dir()]
                ray.init(address=address, runtime_env={"py_modules": modules,
                                                       "env_vars": {"PYTHONPATH": pythonpath}}, **common)
            else:
                start_local_ray(int(workers or available_cores()), **common)
            self._started = True
        resources = ray.cluster_resources()
        self.cluster_gpus = float(resources.get("GPU", 0.0))
        self.cluster_cpus = float(resources.get("CPU", 0.0))
        self.workers = max(1, int(self.cluster_cpus // max(self.cpus_per_job, 1e-9)))  # tasks in flight at most
        self.threads = max(1, int(self.cpus_per_job))  # torch threads of each task: its CPU share
        self._remote = ray.remote(_ray_call)

    def resources_for(self, spec) -> dict:
        """Ray resources of one task: CPUs always; GPUs only for fitting jobs on a cluster with GPUs."""
        gpus = self.gpus_per_job if (spec.uses_fitting and self.cluster_gpus > 0) else 0.0
        return {"num_cpus": self.cpus_per_job, "num_gpus": gpus}

    def run(self, fn: Callable, specs: Sequence, on_stage: StageCallback | None = None) -> Iterator[tuple[Any, Any]]:
        ray = self.ray
        pending = {}
        for spec in specs:
            res = self.resources_for(spec)
            ref = self._remote.options(max_retries=self.retries, retry_exceptions=False, **res).remote(fn, spec,
                                                                                                      self.threads)
            pending[ref] = spec
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            for ref in ready:
                spec = pending.pop(ref)
                try:
                    outcome = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 -- WorkerCrashedError, RayTaskError, ...
                    outcome = exc
                yield spec, outcome
            if on_stage is not None and pending:
                on_stage(f"{len(pending)} task(s)", "queued/running on ray")

    def map(self, fn: Callable, items: Sequence) -> list:
        """``[fn(x) for x in items]`` in this process (the run directory's files are on this machine,
        not necessarily on the cluster's)."""
        return [fn(x) for x in items]

    def close(self) -> None:
        if self._started and self.ray.is_initialized():
            self.ray.shutdown()
            self._started = False


# =============================================================================================


#: Executor name -> factory taking the run's :class:`runner.config.RunConfig`.
EXECUTORS: Registry = Registry("executor")
def auto_executor(config, tasks: int):
    """The default executor for ``tasks`` tasks (module docstring): process workers on a CPU, one per
    physical core (``config.workers`` if given, never more than the tasks) with ``config.threads`` (default
    1) torch threads each; the local executor for one task or a non-CPU device."""
    from methods.core.device import get_device

    workers = min(int(config.workers or physical_cores()), int(tasks))
    if get_device().type != "cpu" or workers < 2:
        return LocalExecutor(threads=config.threads)
    return ProcessExecutor(workers=workers, retries=config.retries, threads=config.threads or 1)


#: Executor name -> factory taking the run's :class:`runner.config.RunConfig` and its number of tasks.
EXECUTORS: Registry = Registry("executor")
EXECUTORS.register("auto", auto_executor)
EXECUTORS.register("local", lambda config, tasks: LocalExecutor(threads=config.threads))
EXECUTORS.register("process", lambda config, tasks: ProcessExecutor(workers=config.workers, retries=config.retries,
                                                                    threads=config.threads))
EXECUTORS.register("ray", lambda config, tasks: RayExecutor(address=config.address, workers=config.workers,
                                                            retries=config.retries, gpus_per_job=config.gpus_per_job,
                                                            cpus_per_job=config.cpus_per_job))


def make_executor(config, tasks: int):
    """The executor a run config names (``auto``: :func:`auto_executor`) for ``tasks`` tasks at once at
    most (the run's tasks, or as many as its memory needs let run together), built with its
    workers/address/retries/resources."""
    return EXECUTORS.get(config.executor)(config, tasks)


def execution_record(executor) -> dict[str, Any]:
    """What ran the jobs, for config.json and the timing caption: the executor's name, its parallel
    workers and the torch threads of each job (None where the executor leaves torch's default)."""
    threads = executor.threads
    if threads is None:
        import torch

        threads = torch.get_num_threads()
    return {"executor": executor.name, "workers": executor.workers, "threads_per_job": threads}


def ray_available() -> tuple[bool, str]:
    """(importable, reason) for skip messages."""
    try:
        import ray  # noqa: F401

        return True, ""
    except ImportError as exc:
        return False, f"ray is not installed ({exc}); pip install 'ray>=2.9' to run the Ray executor"


__all__ = ["LocalExecutor", "ProcessExecutor", "RayExecutor", "WorkerLost", "make_executor", "auto_executor",
           "execution_record", "pin_threads", "threads_per_worker", "available_cores", "physical_cores",
           "ray_available", "EXECUTORS"]
