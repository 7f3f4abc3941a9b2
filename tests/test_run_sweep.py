"""Sweeps as runs (runner.sweep through the command line): one row per sweep point with its
values in ``sweep.<key>`` columns, shared fits for extraction-only sweeps, oracle ceiling rows,
resume after a kill, typed keys and values, config files and the shipped recipes.

Runs use the test-only methods of tests/fake_methods.py (marching cubes on a fitted or exact SDF).
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from runner.cli import EXIT_REFUSED, build_parser, configure, main, recipe_names
from runner.plan import resolve
from runner.sweep import variants
from tests.fake_methods import PLUGIN
from tests.kill_run import kill_after_ok_jobs

REPO = Path(__file__).resolve().parents[1]


def neural_args(out: Path, cache: Path, *extra: str) -> list[str]:
    return ["--methods", "test_sdf", "--mode", "neural", "--budget", "tiny", "--grid", "24", "--eval-points", "5000",
            "--limit", "1", "--out", str(out), "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet",
            "--threads", "1", "--executor", "local", *extra]  # the default executor: test_run_executors


def results(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "results.csv")


def test_variants_are_the_cross_product_first_key_slowest():
    assert variants({"grid": (32, 64), "sals.normals": (True, False)}) == [
        {"grid": 32, "sals.normals": True}, {"grid": 32, "sals.normals": False},
        {"grid": 64, "sals.normals": True}, {"grid": 64, "sals.normals": False}]
    assert variants({}) == [{}]


@pytest.mark.slow
def test_a_2x2_extraction_sweep_gives_four_rows_with_sweep_columns_fits_once_and_reports_it(fakes, tmp_path):
    out = tmp_path / "run"
    code = main(neural_args(out, tmp_path / "cache", "--sweep", "test_sdf.level=0,0.01", "--sweep", "grid=20,24",
                            "--no-ceiling"))
    assert code == 0
    df = results(out)
    assert len(df) == 4 and (df.status == "ok").all()
    assert list(zip(df["sweep.test_sdf.level"], df["sweep.grid"])) == [(0.0, 20), (0.0, 24), (0.01, 20), (0.01, 24)]
    assert list(df["grid"]) == [20, 24, 20, 24]
    assert df["fitted"].sum() == 1  # level and grid change the extraction only: one fit serves all four
    assert df["fit_loss"].nunique() == 1
    assert len(set(df["mesh_path"])) == 4  # every point keeps its own mesh
    assert (out / "sweep.md").is_file() and "Sweep of test\\_sdf.level" in (out / "sweep.md").read_text()
    html = (out / "report.html").read_text()
    assert "Sweep of grid" in html and "<img" in html
    record = json.loads((out / "config.json").read_text())
    assert record["config"]["sweep"] == {"test_sdf.level": [0.0, 0.01], "grid": [20, 24]}


def test_a_sweep_of_a_setting_the_fit_reads_fits_each_value(fakes, tmp_path):
    """test_sdf.offset is a Param(fit=True): it keys the weights, so the two points do not share a fit
    (they would, wrongly, if only the extraction settings were told apart)."""
    out = tmp_path / "run"
    assert main(neural_args(out, tmp_path / "cache", "--sweep", "test_sdf.offset=0,0.02", "--no-ceiling")) == 0
    df = results(out)
    assert list(df["sweep.test_sdf.offset"]) == [0.0, 0.02] and df["fitted"].sum() == 2
    assert df["fit_loss"].nunique() == 2


def test_a_budget_sweep_fits_each_value_and_adds_one_oracle_ceiling(fakes, tmp_path):
    out = tmp_path / "run"
    assert main(neural_args(out, tmp_path / "cache", "--sweep", "budget.steps=20,40")) == 0
    df = results(out)
    neural, oracle = df[df["mode"] == "neural"], df[df["mode"] == "oracle"]
    assert list(neural["sweep.budget.steps"]) == [20, 40] and neural["fitted"].sum() == 2
    assert neural["fit_loss"].nunique() == 2
    # the budget does not apply to the exact field: one ceiling job, its sweep value empty
    assert len(oracle) == 1 and oracle["sweep.budget.steps"].isna().all() and oracle["fitted"].sum() == 0
    info = [json.loads(r[0]) for r in sqlite3.connect(out / "results.db").execute(
        "SELECT info FROM jobs WHERE mode = 'neural'")]
    assert sorted(i["fit_steps"] for i in info) == [20, 40]  # rows come in the order the jobs finished


def test_budget_params_override_the_budget_and_are_recorded(fakes, tmp_path):
    out = tmp_path / "run"
    assert main(neural_args(out, tmp_path / "cache", "--budget-param", "steps=30")) == 0
    record = json.loads((out / "config.json").read_text())
    assert record["config"]["budget_params"] == {"steps": 30}
    assert record["resolved"]["budget"]["encode"]["steps"] == 30
    info = json.loads(sqlite3.connect(out / "results.db").execute("SELECT info FROM jobs").fetchone()[0])
    assert info["fit_steps"] == 30
    assert info["fit_loss_every"] == 20 and len(info["fit_loss_curve"]) == 2  # steps 1-20 and 21-30


def test_the_fits_precision_is_in_config_json_and_every_row(fakes, tmp_path, monkeypatch):
    from methods.core import device
    monkeypatch.setattr(device, "cpu_flags", lambda: frozenset({"avx512_bf16"}))  # bfloat16 is emulated elsewhere
    out = tmp_path / "run"
    assert main(neural_args(out, tmp_path / "cache", "--budget-param", "precision=bfloat16",
                            "--sweep", "seed=0,1", "--no-ceiling")) == 0
    assert json.loads((out / "config.json").read_text())["resolved"]["budget"]["encode"]["precision"] == "bfloat16"
    assert list(results(out)["precision"]) == ["bfloat16", "bfloat16"]
    out32 = tmp_path / "run32"
    assert main(neural_args(out32, tmp_path / "cache")) == 0
    assert list(results(out32)["precision"]) == ["float32"]


def test_bfloat16_is_refused_before_any_work_where_the_cpu_lacks_it(fakes, tmp_path, capsys, monkeypatch):
    from methods.core import device
    monkeypatch.setattr(device, "cpu_flags", lambda: frozenset({"avx2"}))
    out = tmp_path / "run"
    assert main(neural_args(out, tmp_path / "cache", "--budget-param", "precision=bfloat16")) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "precision=bfloat16: this CPU has no bfloat16 instructions" in err, err
    assert not out.exists()


@pytest.mark.parametrize("args, message", [
    (["--sweep", "test_sdf.levle=0,0.01"], "unknown key 'test_sdf.levle'; known keys: budget, grid, eval_points"),
    (["--sweep", "test_sdf.level=0,0.5"], "test_sdf.level='0.5': expected float in (-0.1, 0.1)"),
    (["--sweep", "grid=32,32"], "values must not repeat"),
    (["--sweep", "grid"], "use KEY=V1,V2"),
    (["--sweep", "budget.steps=1,2", "--mode", "oracle"], "oracle mode fits nothing"),
    (["--sweep", "seed=0,1", "--seed", "3"], "both give the seeds"),
    (["--budget-param", "iters=3"], "no method of this run (test_sdf) reads a budget setting 'iters'"),
])
def test_bad_sweeps_are_one_line_naming_the_key(fakes, tmp_path, capsys, args, message):
    out = tmp_path / "run"
    assert main(neural_args(out, tmp_path / "cache", *args)) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()


@pytest.mark.slow
def test_a_sweep_from_a_config_file_is_the_same_run_as_from_the_command_line(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(neural_args(out, cache, "--sweep", "test_sdf.level=0,0.01", "--no-ceiling")) == 0
    toml = tmp_path / "sweep.toml"
    toml.write_text('ceiling = false\n[sweep]\n"test_sdf.level" = [0.0, 0.01]\n')
    # the same protocol: the run directory accepts it and has nothing left to do
    assert main(neural_args(out, cache, "--config", str(toml))) == 0
    assert len(results(out)) == 2


@pytest.mark.parametrize("name", recipe_names())
def test_every_shipped_recipe_resolves_against_the_registry(name, tmp_path):
    args = build_parser().parse_args(["--recipe", name, "--out", str(tmp_path / "r")])
    plan = resolve(configure(args, tmp_path / "r"))
    # the oracle ceiling doubles the points, unless the recipe turns it off (the reconstruct task has none)
    ceiling = 2 if plan.config.task == "encode" and plan.config.ceiling else 1
    assert plan.sweep and len(plan.variants) == ceiling * len(variants(plan.sweep))
    assert {"normals", "o-threshold", "samples", "grid", "faces", "knn", "backbone", "extractors"} <= set(recipe_names())


@pytest.mark.slow
def test_a_killed_sweep_resumes_to_the_uninterrupted_table(tmp_path):
    env = {**os.environ, "SALSBENCH_CACHE": str(tmp_path / "cache")}
    args = ["--methods", "test_sdf", "test_occ", "--mode", "oracle", "--eval-points", "5000", "--limit", "2",
            "--sweep", "grid=20,24", "--sweep", "test_sdf.level=0,0.01", "--no-cache", "--plugin", PLUGIN,
            "--quiet", "--gallery", "0", "--executor", "local"]
    killed = tmp_path / "killed"
    kill_after_ok_jobs(args, killed, env, ok_jobs=2)
    resumed = subprocess.run([sys.executable, "run_benchmark.py", "--resume", "--out", str(killed)], cwd=REPO,
                             capture_output=True, text=True, timeout=600, env=env)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    straight = tmp_path / "straight"
    done = subprocess.run([sys.executable, "run_benchmark.py", *args, "--out", str(straight)], cwd=REPO,
                          capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    columns = ["shape", "method", "sweep.grid", "sweep.test_sdf.level", "status", "cd", "n_faces"]
    a, b = results(killed), results(straight)
    assert len(a) == 2 * (2 + 2 * 2)  # per shape: test_occ at 2 grids, test_sdf at 2 grids x 2 levels
    pd.testing.assert_frame_equal(a[columns], b[columns])


def test_jobs_that_share_a_fit_are_scheduled_after_every_fitting_job(fakes, tmp_path):
    from runner.driver import _schedule
    from runner.plan import build_tasks

    args = build_parser().parse_args(neural_args(tmp_path / "r", tmp_path / "cache", "--limit", "2", "--sweep",
                                                 "test_sdf.level=0,0.01", "--no-ceiling"))
    plan = resolve(configure(args, tmp_path / "r"))
    floors, jobs = build_tasks(plan)
    todo = sorted(floors + jobs, key=_schedule(plan, floors + jobs))
    kinds = [(t.kind, t.shape[:11], t.params.get("level") if t.kind == "job" else None) for t in todo]
    assert kinds == [("job", "builtin_000", 0.0), ("job", "builtin_001", 0.0),
                     ("floor", "builtin_000", None), ("floor", "builtin_001", None),
                     ("job", "builtin_000", 0.01), ("job", "builtin_001", 0.01)]


def test_the_floors_come_after_the_fitting_jobs_to_fill_the_end_of_the_run(tmp_path):
    """The floors, the shortest tasks of an encode run, follow every job that fits, in shape order:
    the last tasks two workers take are floors, not one worker's last fit."""
    from runner.driver import _schedule
    from runner.plan import build_tasks

    args = build_parser().parse_args(["--methods", "sdf", "udf", "--limit", "2", "--out", str(tmp_path / "r")])
    plan = resolve(configure(args, tmp_path / "r"))
    floors, jobs = build_tasks(plan)
    todo = sorted(floors + jobs, key=_schedule(plan, floors + jobs))
    assert [(t.kind, t.shape[8:11], getattr(t, "method", None)) for t in todo] == [
        ("job", "000", "sdf"), ("job", "000", "udf"), ("job", "001", "sdf"), ("job", "001", "udf"),
        ("floor", "000", None), ("floor", "001", None)]


