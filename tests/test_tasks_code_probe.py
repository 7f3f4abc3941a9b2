"""tasks/cache.py's code digests against the code that really runs: for each task and method family,
a small task is run in this process while a profiler records the project modules whose functions
run (in the task frame, in a block-wise job's steps before it, in its blocks). Every such module is
in the task's digest, unless it is on the list of what stays out (the run layer and the reports:
scheduling, I/O, display); no module of that list is in any digest. Every module of those two
packages is on the list by name, so that a new one is put there on purpose: a module elsewhere
computes, and the probes require it in the digest of every task it runs in.

What the probes cannot see: a computing step written inside a module of the list. That is why the
list is a decision per module, reviewed like code (ARCHITECTURE: "nothing here computes a result").
"""

from __future__ import annotations

import contextlib
import sys
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]

#: Modules that never compute a result: they must stay out of every code digest, and may run
#: during a task (the task frame, the executors, the scheduling of a scene's blocks).
STAYS_OUT = frozenset({
    "runner", "runner.blocks", "runner.cli", "runner.config", "runner.display", "runner.driver", "runner.executors",
    "runner.export", "runner.export_inputs", "runner.job", "runner.memory", "runner.memory_need", "runner.parsing",
    "runner.plan", "runner.references", "runner.references_cli",
    "runner.provenance", "runner.records", "runner.regression", "runner.report_cli", "runner.rundir", "runner.sweep",
    "reports", "reports.compare", "reports.decomposition", "reports.frames", "reports.glb", "reports.html",
    "reports.plots", "reports.protocol", "reports.render", "reports.robustness", "reports.significance",
    "reports.statistics", "reports.style", "reports.summary", "reports.sweep", "reports.table", "reports.timing",
    "reports.viewer", "reports.viewer_assets", "reports.viewer_data",
})


