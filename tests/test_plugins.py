"""Plugins from outside the package: a Python file given to --plugin, an entry point of an installed
package; the example plugin (examples/convex_hull.py) end to end."""

from __future__ import annotations

import importlib.metadata
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import runner.config as config_module
from methods.base import METHODS
from runner.cli import EXIT_REFUSED, main
from runner.config import import_plugins, plugin_from_file, split_plugin

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "convex_hull.py"


@pytest.fixture
def example():
    yield plugin_from_file(str(EXAMPLE))
    METHODS.unregister("convex-hull")
    sys.modules.pop("salsbench_plugin_convex_hull", None)


def test_the_example_plugin_reconstructs_a_closed_outward_hull(example):
    from methods.base import get_method

    points = np.random.default_rng(0).normal(size=(500, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)  # on the unit sphere: every point is a hull vertex
    mesh = get_method("convex-hull").reconstruct(points, 32)
    V, F = mesh.vertices, mesh.faces
    assert len(V) == 500 and len(F) == 2 * 500 - 4  # a triangulated sphere: F = 2V - 4
    volume = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6
    assert 0.9 * 4 / 3 * np.pi < volume < 4 / 3 * np.pi  # positive: outward faces; below the ball's volume


@pytest.mark.slow
def test_the_example_plugin_is_a_row_of_a_run(tmp_path):
    out = tmp_path / "run"
    try:
        code = main(["--task", "reconstruct", "--plugin", str(EXAMPLE), "--methods", "convex-hull", "poisson",
                     "--limit", "1", "--grid", "32", "--pc-points", "5000", "--eval-points", "5000", "--quiet",
                     "--gallery", "0", "--out", str(out), "--cache-dir", str(tmp_path / "c"), "--executor", "local"])
    finally:
        METHODS.unregister("convex-hull")
        sys.modules.pop("salsbench_plugin_convex_hull", None)
    assert code == 0
    df = pd.read_csv(out / "results.csv").set_index("method")
    assert (df.status == "ok").all() and df.loc["convex-hull", "cd"] > df.loc["poisson", "cd"]  # a bracket is not convex
    assert "convex-hull" in (out / "summary.md").read_text()


def test_a_plugin_files_code_enters_the_job_key(tmp_path):
    from tasks.cache import code_digest, task_code_digest
    from tasks.spec import ReconstructJob

    copy = tmp_path / "my_hull.py"
    copy.write_text(EXAMPLE.read_text().replace('"convex-hull"', '"my-hull"'))
    spec = ReconstructJob(dataset="builtin", dataset_options={}, shape="s", eval_points=None, metric_preset="default",
                          seed=0, method="my-hull")
    try:
        plugin_from_file(str(copy))
        before = task_code_digest(spec)
        METHODS.unregister("my-hull")
        sys.modules.pop("salsbench_plugin_my_hull")
        copy.write_text(copy.read_text().replace("info={", "info={'changed': 1, "))
        code_digest.cache_clear()
        plugin_from_file(str(copy))
        assert task_code_digest(spec) != before
    finally:
        METHODS.unregister("my-hull")
        sys.modules.pop("salsbench_plugin_my_hull", None)
        code_digest.cache_clear()


def test_plugin_values_and_their_errors(tmp_path, capsys):
    assert split_plugin("pkg.mod:register") == ("pkg.mod", "register")
    assert split_plugin("/a/b/file.py") == ("/a/b/file.py", "")
    assert split_plugin("/a/b/file.py:setup") == ("/a/b/file.py", "setup")
    assert main(["--plugin", str(tmp_path / "absent.py"), "--out", str(tmp_path / "r")]) == EXIT_REFUSED
    assert f"--plugin {tmp_path / 'absent.py'}: cannot load (ImportError: no such file" in capsys.readouterr().err
    other = tmp_path / "convex_hull.py"
    other.write_text("X = 1\n")
    try:
        plugin_from_file(str(EXAMPLE))
        with pytest.raises(ImportError, match="are both plugin module 'salsbench_plugin_convex_hull': rename one"):
            plugin_from_file(str(other))
    finally:
        METHODS.unregister("convex-hull")
        sys.modules.pop("salsbench_plugin_convex_hull", None)


def test_entry_points_of_installed_packages_are_loaded_once(monkeypatch):
    calls = []
    sys.modules["zz_entry_plugin"] = type(sys)("zz_entry_plugin")
    sys.modules["zz_entry_plugin"].register = lambda: calls.append(1)
    entry = importlib.metadata.EntryPoint(name="zz", value="zz_entry_plugin:register", group="salsbench.plugins")
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group=None: [entry] if group == "salsbench.plugins" else [])
    monkeypatch.setattr(config_module, "_ENTRY_POINTS_LOADED", False)
    try:
        import_plugins([])
        import_plugins([])
    finally:
        sys.modules.pop("zz_entry_plugin")
    assert calls == [1]