def test_a_method_that_extracts_another_methods_fit_runs_after_every_job_that_fits(tmp_path):
    """``sdf-ndc`` extracts the ``sdf`` network (``fit_of``): its jobs follow every fitting job, so
    two workers never fit the same network at once or wait on each other's fit."""
    from runner.driver import _schedule
    from runner.plan import build_tasks

    args = build_parser().parse_args(["--methods", "sdf", "sdf-ndc", "--limit", "2", "--out", str(tmp_path / "r")])
    plan = resolve(configure(args, tmp_path / "r"))
    floors, jobs = build_tasks(plan)
    todo = sorted(floors + jobs, key=_schedule(plan, floors + jobs))
    assert [(t.kind, t.shape[8:11], getattr(t, "method", None)) for t in todo] == [
        ("job", "000", "sdf"), ("job", "001", "sdf"), ("floor", "000", None), ("floor", "001", None),
        ("job", "000", "sdf-ndc"), ("job", "001", "sdf-ndc")]
    assert len({j.fit_identity() for j in jobs}) == 2  # one fit per shape


def test_a_k_sweep_runs_the_jobs_of_networks_trained_early_while_the_last_one_trains(tmp_path):
    """Reconstruct jobs of one learned network (method, budget, training set) share its training
    across shapes: the first job of each K trains, and the others follow in the order their
    networks are trained, so a worker never waits on K = 50's lock with K = 10 jobs queued behind it."""
    import trimesh

    from runner.driver import _schedule
    from runner.plan import build_tasks

    (tmp_path / "train").mkdir()
    trimesh.creation.box().export(tmp_path / "train" / "box.ply")
    args = build_parser().parse_args(["--task", "reconstruct", "--methods", "sals-knn", "--limit", "3", "--sweep",
                                      "budget.k=10,50", "--train-dir", str(tmp_path / "train"), "--out",
                                      str(tmp_path / "r")])
    plan = resolve(configure(args, tmp_path / "r"))
    floors, jobs = build_tasks(plan)
    todo = sorted(floors + jobs, key=_schedule(plan, floors + jobs))
    order = [(t.kind, t.shape[8:11], t.budget_params.get("k") if t.kind == "job" else None) for t in todo]
    assert order == [("job", "000", 10), ("job", "000", 50), ("floor", "000", None), ("floor", "001", None),
                     ("floor", "002", None), ("job", "001", 10), ("job", "002", 10), ("job", "001", 50),
                     ("job", "002", 50)]
    assert len({j.fit_identity() for j in jobs}) == 2  # one network per K, whatever the shape