def _module_of(filename: str) -> str | None:
    try:
        rel = Path(filename).resolve().relative_to(REPO)
    except ValueError:
        return None
    if rel.suffix != ".py" or rel.parts[0] not in ("foundation", "methods", "datasets", "tasks", "runner", "reports"):
        return None
    parts = list(rel.with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@contextlib.contextmanager
def functions_run():
    """The set (filled on exit) of project modules whose functions ran inside the block (module-level
    code of a first import excluded: it defines, it does not compute)."""
    files: set[str] = set()

    def profile(frame, event, arg):
        if event == "call" and frame.f_code.co_name != "<module>":
            files.add(frame.f_code.co_filename)

    modules: set[str] = set()
    previous = sys.getprofile()
    sys.setprofile(profile)
    threading.setprofile(profile)
    try:
        yield modules
    finally:
        sys.setprofile(previous)
        threading.setprofile(None)
        modules.update(m for m in map(_module_of, files) if m is not None)


def _project_modules() -> set[str]:
    found = set()
    for package in ("foundation", "methods", "datasets", "tasks", "runner", "reports"):
        for path in (REPO / package).rglob("*.py"):
            found.add(_module_of(str(path)))
    return found


def test_every_module_of_the_run_layer_and_the_reports_is_classified_by_name():
    modules = _project_modules()
    unclassified = sorted(m for m in modules if m.split(".")[0] in ("runner", "reports") and m not in STAYS_OUT)
    assert not unclassified, f"put each on STAYS_OUT, or move its computing code to tasks/ or below: {unclassified}"
    assert STAYS_OUT <= modules, sorted(STAYS_OUT - modules)  # no name of a module that is gone


def _specs(config_kw: dict):
    from runner.config import RunConfig
    from runner.plan import build_tasks, resolve

    floors, jobs = build_tasks(resolve(RunConfig(**config_kw)))
    return floors, jobs


def _probe(spec, run_dir: Path) -> tuple[set[str], set[str]]:
    """(modules whose functions ran for ``spec``, modules of its code digest), the task run ok."""
    from runner.blocks import run_blocks
    from runner.executors import LocalExecutor
    from runner.job import run_task
    from tasks.cache import code_modules, task_code_digest, task_code_modules

    with functions_run() as ran:
        if getattr(spec, "block_wise", False):
            (spec,) = run_blocks([spec], run_dir, LocalExecutor(threads=1), {spec.key: task_code_digest(spec)})
        result = run_task(spec)
    assert result.status == "ok", result.error
    return ran, set(code_modules(*task_code_modules(spec)))


def _check(spec, run_dir: Path) -> None:
    ran, digest = _probe(spec, run_dir)
    outside = sorted(ran - digest - STAYS_OUT)
    assert not outside, f"{spec.label}: code that ran outside its digest: {outside}"
    assert not digest & STAYS_OUT, sorted(digest & STAYS_OUT)
    assert {spec.body, "tasks.load"} <= digest and spec.body in ran


BUILTIN = dict(dataset="builtin", limit=1, eval_points=3000, cache_dir=None, no_cache=True, threads=1, gallery=0)


@pytest.mark.parametrize("methods", [("sdf", "bof"), ("sals", "udf-dualmesh")], ids="-".join)
def test_oracle_encode_runs_only_code_of_its_digest(tmp_path, methods):
    floors, jobs = _specs(dict(BUILTIN, mode="oracle", grid=16, methods=methods))
    for spec in [*floors, *jobs]:
        _check(spec, tmp_path)


def test_reconstruct_and_block_wise_reconstruct_run_only_code_of_their_digests(tmp_path):
    """Poisson on a whole cloud and block by block (windows of 24 points on a scene grid of 32 in blocks of 16)."""
    kw = dict(BUILTIN, task="reconstruct", grid=24, methods=("poisson",), pc_points=3000)
    (_, (whole,)), (_, (blocks,)) = _specs(kw), _specs(dict(kw, pc_blocks=16, pc_scene_grid=32))
    assert blocks.body == "tasks.blocks" and whole.body == "tasks.reconstruct"
    _check(whole, tmp_path)
    _check(blocks, tmp_path)
    from tasks.cache import code_modules, task_code_modules

    assert {"tasks.blocks", "methods.pointcloud.blocks"} <= set(code_modules(*task_code_modules(blocks)))
    assert "tasks.blocks" not in code_modules(*task_code_modules(whole))  # a whole-cloud row is not the blocks'


def test_score_runs_only_code_of_its_digest(tmp_path):
    from datasets import get_dataset
    from datasets.io import save_mesh

    builtin = get_dataset("builtin")
    shape = builtin.load(builtin.names()[0])
    pred = tmp_path / "pred"
    pred.mkdir()
    save_mesh(pred / f"{shape.name}.ply", shape.vertices, shape.faces)
    floors, jobs = _specs(dict(BUILTIN, task="score", method_params={"mine": {"pred_dir": str(pred)}},
                               methods=("mine",)))
    assert len(jobs) == 1
    _check(jobs[0], tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("methods", [("sals", "sals-ndc"), ("sdf", "sdf-ndc"), ("udf", "udf-ndc")], ids="-".join)
def test_neural_encode_runs_only_code_of_its_digest(tmp_path, methods):
    _, jobs = _specs(dict(BUILTIN, mode="neural", budget="tiny", grid=16, methods=methods))
    for spec in jobs:
        _check(spec, tmp_path)


@pytest.mark.slow
def test_a_learned_block_wise_reconstruction_runs_only_code_of_its_digest(tmp_path):
    """sals-knn by edges (its network trained at the tiny budget, in the probe too)."""
    kw = dict(BUILTIN, task="reconstruct", grid=16, methods=("sals-knn",), budget="tiny", pc_points=3000,
              cache_dir=str(tmp_path / "cache"), no_cache=False, train_dirs=())
    _, (blocks,) = _specs(dict(kw, pc_blocks=8, pc_scene_grid=16))
    _check(blocks, tmp_path)
    _, (whole,) = _specs(kw)
    _check(whole, tmp_path)
