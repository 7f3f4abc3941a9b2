"""The run layer's caches (tasks.cache): code digests follow the imports, damaged entries
are recomputed and counted, never used."""

from __future__ import annotations

import pathlib

import numpy as np
import pandas as pd
import pytest

from tasks.cache import RunCaches, code_digest
from runner.cli import main
from foundation.storage import CacheStats
from tests.fake_methods import PLUGIN


def test_code_digest_follows_imports_and_refuses_missing_modules(tmp_path, monkeypatch):
    import foundation

    pkg = tmp_path / "benchmark_extra"
    monkeypatch.setattr(foundation, "__path__", [*foundation.__path__, str(pkg)])
    pkg.mkdir()
    (pkg / "zz_probe_a.py").write_text("def f():\n    from foundation import zz_probe_b\n")
    (pkg / "zz_probe_b.py").write_text("X = 1\n")
    code_digest.cache_clear()
    first = code_digest("foundation.zz_probe_a")
    (pkg / "zz_probe_b.py").write_text("X = 2\n")  # a module imported lazily, inside a function
    code_digest.cache_clear()
    assert code_digest("foundation.zz_probe_a") != first
    (pkg / "zz_probe_b.py").write_text('"""A docstring."""\n# a comment\nX = (\n    2)  # same code\n')
    code_digest.cache_clear()
    second = code_digest("foundation.zz_probe_a")
    (pkg / "zz_probe_b.py").write_text("X = 2\n")
    code_digest.cache_clear()
    assert code_digest("foundation.zz_probe_a") == second  # comments, docstrings, layout: same digest
    (pkg / "zz_probe_a.py").write_text('def f():\n    "Doc."\n    from foundation import zz_probe_b\n')
    code_digest.cache_clear()
    assert code_digest("foundation.zz_probe_a") == second
    (pkg / "zz_probe_b.py").write_text('@register_method(order=1, color="#000000")\nclass M:\n    pass\nX = 2\n')
    code_digest.cache_clear()
    colored = code_digest("foundation.zz_probe_a")
    (pkg / "zz_probe_b.py").write_text('@register_method(order=9, color="#ffffff", note="a note")\nclass M:\n    pass\nX = 2\n')
    code_digest.cache_clear()
    assert code_digest("foundation.zz_probe_a") == colored  # how tables show a method is not code
    (pkg / "zz_probe_b.py").write_text('@register_method(order=9, color="#ffffff", note="a note")\nclass M:\n    y = 1\nX = 2\n')
    code_digest.cache_clear()
    assert code_digest("foundation.zz_probe_a") != colored
    (pkg / "zz_probe_b.py").unlink()  # renamed away: never silently counted as empty
    code_digest.cache_clear()
    with pytest.raises(ModuleNotFoundError, match="imports 'foundation.zz_probe_b', which does not exist"):
        code_digest("foundation.zz_probe_a")
    code_digest.cache_clear()


def test_damaged_mesh_entry_is_recomputed_and_counted(tmp_path):
    stats = CacheStats()
    caches = RunCaches(tmp_path, stats)
    V, F = np.random.default_rng(0).random((4, 3)), np.array([[0, 1, 2], [0, 2, 3]])
    caches.save_mesh("m", "k", V, F, {"query_s": 1.0}, {"n": 1}, 0.5)
    got = caches.load_mesh("m", "k")
    assert np.array_equal(got[0], V) and got[2] == {"query_s": 1.0} and got[4] == 0.5 and stats.hits == ["mesh"]
    path = tmp_path / "meshes" / "m_k.npz"
    data = bytearray(path.read_bytes())
    data[-100:-36] = bytes(64)  # 64 bytes zeroed inside the payload
    path.write_bytes(bytes(data))
    assert caches.load_mesh("m", "k") is None and len(stats.rejected) == 1 and "checksum mismatch" in stats.rejected[0]