def test_jobs_of_a_network_the_cache_holds_keep_the_table_order(tmp_path):
    """A network already in the cache trains in no job: its jobs wait on nothing and run shape by
    shape beside the others (a run stopped part-way has whole shapes); a network not in the cache
    still defers its jobs behind its training."""
    import trimesh

    from methods.base import get_method
    from runner.driver import _schedule, _trained_networks
    from runner.plan import build_tasks
    from tasks.trained_networks import network_path, trained_network_key

    (tmp_path / "train").mkdir()
    trimesh.creation.box().export(tmp_path / "train" / "box.ply")
    cache = tmp_path / "cache"
    args = build_parser().parse_args(["--task", "reconstruct", "--methods", "sals-knn", "--limit", "3", "--sweep",
                                      "budget.k=10,50", "--train-dir", str(tmp_path / "train"), "--cache-dir",
                                      str(cache), "--out", str(tmp_path / "r")])
    plan = resolve(configure(args, tmp_path / "r"))
    floors, jobs = build_tasks(plan)
    k10 = next(j for j in jobs if j.budget_params.get("k") == 10)
    method = get_method(k10.method, **k10.params)
    path = network_path(cache, method, trained_network_key(method, method.budget(k10.budget, k10.budget_params),
                                                   k10.train_dirs)[0])
    path.parent.mkdir(parents=True)
    path.write_bytes(b"weights")
    trained = _trained_networks(floors + jobs)
    assert trained == {k10.fit_identity()}
    todo = sorted(floors + jobs, key=_schedule(plan, floors + jobs, trained))
    order = [(t.kind, t.shape[8:11], t.budget_params.get("k") if t.kind == "job" else None) for t in todo]
    assert order == [("job", "000", 10), ("job", "000", 50), ("job", "001", 10), ("job", "002", 10),
                     ("floor", "000", None), ("floor", "001", None), ("floor", "002", None), ("job", "001", 50),
                     ("job", "002", 50)]


