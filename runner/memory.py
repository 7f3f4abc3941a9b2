"""A job's memory limit (``--worker-memory``), how a failed allocation reads in its row, and the
peak resident memory of a task."""

from __future__ import annotations

import contextlib
from pathlib import Path

__all__ = ["memory_limit", "out_of_memory", "reset_peak_rss", "peak_rss_mib"]

#: Messages of the allocation failures that are not a MemoryError: torch's CPU allocator, C++'s
#: std::bad_alloc as some bindings pass it on.
_ALLOCATION_FAILURES = ("can't allocate memory", "not enough memory", "bad_alloc", "out of memory")


@contextlib.contextmanager
def memory_limit(gib: float | None):
    """Within the block, this process may hold at most ``gib`` GiB of data: the soft RLIMIT_DATA
    (heap and private anonymous memory, which is what numpy, torch and the C++ libraries allocate;
    not the code of shared libraries or files mapped read-only). An allocation past it fails in the
    process (numpy: MemoryError; torch: RuntimeError) instead of waking the kernel's out-of-memory
    killer. The previous limit is restored after the block. None: no change.

    The limit is the whole process's: a job run in the driver process (``--executor local``)
    counts what the driver already holds."""
    if gib is None:
        yield
        return
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    limit = int(gib * 2**30)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_DATA, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))


def out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is a failed allocation (MemoryError, or torch's and C++'s own messages)."""
    if isinstance(exc, MemoryError):
        return True
    text = str(exc).lower()
    return isinstance(exc, RuntimeError) and any(m in text for m in _ALLOCATION_FAILURES)


def reset_peak_rss() -> None:
    """Start a new peak of resident memory for this process (Linux: ``/proc/self/clear_refs``); a
    worker calls it before each task, so that :func:`peak_rss_mib` is that task's."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def peak_rss_mib() -> float | None:
    """The peak resident memory of this process since :func:`reset_peak_rss` (or its start), in MiB
    (``VmHWM``); None where the system does not say."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None
