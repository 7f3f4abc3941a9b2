"""Shared test fixtures: the real meshes in ../shared/data (skipped, with a reason, when absent), and
the seeds, threads and measurement log of the tests that fit or train a network (``learned``).

A ``learned`` test asserts bounds on what a fit reaches. Those bounds hold across seeds and CPU float
paths, and ``scripts/measure_learned_spread.py`` measures that spread by running the learned tests
with these variables set:

* ``SALSBENCH_TEST_SEEDS`` (``0,1,2,3,4``): the seeds a test taking ``fit_seed`` runs at (default 0);
* ``SALSBENCH_TEST_THREADS``: the torch threads of ``torch_threads`` (default 1);
* ``SALSBENCH_SPREAD_OUT``: a JSON-lines file that ``measured(...)`` appends each test's values to.

The property-based tests of the loaders (Hypothesis; ``tests/loader_fuzz.py``) run under the profile
named by ``SALSBENCH_HYPOTHESIS``: ``fast`` (the default: a few examples per test, the fast lane) or
``slow`` (ten times as many). Both are derandomized (the same examples on every run: same seed, same
result) and keep no example database; Hypothesis's other caches go to the system's temporary folder
(nothing is written into the checkout).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings
from hypothesis.configuration import set_hypothesis_home_dir

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("SALSBENCH_SHARED_DATA", REPO.parent / "shared" / "data"))
MESH_SUFFIXES = {".obj", ".ply", ".stl", ".off"}

HYPOTHESIS_ENV = "SALSBENCH_HYPOTHESIS"
#: Examples per property-based test in the fast lane; the slow profile runs ten times as many.
FAST_EXAMPLES = 50
for _name, _examples in (("fast", FAST_EXAMPLES), ("slow", 10 * FAST_EXAMPLES)):
    settings.register_profile(_name, max_examples=_examples, derandomize=True, database=None, deadline=2000,
                              print_blob=False, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get(HYPOTHESIS_ENV, "fast"))
if not os.environ.get("HYPOTHESIS_STORAGE_DIRECTORY"):  # its caches (constants) outside the checkout too
    set_hypothesis_home_dir(Path(tempfile.gettempdir()) / f"salsbench-hypothesis-{os.getuid()}")


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

    from methods.base import registered_method
    from tests.fake_methods import FAKES

    with ExitStack() as stack:
        for cls, order in FAKES:
            stack.enter_context(registered_method(cls, order=order))
        yield


SEEDS_ENV = "SALSBENCH_TEST_SEEDS"
THREADS_ENV = "SALSBENCH_TEST_THREADS"
SPREAD_OUT_ENV = "SALSBENCH_SPREAD_OUT"


def pytest_generate_tests(metafunc):
    if "fit_seed" in metafunc.fixturenames:
        seeds = [int(s) for s in os.environ.get(SEEDS_ENV, "0").split(",")]
        metafunc.parametrize("fit_seed", seeds, ids=[f"seed{s}" for s in seeds])


@pytest.fixture
def torch_threads():
    """torch on $SALSBENCH_TEST_THREADS threads (default 1: bit-identical reruns on a shared machine)
    for one test, restored after; the thread count."""
    import torch

    threads = torch.get_num_threads()
    wanted = int(os.environ.get(THREADS_ENV, "1"))
    torch.set_num_threads(wanted)
    yield wanted
    torch.set_num_threads(threads)


@pytest.fixture
def measured(request):
    """``measured(name=value, ...)``: log a learned test's measured values to $SALSBENCH_SPREAD_OUT (one
    JSON line with the test, its parameters, seed, threads and torch's CPU kernel family); a no-op
    when the variable is unset. Call it before asserting, so a failing value is logged too."""
    path = os.environ.get(SPREAD_OUT_ENV)

    def record(**values):
        if not path:
            return
        import torch

        from methods.core.device import cpu_capability

        callspec = getattr(request.node, "callspec", None)
        params = dict(callspec.params) if callspec else {}
        seed = params.pop("fit_seed", None)
        row = {"test": f"{request.node.module.__name__.split('.')[-1]}::{request.node.originalname}",
               "case": "-".join(str(v) for v in params.values()), "seed": seed,
               "threads": torch.get_num_threads(), "capability": cpu_capability(),
               **{k: float(v) for k, v in values.items()}}
        with open(path, "a") as f:
            f.write(json.dumps(row) + "\n")

    return record