def test_a_per_cloud_optimisation_shares_no_fit_across_jobs(tmp_path):
    """CAP-UDF optimises a field per input cloud: its jobs have no shared fit, so none waits on another."""
    from runner.plan import build_tasks

    args = build_parser().parse_args(["--task", "reconstruct", "--methods", "cap-udf", "--limit", "2", "--out",
                                      str(tmp_path / "r")])
    floors, jobs = build_tasks(resolve(configure(args, tmp_path / "r")))
    assert len(jobs) == 2 and all(j.uses_fitting and j.fit_identity() is None for j in jobs)


def test_a_parameter_only_the_neural_query_reads_gives_one_ceiling_job(tmp_path):
    from runner.plan import build_tasks

    args = build_parser().parse_args(["--methods", "sals", "--limit", "1", "--sweep", "sals.o_threshold=0.1,0.3",
                                      "--sweep", "sals.normals=yes,no", "--out", str(tmp_path / "r")])
    floors, jobs = build_tasks(resolve(configure(args, tmp_path / "r")))
    neural = [j for j in jobs if j.mode == "neural"]
    oracle = [j for j in jobs if j.mode == "oracle"]
    assert len(neural) == 4 and len(oracle) == 2  # the exact field has no o: only normals splits the ceiling
    assert [j.sweep for j in oracle] == [{"sals.normals": True}, {"sals.normals": False}]
    assert all(j.params["o_threshold"] == 0.5 for j in oracle)  # the default, not a swept value
