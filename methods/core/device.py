"""The torch device and seeding helpers shared by fitting and querying.

The device is chosen once per process: ``SALSBENCH_DEVICE`` (e.g. ``cpu``, ``cuda``, ``cuda:1``) when
set, else CUDA when available, else the CPU. On the CPU the fitting is bit-for-bit deterministic for
a given seed and thread count (torch's CPU kernels are deterministic; ``torch.use_deterministic_algorithms``
is switched on there to make any non-deterministic kernel raise instead of drifting silently). CUDA
runs are seeded the same way but may differ in the last bits between runs.
"""

from __future__ import annotations

import contextlib
import os
from functools import lru_cache
from typing import Iterator

import torch

#: Environment variable that overrides the automatic device choice.
DEVICE_ENV = "SALSBENCH_DEVICE"

#: Environment variable (read by torch at import) that picks the family of torch's CPU kernels.
CAPABILITY_ENV = "ATEN_CPU_CAPABILITY"
#: The CPU float paths a learned result is checked across: torch's scalar kernels, its AVX2
#: kernels, and the best this CPU has (the variable unset). Each rounds differently, so a fit
#: diverges on them like a change of seed.
FLOAT_PATHS = ("default", "avx2", "native")


def float_path_environment(path: str, base: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of ``base`` (default: this process's environment) in which torch runs the CPU kernels
    of ``path`` (one of :data:`FLOAT_PATHS`; ``'native'`` unsets the variable)."""
    if path not in FLOAT_PATHS:
        raise ValueError(f"unknown float path {path!r}; known: {', '.join(FLOAT_PATHS)}")
    env = dict(os.environ if base is None else base)
    env.pop(CAPABILITY_ENV, None)
    if path != "native":
        env[CAPABILITY_ENV] = path
    return env


def cpu_capability() -> str:
    """The kernel family torch's CPU operators run in this process, e.g. ``'AVX512'`` or ``'DEFAULT'``."""
    return torch.backends.cpu.get_cpu_capability()


@lru_cache(maxsize=None)
def _device_from(spec: str | None) -> torch.device:
    if spec:
        try:
            device = torch.device(spec)
        except RuntimeError as exc:
            raise ValueError(f"{DEVICE_ENV}={spec!r} is not a torch device ({exc})") from None
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"{DEVICE_ENV}={spec!r} asks for CUDA but torch sees no CUDA device")
        return device
    return torch.device("cuda") if torch.cuda.is_available() else torch.device("cpu")


def get_device(spec: str | torch.device | None = None) -> torch.device:
    """The device to use: ``spec`` if given, else ``$SALSBENCH_DEVICE``, else CUDA if present, else CPU."""
    if isinstance(spec, torch.device):
        return spec
    return _device_from(spec or os.environ.get(DEVICE_ENV) or None)


def describe_device(device: torch.device | str | None = None) -> str:
    """A short human-readable name for tables, e.g. ``'cpu (2 threads)'`` or ``'cuda: NVIDIA H100'``."""
    device = get_device(device)
    if device.type == "cuda":
        return f"cuda: {torch.cuda.get_device_name(device)}"
    return f"{device.type} ({torch.get_num_threads()} threads)"


def seeded_generator(seed: int, device: torch.device | str | None = None) -> torch.Generator:
    """Seed torch's global generator (network initialisation) with ``seed`` and return a fresh
    ``torch.Generator`` on ``device`` seeded with it (batch order). On the CPU also turn on
    deterministic algorithms (see module docstring). ``seed``: a job's fitting stream
    (:mod:`foundation.seeding`)."""
    seed = int(seed)
    torch.manual_seed(seed)
    device = get_device(device)
    if device.type == "cpu":
        torch.use_deterministic_algorithms(True, warn_only=True)
    generator = torch.Generator(device=device)
    generator.manual_seed(seed)
    return generator


def synchronize(device: torch.device | str | None = None) -> None:
    """Wait for queued kernels (CUDA) so wall-clock readings include them; no-op on the CPU."""
    device = get_device(device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)


_flush_depth = 0


@contextlib.contextmanager
def flush_denormals() -> Iterator[None]:
    """Inside the block, CPU float operations flush denormal numbers to zero (the FTZ/DAZ modes of
    ``torch.set_flush_denormal``); on leaving the outermost block torch's default (off) is back.

    Why: Softplus(beta = 100) computes ``exp(beta x)``, which is denormal wherever ``beta x < -87``,
    and x86 cores take a slow path on every denormal operand. A fitted head has many such
    pre-activations (a SALS head more than an SDF one), so on the CPU this costs time and nothing
    else: the values flushed lie below float32's smallest normal number (1.2e-38), and the fitted
    weights and extracted meshes stay the same (docs/PERFORMANCE.md, section 2). No effect on CUDA
    tensors. Nested blocks are counted, not restored in turn.
    """
    global _flush_depth
    if _flush_depth == 0:
        torch.set_flush_denormal(True)
    _flush_depth += 1
    try:
        yield
    finally:
        _flush_depth -= 1
        if _flush_depth == 0:
            torch.set_flush_denormal(False)


#: The arithmetic a fit's forward and backward passes may run in: ``float32`` (every CPU gives the
#: same numbers on the same float path) or ``bfloat16`` (autocast: the hidden and output layers'
#: products in bfloat16; the input layer on raw coordinates, weights, optimizer state and loss in
#: float32; faster where the CPU has bfloat16 instructions, and rounded differently from float32).
PRECISIONS = ("float32", "bfloat16")

#: CPU flags (Linux ``/proc/cpuinfo``) of native bfloat16 arithmetic: AVX-512 BF16 (newer EPYC and
#: Xeon cores) and AMX (Xeon Sapphire Rapids and later). Without them torch emulates bfloat16.
BFLOAT16_CPU_FLAGS = ("avx512_bf16", "amx_bf16")


@lru_cache(maxsize=None)
def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags as Linux lists them (empty where ``/proc/cpuinfo`` is absent)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


def precision_unavailable(precision: str, device: torch.device | str | None = None) -> str | None:
    """Why ``precision`` cannot run natively on ``device`` (None: it can). float32 always can;
    bfloat16 on a CUDA device that supports it, or on a CPU with one of :data:`BFLOAT16_CPU_FLAGS`."""
    if precision not in PRECISIONS:
        return f"unknown precision {precision!r}; known: {', '.join(PRECISIONS)}"
    if precision == "float32":
        return None
    device = get_device(device)
    if device.type == "cuda":
        return None if torch.cuda.is_bf16_supported() else f"{describe_device(device)} has no bfloat16 arithmetic"
    if device.type == "cpu":
        if cpu_flags() & set(BFLOAT16_CPU_FLAGS):
            return None
        return (f"this CPU has no bfloat16 instructions (none of {', '.join(BFLOAT16_CPU_FLAGS)}); "
                f"use precision=float32")
    return f"bfloat16 fits are not supported on {device.type}"


def autocast(precision: str, device: torch.device | str | None = None):
    """The context in which a fit's forward pass runs at ``precision`` (:data:`PRECISIONS`):
    torch's autocast to bfloat16, or nothing for float32."""
    device = get_device(device)
    if precision == "float32":
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16)