@pytest.mark.slow
def test_damaged_weights_are_refitted_not_used(fakes, tmp_path):
    """Flipping 64 bytes of a cached .pt must not load silently: the damage is counted and the fit redone."""
    cache = tmp_path / "cache"
    args = ["--methods", "test_sdf", "--mode", "neural", "--budget", "tiny", "--grid", "24", "--eval-points", "5000",
            "--limit", "1", "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet", "--threads", "1",
            "--executor", "local"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    for mesh in (cache / "meshes").iterdir():  # force the next run back to the weights
        mesh.unlink()
    (weights,) = (cache / "weights").iterdir()
    data = bytearray(weights.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 64] = bytes(b ^ 0xFF for b in data[middle:middle + 64])
    weights.write_bytes(bytes(data))
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    a, b = (pd.read_csv(tmp_path / r / "results.csv").iloc[0] for r in ("a", "b"))
    assert b["cache_rejected"] == 1 and b["fit_s"] > 0        # refitted, and the damage counted
    assert b["cd"] == a["cd"] and b["fit_loss"] == a["fit_loss"]  # the same fit as the first time


def test_a_weights_entry_that_would_run_code_is_refused_unread_and_refitted(tmp_path):
    from foundation.storage import write_checked
    from methods.base import get_method
    from tests.test_weights import crafted_weights

    stats = CacheStats()
    caches = RunCaches(tmp_path / "cache", stats)
    method = get_method("sdf")
    write_checked(caches._path("weights", method.fit_name, "k", ".pt"), crafted_weights(tmp_path / "ran"))
    assert caches.load_weights(method, "k", "cpu") is None  # the job fits afresh and overwrites the entry
    assert not (tmp_path / "ran").exists() and stats.hits == []
    assert len(stats.rejected) == 1 and "refused unread" in stats.rejected[0] and "\n" not in stats.rejected[0]


def _neural_run(out, cache, *extra: str) -> list[str]:
    return ["--methods", "test_sdf", "test_occ", "--mode", "neural", "--budget", "tiny", "--grid", "24",
            "--eval-points", "5000", "--limit", "2", "--out", str(out), "--cache-dir", str(cache), "--plugin", PLUGIN,
            "--quiet", "--threads", "1", "--executor", "local", *extra]


METRICS = ["shape", "method", "cd", "nc", "f1_005", "f1_01", "ecd", "ef1", "n_vertices", "n_faces"]


def check_cache_entries(cache) -> int:
    """Every entry under ``cache`` reads back whole (its checksum holds) and no temporary file is
    left; returns the number of entries."""
    from foundation.storage import read_checked

    entries = [p for kind in ("fields", "weights", "meshes") for p in (cache / kind).rglob("*") if p.is_file()]
    assert not [p for p in cache.rglob("*.tmp")]
    for path in entries:
        assert read_checked(path) is not None
    return len(entries)


@pytest.mark.slow
def test_two_runs_sharing_one_cache_fit_each_network_once_and_equal_a_serial_run(tmp_path):
    """Two processes start the same neural jobs at once on one cache folder: every entry stays whole,
    each (shape, method) network is fitted once between them (the other job waits on the entry's lock
    and loads it, or finds the mesh), and both tables equal a serial run's on a fresh cache bit for bit."""
    import subprocess
    import sys

    shared = tmp_path / "shared-cache"
    procs = [subprocess.Popen([sys.executable, "run_benchmark.py", *_neural_run(tmp_path / name, shared)], cwd=pathlib.Path(__file__).resolve().parents[1],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for name in ("a", "b")]
    assert [p.wait(timeout=600) for p in procs] == [0, 0], [p.stderr.read() for p in procs]
    assert main(_neural_run(tmp_path / "serial", tmp_path / "fresh-cache")) == 0
    a, b, serial = (pd.read_csv(tmp_path / n / "results.csv").sort_values(["shape", "method"]).reset_index(drop=True)
                    for n in ("a", "b", "serial"))
    for run in (a, b):
        pd.testing.assert_frame_equal(run[METRICS], serial[METRICS])
    fits = (a.set_index(["shape", "method"])["fitted"] + b.set_index(["shape", "method"])["fitted"])
    assert (fits == 1).all(), fits  # never fitted twice, never lost
    assert check_cache_entries(shared) == check_cache_entries(tmp_path / "fresh-cache")


def _specs():
    from tasks import FloorSpec
    from tasks.spec import EncodeJob, ReconstructJob, ScoreJob

    common = dict(dataset="builtin", dataset_options={}, shape="s", eval_points=None, metric_preset="default", seed=0)
    return [FloorSpec(**common), EncodeJob(**common, method="sals"), EncodeJob(**common, method="udf-ndc"),
            ReconstructJob(**common, method="poisson"), ReconstructJob(**common, method="sals-knn", budget="cpu"),
            ScoreJob(**common, method="mine", params={"pred_dir": "/p", "pred_frame": "original"})]


@pytest.mark.parametrize("spec", _specs(), ids=lambda s: s.label)
def test_a_tasks_code_digest_covers_what_computes_it_and_nothing_of_the_run_layer_or_the_reports(spec):
    """The modules of a task's digest: its body, the shape loading, the method's module and what
    they import; never the command line, the configuration, the executors, the progress display,
    the driver or the reports, so an edit there leaves every finished result valid."""
    from tasks.cache import code_modules, task_code_modules

    modules = set(code_modules(*task_code_modules(spec)))
    assert {spec.body, "tasks.load", "foundation.metrics.evaluate"} <= modules
    assert not {m for m in modules if m.split(".")[0] in ("runner", "reports")}, sorted(modules)
    if spec.kind == "job":
        from tasks.rows import row_kind

        assert row_kind(spec.task, spec.method).module in modules


@pytest.mark.slow
def test_edits_outside_the_computing_code_re_run_no_finished_job(tmp_path, capsys):
    """A finished run, then a copy of the code with an unused function appended to the CLI module
    and to the executors' module and a help text changed: the same command into the same run
    directory runs none of its jobs again."""
    import shutil
    import subprocess
    import sys

    repo = pathlib.Path(__file__).resolve().parents[1]
    copy = tmp_path / "copy"
    for name in ("foundation", "datasets", "methods", "reports", "runner", "tasks"):
        shutil.copytree(repo / name, copy / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(repo / "run_benchmark.py", copy / "run_benchmark.py")
    with open(copy / "runner" / "cli.py", "a") as f:
        f.write("\n\ndef an_unused_function():\n    return 'nothing calls this'\n")
    with open(copy / "runner" / "executors.py", "a") as f:
        f.write("\n\ndef another_unused_function():\n    return 'nor this'\n")
    config = copy / "runner" / "config.py"
    config.write_text(config.read_text().replace("override a value of the budget", "change a value of the budget"))
    args = ["--methods", "sdf", "bof", "--mode", "oracle", "--grid", "24", "--eval-points", "5000", "--limit", "1",
            "--out", str(tmp_path / "run"), "--cache-dir", str(tmp_path / "cache"), "--gallery", "0", "--quiet",
            "--executor", "local"]

    assert main(args) == 0  # this checkout's code, in this process
    assert "(3 run now, 0 done before)" in capsys.readouterr().err
    proc = subprocess.run([sys.executable, str(copy / "run_benchmark.py"), *args], cwd=copy, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "(0 run now, 3 done before)" in proc.stderr.strip().splitlines()[-1]


def test_code_digest_of_another_source_tree_reads_that_trees_files(tmp_path):
    """``root``: the digest of a commit's files (git archive) is computed on them, not on the code
    Python imports: a copy of the metrics gives today's digest, an edited copy another one."""
    import shutil

    from tasks.cache import metric_code_digest

    repo = pathlib.Path(__file__).resolve().parents[1]
    shutil.copytree(repo / "foundation", tmp_path / "foundation", ignore=shutil.ignore_patterns("__pycache__"))
    code_digest.cache_clear()
    assert metric_code_digest(tmp_path) == metric_code_digest()
    edges = tmp_path / "foundation" / "metrics" / "edges.py"
    edges.write_text(edges.read_text() + "\nUNUSED = 1\n")
    code_digest.cache_clear()
    assert metric_code_digest(tmp_path) != metric_code_digest()
    with pytest.raises(ModuleNotFoundError, match="'foundation.metrics' has no source file"):
        code_digest("foundation.metrics", root=tmp_path / "nowhere")
    code_digest.cache_clear()


def test_code_digest_hashes_regenerated_source_not_a_tree_dump():
    """The digest is of the code as ast.unparse writes it (the same text under every Python that
    parses it; a dump of the tree changes its node fields between versions)."""
    from tasks.cache import _code_without_docstrings

    assert _code_without_docstrings('"""Doc."""\ndef f(a,b):\n    "doc"\n    return (a+\n b)  # sum\n', "x.py") == \
        b"def f(a, b):\n    return a + b"
