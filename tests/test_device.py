"""methods/core/device.py: the device choice and the denormal flushing of CPU float operations."""

import pytest
import torch

from methods.core.device import flush_denormals, get_device


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
