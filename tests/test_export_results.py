"""scripts/export_results.py: every job of the runs in the CSV's columns, failed ones with NaN
metrics and their status, the input named by the run's task, the commit stamped on every row."""

import json
from pathlib import Path

import numpy as np
import pandas as pd

from tests.scripts import load_script


def _run(path: Path, task: str, corruption: str, rows: list[dict], budget_params: dict | None = None) -> Path:
    path.mkdir()
    config = {"task": task, "pc_corruption": corruption, "budget_params": budget_params or {}}
    (path / "config.json").write_text(json.dumps({"config": config}))
    pd.DataFrame(rows).to_csv(path / "results.csv", index=False)
    return path


def test_every_job_with_its_status_input_and_commit(tmp_path):
    script = load_script("export_results")
    encode = _run(tmp_path / "encode", "encode", "uniform", [
        {"shape": "b", "method": "sals", "seed": 0, "mode": "neural", "budget": "cpu", "status": "ok", "cd": 0.002,
         "ef1": 0.7, "n_faces": 100, "extra_column": 1},
        {"shape": "a", "method": "sals", "seed": 0, "mode": "neural", "budget": "cpu", "status": "failed",
         "error": "fit: FittingError: non-finite loss"}])
    scan = _run(tmp_path / "scan", "reconstruct", "scan", [
        {"shape": "a", "method": "poisson", "seed": 0, "mode": "neural", "status": "ok", "cd": 0.004}])
    out = tmp_path / "out.csv"
    assert script.main([str(encode), str(scan), "--commit", "abc1234", "--out", str(out)]) == 0
    table = pd.read_csv(out)
    assert list(table.columns) == script.COLUMNS
    assert list(zip(table["method"], table["shape"])) == [("poisson", "a"), ("sals", "a"), ("sals", "b")]
    failed = table[table.status == "failed"].iloc[0]
    assert np.isnan(failed["cd"]) and failed["error"].startswith("fit:")
    assert list(table["input"]) == ["scan", "mesh", "mesh"] and set(table["commit"]) == {"abc1234"}
    assert script.main([str(tmp_path / "nope"), "--commit", "x", "--out", str(out)]) == 2


def test_a_changed_budget_is_named_with_its_changes(tmp_path):
    script = load_script("export_results")
    rows = [{"shape": "a", "method": "sals", "seed": 0, "mode": "neural", "budget": "cpu", "status": "ok"},
            {"shape": "a", "method": "udf", "seed": 0, "mode": "oracle", "status": "ok"}]
    changed = _run(tmp_path / "changed", "encode", "uniform", rows, {"steps": 2400, "lr": 0.005})
    out = tmp_path / "out.csv"
    assert script.main([str(changed), "--commit", "c", "--out", str(out)]) == 0
    table = pd.read_csv(out).set_index("method")
    assert table.loc["sals", "budget"] == "cpu lr=0.005 steps=2400"
    assert np.isnan(table.loc["udf", "budget"])  # oracle: nothing fitted
    named = _run(tmp_path / "named", "encode", "uniform", rows[:1])
    assert script.main([str(named), "--commit", "c", "--out", str(out), "--append"]) == 0  # another job
    assert sorted(pd.read_csv(out).budget.dropna()) == ["cpu", "cpu lr=0.005 steps=2400"]


