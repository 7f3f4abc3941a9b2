"""The torch device and seeding helpers shared by fitting and querying.

The device is chosen once per process: ``SALSBENCH_DEVICE`` (e.g. ``cpu``, ``cuda``, ``cuda:1``) when
set, else CUDA when available, else the CPU. On the CPU the fitting is bit-for-bit deterministic for
a given seed and thread count (torch's CPU kernels are deterministic; ``torch.use_deterministic_algorithms``
is switched on there to make any non-deterministic kernel raise instead of drifting silently). CUDA
runs are seeded the same way but may differ in the last bits between runs.
"""

from __future__ import annotations

import os
from functools import lru_cache

import torch

#: Environment variable that overrides the automatic device choice.
DEVICE_ENV = "SALSBENCH_DEVICE"


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
    (:mod:`benchmark.seeding`)."""
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
