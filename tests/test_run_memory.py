"""runner.memory: a job's data-segment limit, and which exceptions are failed allocations."""

from __future__ import annotations

import resource

import numpy as np
import pytest

from runner.memory import memory_limit, out_of_memory


def _data_gib() -> float:
    """This process's data segment now (VmData), GiB."""
    with open("/proc/self/status") as f:
        kib = next(int(line.split()[1]) for line in f if line.startswith("VmData:"))
    return kib / 2**20


def test_an_allocation_past_the_limit_fails_in_the_process_and_the_limit_is_restored_after():
    before = resource.getrlimit(resource.RLIMIT_DATA)
    limit = _data_gib() + 0.5
    with memory_limit(limit):
        assert resource.getrlimit(resource.RLIMIT_DATA)[0] == int(limit * 2**30)
        small = np.ones(2**20)  # 8 MiB: within the limit
        with pytest.raises(MemoryError) as numpy_failure:
            np.ones(2**28)  # 2 GiB
        import torch

        with pytest.raises(RuntimeError) as torch_failure:
            torch.ones(2**28, dtype=torch.float64)
    assert resource.getrlimit(resource.RLIMIT_DATA) == before
    assert small.sum() == 2**20 and np.ones(2**26).sum() == 2**26  # 512 MiB: fine again
    assert out_of_memory(numpy_failure.value) and out_of_memory(torch_failure.value)


def test_no_limit_changes_nothing_and_other_errors_are_not_out_of_memory():
    before = resource.getrlimit(resource.RLIMIT_DATA)
    with memory_limit(None):
        assert resource.getrlimit(resource.RLIMIT_DATA) == before
    assert not out_of_memory(RuntimeError("shapes (3,) and (4,) do not match"))
    assert not out_of_memory(ValueError("can't allocate memory"))  # only a MemoryError or an allocator's RuntimeError
    assert out_of_memory(RuntimeError("std::bad_alloc"))