def test_budget_fields_are_each_jobs_value_from_its_sweep_or_the_runs_budget(tmp_path, capsys):
    script = load_script("export_results")
    rows = [{"shape": "a", "method": "sals", "seed": 0, "mode": "neural", "budget": "mlp", "status": "ok",
             "precision": "bfloat16"},
            {"shape": "a", "method": "sdf", "seed": 0, "mode": "oracle", "status": "ok"}]
    fixed = _run(tmp_path / "fixed", "encode", "uniform", rows, {"steps": 4000, "precision": "bfloat16"})
    record = json.loads((fixed / "config.json").read_text())
    record["resolved"] = {"budget": {"encode": {"steps": 4000, "precision": "bfloat16", "lr": 0.001}}}
    (fixed / "config.json").write_text(json.dumps(record))
    swept = _run(tmp_path / "swept", "encode", "uniform", [{**rows[0], "sweep.budget.steps": 8000}])
    (swept / "config.json").write_text(json.dumps({**record, "config": {"task": "encode"}}))
    out = tmp_path / "out.csv"
    assert script.main([str(fixed), str(swept), "--commit", "c", "--out", str(out), "--extra", "precision",
                        "--budget-fields", "steps"]) == 0
    table = pd.read_csv(out)
    assert list(table.columns[-3:]) == ["precision", "steps", "commit"]
    neural = table[table["mode"] == "neural"].sort_values("steps")
    assert list(neural["steps"]) == [4000, 8000] and list(neural["precision"]) == ["bfloat16"] * 2
    assert np.isnan(table.loc[table["mode"] == "oracle", "steps"]).all()
    capsys.readouterr()
    assert script.main([str(fixed), "--commit", "c", "--out", str(out), "--budget-fields", "stesp"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("export_results: --budget-fields:") and "has no field stesp" in err


def test_components_export_one_row_per_job_and_exact_set(tmp_path):
    script = load_script("export_results")
    run = _run(tmp_path / "run", "encode", "uniform", [{"shape": "a", "method": "sals", "seed": 0, "status": "ok"}])
    pd.DataFrame([
        {"shape": "a", "method": "sals", "seed": 0, "exact": "normals", "cd": 0.002, "ef1": 0.9, "n_faces": 10,
         "extract_s": 0.1, "component_hash": "h"},
        {"shape": "a", "method": "sals", "seed": 0, "exact": "flags", "cd": 0.001, "ef1": 0.8, "n_faces": 12,
         "extract_s": 0.2, "component_hash": "h"}]).to_csv(run / "components.csv", index=False)
    out = tmp_path / "out.csv"
    assert script.main([str(run), "--components", "--commit", "abc1234", "--out", str(out)]) == 0
    table = pd.read_csv(out)
    assert list(table.columns) == script.COMPONENT_COLUMNS
    assert list(table["exact"]) == ["flags", "normals"] and list(table["ef1"]) == [0.8, 0.9]
    (run / "components.csv").unlink()
    assert script.main([str(run), "--components", "--commit", "x", "--out", str(out)]) == 2


def test_append_keeps_each_rows_commit_and_refuses_a_job_twice(tmp_path):
    script = load_script("export_results")
    first = _run(tmp_path / "first", "encode", "uniform", [
        {"shape": "a", "method": "sdf", "seed": 0, "mode": "neural", "status": "ok", "cd": 0.002}])
    later = _run(tmp_path / "later", "encode", "uniform", [
        {"shape": "a", "method": "nglod", "seed": 0, "mode": "neural", "status": "ok", "cd": 0.003}])
    out = tmp_path / "out.csv"
    assert script.main([str(later), "--commit", "b", "--out", str(out), "--append"]) == 2  # nothing to append to
    assert script.main([str(first), "--commit", "a", "--out", str(out)]) == 0
    assert script.main([str(later), "--commit", "b", "--out", str(out), "--append"]) == 0
    table = pd.read_csv(out)
    assert list(zip(table["method"], table["commit"])) == [("nglod", "b"), ("sdf", "a")]
    assert script.main([str(later), "--commit", "c", "--out", str(out), "--append"]) == 2
    assert len(pd.read_csv(out)) == 2


def test_replace_failed_puts_an_ok_rerun_in_place_of_the_failed_job_only(tmp_path):
    script = load_script("export_results")
    first = _run(tmp_path / "first", "reconstruct", "uniform", [
        {"shape": "a", "method": "cap-udf", "seed": 0, "mode": "neural", "status": "failed", "error": "SIGSEGV"},
        {"shape": "b", "method": "cap-udf", "seed": 0, "mode": "neural", "status": "ok", "cd": 0.004}])
    rerun = _run(tmp_path / "rerun", "reconstruct", "uniform", [
        {"shape": "a", "method": "cap-udf", "seed": 0, "mode": "neural", "status": "ok", "cd": 0.002},
        {"shape": "b", "method": "cap-udf", "seed": 0, "mode": "neural", "status": "ok", "cd": 0.004}])
    out = tmp_path / "out.csv"
    assert script.main([str(first), "--commit", "a", "--out", str(out)]) == 0
    assert script.main([str(rerun), "--commit", "b", "--out", str(out), "--replace-failed"]) == 2  # needs --append
    # b is ok in the CSV: its repeat is refused, and nothing is written
    assert script.main([str(rerun), "--commit", "b", "--out", str(out), "--append", "--replace-failed"]) == 2
    assert list(pd.read_csv(out)["status"]) == ["failed", "ok"]
    only_a = _run(tmp_path / "only_a", "reconstruct", "uniform", [
        {"shape": "a", "method": "cap-udf", "seed": 0, "mode": "neural", "status": "ok", "cd": 0.002}])
    assert script.main([str(only_a), "--commit", "b", "--out", str(out), "--append", "--replace-failed"]) == 0
    table = pd.read_csv(out)
    assert list(zip(table["shape"], table["status"], table["cd"], table["commit"])) == [
        ("a", "ok", 0.002, "b"), ("b", "ok", 0.004, "a")]


def test_cost_adds_the_grid_seconds_and_peak_memory_of_each_job(tmp_path):
    """--cost: a job's grid and stage seconds from results.csv, its worker's peak memory from its
    info in results.db; the same job at two grids is two rows."""
    import sqlite3

    script = load_script("export_results")
    rows = [{"shape": "a", "method": "sdf", "seed": 0, "mode": "oracle", "status": "ok", "grid": N, "query_s": 1.0,
             "extract_s": 0.5 * N, "total_s": 3.0, "config_hash": f"k{N}"} for N in (64, 128)]
    run = _run(tmp_path / "run", "encode", "uniform", rows)
    with sqlite3.connect(run / "results.db") as con:
        con.execute("CREATE TABLE jobs (config_hash TEXT, info TEXT)")
        con.executemany("INSERT INTO jobs VALUES (?, ?)", [("k64", json.dumps({"peak_rss_mib": 512.5})),
                                                           ("k128", json.dumps({}))])
    out = tmp_path / "out.csv"
    assert script.main([str(run), "--cost", "--commit", "c", "--out", str(out)]) == 0
    table = pd.read_csv(out)
    assert list(table.columns) == script.COLUMNS[:-1] + script.COST_COLUMNS + ["commit"]
    assert list(table["grid"]) == [64, 128] and list(table["extract_s"]) == [32.0, 64.0]
    assert table["peak_rss_mib"].iloc[0] == 512.5 and np.isnan(table["peak_rss_mib"].iloc[1])


def test_where_and_complete_shapes_keep_a_stopped_runs_finished_shapes(tmp_path):
    script = load_script("export_results")
    rows = [{"shape": s, "method": m, "seed": 0, "mode": mode, "status": "ok", "cd": 0.001}
            for s, methods in (("a", ("sals", "sdf")), ("b", ("sals",))) for m in methods
            for mode in ("neural", "oracle")]
    run = _run(tmp_path / "run", "encode", "uniform", rows)
    out = tmp_path / "out.csv"
    assert script.main([str(run), "--where", "mode=oracle", "--complete-shapes", "--commit", "c", "--out",
                        str(out)]) == 0
    table = pd.read_csv(out)
    assert set(table["mode"]) == {"oracle"} and list(zip(table["shape"], table["method"])) == [("a", "sals"),
                                                                                                 ("a", "sdf")]
    assert script.main([str(run), "--where", "nope", "--commit", "c", "--out", str(out)]) == 2
