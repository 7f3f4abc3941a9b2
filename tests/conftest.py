"""Shared test fixtures: the real meshes in ../shared/data (skipped, with a reason, when absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("SALSBENCH_SHARED_DATA", REPO.parent / "shared" / "data"))
MESH_SUFFIXES = {".obj", ".ply", ".stl", ".off"}


def shared_meshes(subdir: str | None = None) -> list[Path]:
    """Every mesh file under ../shared/data (or one of its sub-folders); [] when absent."""
    root = SHARED_DATA / subdir if subdir else SHARED_DATA
    if not root.is_dir():
        return []
    return sorted(p for p in root.rglob("*") if p.suffix.lower() in MESH_SUFFIXES)


def requires_shared(subdir: str | None = None):
    """Skip marker for tests that read ../shared/data."""
    root = SHARED_DATA / subdir if subdir else SHARED_DATA
    return pytest.mark.skipif(
        not root.is_dir(), reason=f"{root} is absent: real-mesh tests need ../shared/data beside the checkout"
    )


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"{SHARED_DATA} is absent: real-mesh tests need ../shared/data beside the checkout")
    return SHARED_DATA


@pytest.fixture
def fakes():
    """The test-only methods of tests/fake_methods.py, registered for one test."""
    from contextlib import ExitStack

    from methods.base import METHODS
    from tests.fake_methods import FAKES

    with ExitStack() as stack:
        for cls in FAKES:
            stack.enter_context(METHODS.registered(cls.name, cls))
        yield


@pytest.fixture
def one_torch_thread():
    """torch on one thread for one test (bit-identical reruns; the machine is shared), restored after."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
