"""methods/core/device.py: the device choice, the denormal flushing of CPU float operations and the
fit precisions a device can run."""

import pytest
import torch

from methods.core import device
from methods.core.device import autocast, flush_denormals, get_device, precision_unavailable


def _doubled_denormal() -> float:
    return float((torch.tensor([1e-39], dtype=torch.float32) * 2.0)[0])


def test_flush_denormals_zeroes_denormals_inside_nested_blocks_only():
    """1e-39 is a float32 denormal: doubled it stays (2e-39) outside, flushes to 0 inside, also after
    an inner block ends; torch's default (off) is back after the outer one."""
    assert _doubled_denormal() > 0
    with flush_denormals():
        assert _doubled_denormal() == 0.0
        assert float(torch.tensor([1e-30]) * 2.0) == pytest.approx(2e-30)  # normal numbers are untouched
        with flush_denormals():
            assert _doubled_denormal() == 0.0
        assert _doubled_denormal() == 0.0
    assert _doubled_denormal() > 0


def test_a_block_left_by_an_exception_restores_the_default():
    try:
        with flush_denormals():
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert _doubled_denormal() > 0


def test_the_device_is_the_cpu_here_unless_asked(monkeypatch):
    monkeypatch.setenv("SALSBENCH_DEVICE", "cpu")
    assert get_device().type == "cpu"


def test_float_path_environment_sets_or_clears_torchs_kernel_family():
    from methods.core.device import CAPABILITY_ENV, FLOAT_PATHS, float_path_environment

    base = {"PATH": "/bin", CAPABILITY_ENV: "avx2"}
    assert FLOAT_PATHS == ("default", "avx2", "native")
    assert float_path_environment("default", base) == {"PATH": "/bin", CAPABILITY_ENV: "default"}
    assert float_path_environment("native", base) == {"PATH": "/bin"}  # unset: the CPU's best
    assert base[CAPABILITY_ENV] == "avx2"  # the caller's mapping is left alone
    with pytest.raises(ValueError, match="unknown float path 'avx512'"):
        float_path_environment("avx512", base)


def test_bfloat16_needs_the_cpus_bfloat16_instructions_and_float32_runs_anywhere(monkeypatch):
    monkeypatch.setattr(device, "cpu_flags", lambda: frozenset({"avx2", "avx512f"}))
    reason = precision_unavailable("bfloat16", "cpu")
    assert "no bfloat16 instructions" in reason and "avx512_bf16" in reason and "\n" not in reason
    assert precision_unavailable("float32", "cpu") is None
    for flag in device.BFLOAT16_CPU_FLAGS:
        monkeypatch.setattr(device, "cpu_flags", lambda flag=flag: frozenset({"avx2", flag}))
        assert precision_unavailable("bfloat16", "cpu") is None
    assert "unknown precision 'float16'" in precision_unavailable("float16", "cpu")


def test_cpu_flags_are_this_machines_and_autocast_is_off_for_float32():
    flags = device.cpu_flags()
    assert isinstance(flags, frozenset) and (not flags or "fpu" in flags or "sse2" in flags)
    x = torch.ones(4, 4)
    with autocast("float32", "cpu"):
        assert (x @ x).dtype == torch.float32
    with autocast("bfloat16", "cpu"):
        assert (x @ x).dtype == torch.bfloat16
