"""Whole runs through the command line (runner.cli, run_benchmark.py): bad options refused
with one line before any work, the output contract, failures and exit codes, resume, one protocol
and one writer per run directory, caches, reproduction from config.json and the report subcommand.

Runs use the test-only methods of tests/fake_methods.py on the exact fields (oracle mode), so they
do not depend on the real methods' fitting budgets.
"""

from __future__ import annotations

import fcntl
import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from runner.cli import EXIT_FAILED_TASKS, EXIT_REFUSED, main
from foundation.schema import csv_lead
from tests.fake_methods import PLUGIN

REPO = Path(__file__).resolve().parents[1]


def oracle_args(out: Path, cache: Path, *extra: str) -> list[str]:
    """A small oracle run; jobs run in the driver (the default executor has its tests in test_run_executors)."""
    return ["--methods", "test_sdf", "test_occ", "--mode", "oracle", "--grid", "32", "--eval-points", "20000",
            "--limit", "2", "--out", str(out), "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet",
            "--executor", "local", *extra]


def read_results(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "results.csv")


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


# ---------------------------------------------------------------------------------------------
# refused up front: one line, exit 2, nothing created
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("args, message", [
    (["--methods", "nope"], "unknown method 'nope'; known methods: test_sdf"),
    (["--grid", "4"], "--grid='4': expected int in [8, inf)"),
    (["--grid", "big"], "--grid='big': expected int"),
    (["--grid", "100000"], "more than this machine's"),                     # bounded by memory
    (["--eval-points", "10"], "--eval-points='10': expected int in [1000, inf)"),
    (["--dataset", "meshes", "--data-dir", "/no/such/dir"], "--data-dir /no/such/dir: does not exist"),
    (["--list", "/no/such/list.txt"], "--list /no/such/list.txt: does not exist"),
    (["--dataset", "nosuch"], "unknown dataset 'nosuch'"),
    (["--method-param", "test_sdf.nope=1"], "has no parameter 'nope'"),
    (["--method-param", "bogus"], "METHOD.NAME=VALUE"),
    (["--method-param", "test_sdf.level=notanumber"], "expected float"),
    (["--method-param", "test_sdf.level=0.5"], "expected float in (-0.1, 0.1)"),
    (["--seed", "1", "-1"], "--seed='-1': expected tuple of int in [0, 2^63-1]"),
    (["--seed", str(2**63)], "expected tuple of int in [0, 2^63-1]"),
    (["--workers", "0"], "--workers='0': expected int in [1, inf)"),
    (["--executor", "local", "--workers", "2"], "--workers applies to --executor auto, process or ray"),
    (["--executor", "cluster"], "unknown executor"),
    (["--address", "auto"], "--address only applies to --executor ray"),
    (["--limit", "0"], "--limit='0': expected int in [1, inf)"),
    (["--plugin", "no_such_module_xyz"], "--plugin no_such_module_xyz"),
    (["--budget", "paper"], "--budget needs --mode neural (oracle mode fits nothing)"),
])
def test_bad_options_fail_with_one_line_before_any_work(fakes, tmp_path, capsys, args, message):
    out = tmp_path / "run"
    base = ["--methods", "test_sdf", "--mode", "oracle", "--out", str(out), "--plugin", PLUGIN]
    assert main(base + args) == EXIT_REFUSED
    assert message in one_error_line(capsys)
    assert not out.exists()  # nothing was started


@pytest.mark.parametrize("text, ok", [("no", False), ("False", False), ("0", False), ("off", False),
                                      ("YES", True), ("true", True), ("1", True), ("maybe", None)])
def test_boolean_method_params_parse_as_booleans(tmp_path, capsys, text, ok):
    """sals.normals=False is False, not True (as bool() of any non-empty string would be)."""
    from runner.cli import parse_method_params

    if ok is None:
        with pytest.raises(ValueError, match="expected bool"):
            parse_method_params([f"sals.normals={text}"], ())
    else:
        assert parse_method_params([f"sals.normals={text}"], ()) == {"sals": {"normals": ok}}


def test_paths_that_cannot_be_written_are_one_line(fakes, tmp_path, capsys):
    """--out under a file, --cache-dir that is a file."""
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    assert main(oracle_args(a_file / "run", tmp_path / "cache")) == EXIT_REFUSED
    assert "is a file, not a directory" in one_error_line(capsys)
    assert main(oracle_args(a_file, tmp_path / "cache")) == EXIT_REFUSED
    assert "exists and is not a directory" in one_error_line(capsys)
    assert main(oracle_args(tmp_path / "run", a_file)) == EXIT_REFUSED
    assert "--cache-dir" in one_error_line(capsys)


def test_unwritable_out_dir_is_one_line(fakes, tmp_path, capsys, monkeypatch):
    """a read-only --out (simulated: the suite may run as root, who can write anywhere)."""
    import errno

    real_write = Path.write_bytes

    def refuse(self, data):
        if self.name.startswith(".salsbench-write-test"):
            raise OSError(errno.EROFS, "Read-only file system")
        return real_write(self, data)

    monkeypatch.setattr(Path, "write_bytes", refuse)
    assert main(oracle_args(tmp_path / "run", tmp_path / "cache")) == EXIT_REFUSED
    assert "not writable (read-only file system)" in one_error_line(capsys)


def test_help_and_bad_flag_through_the_script():
    py = sys.executable
    proc = subprocess.run([py, "run_benchmark.py", "--help"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0
    for option in ("--methods", "--dataset", "--grid", "--eval-points", "--executor", "--resume", "--config"):
        assert option in proc.stdout
    proc = subprocess.run([py, "run_benchmark.py", "--grid", "3", "--mode", "oracle"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0 and "--grid" in proc.stderr


# ---------------------------------------------------------------------------------------------
# a whole run: contract, failures, exit codes
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_oracle_run_writes_the_contract(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache)) == 0
    df = read_results(out)
    assert list(df.columns[: len(csv_lead())]) == csv_lead()
    assert len(df) == 4 and (df.status == "ok").all()
    record = json.loads((out / "config.json").read_text())
    shapes = record["resolved"]["shapes"]
    assert len(shapes) == 2
    assert list(df["shape"]) == [shapes[0]] * 2 + [shapes[1]] * 2          # table order: shape, then method
    assert list(df["method"]) == ["test_sdf", "test_occ"] * 2
    h = 2 / 31  # exact-field marching cubes on a 32^3 grid: within a fraction of a cell of the GT
    assert (df["cd"] < h).all() and (df["cd"] > 0).all()
    assert (df["n_faces"] > 100).all() and (df["extract_s"] >= 0).all() and (df["metrics_s"] > 0).all()
    assert (df["query_s"] > 0).all() and df["fit_s"].isna().all()          # oracle mode fits nothing
    import trimesh

    for r in df.itertuples():
        mesh = trimesh.load(out / "meshes" / r.shape / f"{r.method}.ply", process=False)
        assert len(mesh.faces) == r.n_faces and len(mesh.vertices) == r.n_vertices
        assert np.abs(mesh.vertices).max() <= 1.0
    for s in shapes:
        assert (out / "meshes" / s / "gt.ply").is_file()
    floor = pd.read_csv(out / "floor.csv")
    assert list(floor["shape"]) == shapes and (floor["status"] == "ok").all()
    assert (floor["cd"] < df.groupby("shape")["cd"].min().reindex(shapes).to_numpy()).all()  # GT vs itself is best
    assert record["config"]["grid"] == 32 and record["config"]["methods"] == ["test_sdf", "test_occ"]
    assert record["resolved"]["eval_points"] == 20000 and "F1 thresholds" in record["resolved"]["protocol"]
    env = record["environment"]
    assert {"numpy", "torch", "trimesh", "scipy", "pandas"} <= set(env["versions"]) and "cpu_model" in env
    with sqlite3.connect(out / "results.db") as con:
        n, hashes = con.execute("SELECT count(*), count(DISTINCT config_hash) FROM jobs").fetchone()
    assert n == hashes == 4


def test_failing_job_is_recorded_the_run_goes_on_and_the_exit_says_so(fakes, tmp_path, capsys):
    """the last line counts ok and failed jobs and the exit status is 3."""
    out, cache = tmp_path / "run", tmp_path / "cache"
    args = oracle_args(out, cache)
    args[args.index("test_occ")] = "test_broken"
    assert main(args) == EXIT_FAILED_TASKS
    assert "salsbench: 4 ok, 2 failed" in capsys.readouterr().err.strip().splitlines()[-1]  # 2 floors + 2 jobs ok
    df = read_results(out)
    ok, failed = df[df.method == "test_sdf"], df[df.method == "test_broken"]
    assert (ok.status == "ok").all() and len(ok) == 2
    assert (failed.status == "failed").all() and len(failed) == 2
    assert (failed.error == "extracting: RuntimeError: boom: extractor failed").all()  # one line, with the stage
    assert failed.cd.isna().all()
    with sqlite3.connect(out / "results.db") as con:
        tb = con.execute("SELECT traceback FROM jobs WHERE status='failed'").fetchone()[0]
    assert "second line" in tb and "Traceback" in tb


@pytest.mark.slow
def test_every_job_failing_is_a_nonzero_exit_through_the_script(tmp_path):
    proc = subprocess.run([sys.executable, "run_benchmark.py", *oracle_args(tmp_path / "run", tmp_path / "c"),
                           "--methods", "test_broken"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == EXIT_FAILED_TASKS
    assert proc.stderr.strip().splitlines()[-1].startswith("salsbench: 2 ok, 2 failed")  # the floors are ok


# ---------------------------------------------------------------------------------------------
# resume, one protocol per directory, one writer at a time
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_rerun_skips_finished_jobs_and_retries_failed(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache, "--no-cache")) == 0
    before = read_results(out).set_index(["shape", "method"])
    with sqlite3.connect(out / "results.db") as con:  # pretend one job failed
        con.execute("UPDATE jobs SET status='failed', cd=NULL WHERE rowid = (SELECT min(rowid) FROM jobs)")
    assert main(["--resume", "--out", str(out), "--quiet"]) == 0
    after = read_results(out).set_index(["shape", "method"])
    assert (after.status == "ok").all() and len(after) == 4
    rerun = after.finished != before.finished
    assert rerun.sum() == 1                                          # only the failed job ran again
    assert int(after.loc[rerun, "attempts"].iloc[0]) == 2
    pd.testing.assert_series_equal(after.cd, before.cd)               # and reproduced its numbers exactly


@pytest.mark.slow
def test_second_resume_keeps_the_saved_configuration(fakes, tmp_path):
    """after one --resume, the next one runs the saved configuration, not the defaults (builtin,
    neural, all methods)."""
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache)) == 0
    saved = json.loads((out / "config.json").read_text())["config"]
    for _ in range(2):
        assert main(["--resume", "--out", str(out), "--quiet"]) == 0
        assert json.loads((out / "config.json").read_text())["config"] == saved
    df = read_results(out)
    assert len(df) == 4 and set(df.method) == {"test_sdf", "test_occ"} and (df["mode"] == "oracle").all()


def test_an_invocation_with_nothing_left_keeps_the_record_of_those_that_ran_the_tasks(fakes, tmp_path, monkeypatch):
    """config.json and the timing caption name how the rows were computed: an invocation that finds
    every task done (here with another thread count, then another executor) changes neither and
    starts no pool to draw its report; one that runs tasks differently is added as a session, and the
    caption names both with their task counts."""
    from runner import executors

    out, cache = tmp_path / "run", tmp_path / "cache"
    args = oracle_args(out, cache, "--threads", "1")
    args.remove("test_occ")
    assert main(args) == 0
    first = json.loads((out / "config.json").read_text())
    assert first["execution"] == {"executor": "local", "workers": 1, "threads_per_job": 1}
    assert [s["tasks"] for s in first["sessions"]] == [4]  # 2 shapes: 2 jobs and 2 floors

    again = json.loads((out / "config.json").read_text())
    for key in ("execution", "started", "environment", "sessions"):
        assert again[key] == first[key], key
    assert "executor local, 1 worker x 1 torch thread." in (out / "timing.md").read_text()
    assert main(["--resume", "--out", str(out), "--quiet", "--threads", "2", "--methods", "test_occ"]) == 0
    added = json.loads((out / "config.json").read_text())
    assert [s["tasks"] for s in added["sessions"]] == [4, 2]
    assert added["execution"]["threads_per_job"] == 2 and added["sessions"][0] == first["sessions"][0]
    assert ("executor local, 1 worker x 1 torch thread (4 tasks); executor local, 1 worker x 2 torch threads "
            "(2 tasks).") in (out / "timing.md").read_text()

    def no_pool(self):
        raise AssertionError("a process pool was started")

    monkeypatch.setattr(executors.ProcessExecutor, "_new_pool", no_pool)
    (out / "report.html").unlink()
    assert main(["--resume", "--out", str(out), "--quiet", "--executor", "process", "--workers", "2"]) == 0
    assert (out / "report.html").is_file() and json.loads((out / "config.json").read_text())["sessions"] == added["sessions"]


def test_a_different_protocol_is_refused_naming_the_settings(fakes, tmp_path, capsys):
    """--resume with another grid is refused: one table never mixes two grids."""
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache)) == 0
    capsys.readouterr()
    assert main(["--resume", "--out", str(out), "--grid", "40", "--eval-points", "30000"]) == EXIT_REFUSED
    line = one_error_line(capsys)
    assert "grid=32 there, 40 now" in line and "eval_points=20000 there, 30000 now" in line
    args = oracle_args(out, cache)
    args[args.index("32")] = "40"
    assert main(args) == EXIT_REFUSED  # without --resume too
    assert "--resume continues it" in one_error_line(capsys)
    with sqlite3.connect(out / "results.db") as con:
        assert {r[0] for r in con.execute("SELECT DISTINCT grid FROM jobs")} == {32}


@pytest.mark.slow
def test_adding_a_method_to_a_run_keeps_its_protocol(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    args = oracle_args(out, cache)
    args.remove("test_occ")
    assert main(args) == 0
    assert main(["--resume", "--out", str(out), "--methods", "test_occ", "--quiet"]) == 0
    df = read_results(out)
    assert list(df.method) == ["test_sdf", "test_occ"] * 2
    assert json.loads((out / "config.json").read_text())["config"]["methods"] == ["test_sdf", "test_occ"]


def test_a_locked_run_directory_is_refused_naming_its_holder(fakes, tmp_path, capsys):
    """two runs into one --out: the second is refused, only one writes."""
    out = tmp_path / "run"
    out.mkdir()
    fd = os.open(out / ".salsbench.lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, b"pid 4242 on otherhost (run_benchmark.py --grid 64, since yesterday)")
        assert main(oracle_args(out, tmp_path / "cache")) == EXIT_REFUSED
        assert "is in use by pid 4242 on otherhost" in one_error_line(capsys)
        assert not (out / "results.db").exists()
    finally:
        os.close(fd)
    assert main(oracle_args(out, tmp_path / "cache")) == 0  # released: the next run goes ahead


@pytest.mark.slow
def test_concurrent_runs_into_one_directory_do_not_mix(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "run_benchmark.py", *oracle_args(out, tmp_path / "c")]
    other = list(cmd)
    other[other.index("32")] = "40"
    procs = [subprocess.Popen(c, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for c in (cmd, other)]
    codes = sorted(p.wait(timeout=600) for p in procs)
    assert codes == [0, EXIT_REFUSED]
    with sqlite3.connect(out / "results.db") as con:
        assert len({r[0] for r in con.execute("SELECT DISTINCT grid FROM jobs")}) == 1


# ---------------------------------------------------------------------------------------------
# caches, reproduction, report
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_mesh_cache_is_reused_across_runs(fakes, tmp_path):
    cache = tmp_path / "cache"
    assert main(oracle_args(tmp_path / "a", cache)) == 0
    assert main(oracle_args(tmp_path / "b", cache)) == 0
    a, b = read_results(tmp_path / "a"), read_results(tmp_path / "b")
    assert (a["cache"].isna() | (a["cache"] == "fields")).all() and (b["cache"] == "mesh").all()
    metric_cols = ["cd", "nc", "f1_005", "f1_01", "ecd", "ef1", "n_vertices", "n_faces"]
    pd.testing.assert_frame_equal(a[metric_cols], b[metric_cols])
    assert (cache / "fields").is_dir() and any((cache / "meshes").iterdir())


def test_no_cache_writes_no_cache_file(fakes, tmp_path, monkeypatch):
    monkeypatch.setenv("SALSBENCH_CACHE", str(tmp_path / "env-cache"))
    args = oracle_args(tmp_path / "run", tmp_path / "cache", "--no-cache")
    assert main(args) == 0
    assert not (tmp_path / "cache").exists() and not (tmp_path / "env-cache").exists()


@pytest.mark.slow
def test_a_run_is_reproduced_from_its_own_config(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache, "--seed", "3")) == 0
    again = tmp_path / "again"
    assert main(["--config", str(out / "config.json"), "--out", str(again), "--no-cache", "--quiet"]) == 0
    cols = ["shape", "method", "seed", "status", "cd", "nc", "f1_005", "ecd", "ef1", "n_faces"]
    pd.testing.assert_frame_equal(read_results(out)[cols], read_results(again)[cols])


def test_config_files_with_unknown_settings_are_refused(fakes, tmp_path, capsys):
    cfg = tmp_path / "run.toml"
    cfg.write_text('mode = "oracle"\ngird = 32\n')
    assert main(["--config", str(cfg), "--out", str(tmp_path / "x")]) == EXIT_REFUSED
    assert "unknown setting(s) gird; known: task, dataset" in one_error_line(capsys)
    assert main(["--config", str(cfg), "--resume", "--out", str(tmp_path / "x")]) == EXIT_REFUSED
    assert "give one" in one_error_line(capsys)
    cfg.write_text('mode = "oracle"\ngrid = "big"\n')
    assert main(["--config", str(cfg), "--out", str(tmp_path / "x")]) == EXIT_REFUSED
    assert "grid='big': expected int in [8, inf)" in one_error_line(capsys)


@pytest.mark.slow
def test_report_subcommand_regenerates_results(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache)) == 0
    again = tmp_path / "again"
    assert main(["report", str(out), "--out", str(again)]) == 0
    pd.testing.assert_frame_equal(read_results(out), read_results(again))
    assert main(["report", str(tmp_path / "nothing")]) == 2
    # a run stopped before the second shape's last job: --complete-shapes reports the first shape only
    full = read_results(out)
    second = full["shape"].iloc[-1]
    with sqlite3.connect(out / "results.db") as db:
        db.execute("DELETE FROM jobs WHERE shape = ? AND method = ?", (second, full["method"].iloc[-1]))
    assert main(["report", str(out), "--complete-shapes", "--out", str(tmp_path / "complete")]) == 0
    complete = read_results(tmp_path / "complete")
    assert set(complete["shape"]) == {full["shape"].iloc[0]} and len(complete) == 2
    assert "(1 shape of the run's 2: those whose every job finished)" in (tmp_path / "complete" / "summary.md").read_text()
    assert main(["report", str(out), str(again), "--complete-shapes"]) == 2


def test_neural_run_fits_caches_weights_and_records_nan_loss(fakes, tmp_path):
    cache = tmp_path / "cache"
    args = ["--methods", "test_sdf", "test_nan", "--mode", "neural", "--budget", "tiny", "--grid", "24",
            "--eval-points", "5000", "--limit", "1", "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet",
            "--threads", "1", "--executor", "local"]
    assert main(args + ["--out", str(tmp_path / "a")]) == EXIT_FAILED_TASKS
    a = read_results(tmp_path / "a").set_index("method")
    assert a.loc["test_sdf", "status"] == "ok", a.loc["test_sdf", "error"]
    assert a.loc["test_sdf", "fit_s"] > 0 and a.loc["test_sdf", "sample_s"] > 0 and a.loc["test_sdf", "label_s"] > 0
    assert np.isfinite(a.loc["test_sdf", "fit_loss"]) and a.loc["test_sdf", "n_faces"] > 0
    assert a.loc["test_nan", "status"] == "failed"
    assert a.loc["test_nan", "error"].startswith("fitting: FittingError: non-finite loss")
    # another extractor parameter: the mesh is new, the fitted weights come from the cache, same fit
    args[args.index("test_nan")] = "test_sdf"
    assert main(args + ["--out", str(tmp_path / "b"), "--method-param", "test_sdf.level=0.01"]) == 0
    b = read_results(tmp_path / "b").set_index("method")
    assert b.loc["test_sdf", "cache"] == "weights" and b.loc["test_sdf", "fit_loss"] == a.loc["test_sdf", "fit_loss"]
    assert np.isnan(b.loc["test_sdf", "fit_s"])  # no fitting happened in this run


@pytest.mark.slow
def test_registered_methods_oracle_end_to_end(tmp_path):
    from methods.base import available_methods

    methods = available_methods()
    out = tmp_path / "run"
    code = main(["--mode", "oracle", "--grid", "32", "--eval-points", "20000", "--limit", "1",
                 "--out", str(out), "--cache-dir", str(tmp_path / "cache"), "--quiet", "--executor", "local"])
    assert code == 0
    df = read_results(out)
    assert list(df.method) == methods and (df.status == "ok").all(), df[["method", "error"]]
    assert (df.cd < 2 / 31).all()


@pytest.mark.slow
def test_checkpoints_give_one_row_each_with_increasing_step_and_an_anytime_plot(fakes, tmp_path):
    out = tmp_path / "run"
    args = ["--methods", "test_sdf", "--mode", "neural", "--budget", "tiny", "--grid", "24", "--eval-points", "5000",
            "--limit", "1", "--cache-dir", str(tmp_path / "cache"), "--plugin", PLUGIN, "--quiet", "--threads", "1",
            "--executor", "local", "--checkpoints", "0.25,0.5,1", "--out", str(out)]
    assert main(args) == 0
    ck = pd.read_csv(out / "checkpoints.csv")
    job = read_results(out).iloc[0]
    assert list(ck["fraction"]) == [0.25, 0.5, 1.0] and list(ck["step"]) == [50, 100, 200]  # tiny: 200 steps
    assert ck["fit_elapsed_s"].is_monotonic_increasing and ck["fit_elapsed_s"].iloc[-1] <= job["fit_s"]
    assert job["checkpoints_s"] > 0  # their scoring is timed apart from the fit
    assert ck["cd"].iloc[-1] == job["cd"] and ck["n_faces"].iloc[-1] == job["n_faces"]  # the last one is the job
    assert "Anytime curves" in (out / "report.html").read_text()
    # the checkpoints do not change the fit: the same job without them gives the same numbers
    plain = tmp_path / "plain"
    assert main(args[: args.index("--checkpoints")] + ["--out", str(plain), "--no-cache"]) == 0
    assert read_results(plain).iloc[0]["cd"] == job["cd"]


@pytest.mark.parametrize("value, message", [("0.5,0.25", "increasing fractions"), ("0,1", "in (0, 1]"),
                                            ("half", "--checkpoints='half': expected tuple of float in (0, 1]")])
def test_bad_checkpoints_are_refused(fakes, tmp_path, capsys, value, message):
    args = ["--methods", "test_sdf", "--budget", "tiny", "--out", str(tmp_path / "r"), "--plugin", PLUGIN]
    try:
        code = main(args + ["--checkpoints", value])
    except SystemExit as exc:  # argparse's own one-line error
        code = exc.code
    assert code == EXIT_REFUSED and message in one_error_line(capsys)
    oracle = ["--methods", "test_sdf", "--out", str(tmp_path / "r"), "--plugin", PLUGIN, "--mode", "oracle"]
    assert main(oracle + ["--checkpoints", "0.5"]) == EXIT_REFUSED
    assert "--checkpoints needs --mode neural" in one_error_line(capsys)


def test_run_directories_of_an_older_format_are_refused_with_one_line(fakes, tmp_path, capsys):
    old = tmp_path / "old"
    old.mkdir()
    (old / "config.json").write_text(json.dumps({"options": {"grid": 64}, "environment": {}, "grid": 64}))
    assert main(oracle_args(old, tmp_path / "cache")) == EXIT_REFUSED
    assert "written by an older salsbench" in one_error_line(capsys)
    older = tmp_path / "older"
    older.mkdir()
    with sqlite3.connect(older / "results.db") as con:
        con.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
        con.execute("INSERT INTO meta VALUES ('schema_version', '1')")
    assert main(oracle_args(older, tmp_path / "cache")) == EXIT_REFUSED
    assert "results database schema 1, this version reads 3" in one_error_line(capsys)
    assert not (older / "config.json").exists()  # refused before anything was written


PROBE = '''
from methods.base import METHODS, Extraction
from tests.fake_methods import FakeSDF


class Probe(FakeSDF):
    name = "test_probe"

    def extract(self, grid_field, N):
        ex = super().extract(grid_field, N)
        return Extraction(ex.vertices * {scale}, ex.faces)


def register():
    METHODS.unregister(Probe.name)
    METHODS.register(Probe.name, Probe)
'''


@pytest.mark.slow
def test_a_changed_method_is_refused_in_its_run_directory_or_recomputed_on_request(fakes, tmp_path, monkeypatch,
                                                                                    capsys):
    """A run directory never mixes two versions of the code: after the probe method's extractor
    changes (meshes scaled by 1.0 -> 1.1), re-running into the same --out is refused with one line;
    with --recompute-stale its job runs again and gives the new result (the other method's jobs,
    whose code did not change, are kept)."""
    import sys

    from tasks.cache import code_digest
    from methods.base import METHODS

    monkeypatch.syspath_prepend(str(tmp_path))
    probe = tmp_path / "zz_probe_method.py"
    out = tmp_path / "run"
    args = ["--methods", "test_probe", "test_occ", "--mode", "oracle", "--grid", "32", "--eval-points", "20000",
            "--limit", "1", "--out", str(out), "--no-cache", "--plugin", PLUGIN,
            "--plugin", "zz_probe_method:register", "--quiet", "--executor", "local"]

    def run(source, *extra):
        probe.write_text(source)
        sys.modules.pop("zz_probe_method", None)
        code_digest.cache_clear()
        return main([*args, *extra])

    try:
        assert run(PROBE.format(scale="1.0")) == 0
        before = read_results(out).set_index("method")
        capsys.readouterr()
        assert run(PROBE.format(scale="1.1")) == EXIT_REFUSED
        line = one_error_line(capsys)
        assert "1 finished jobs rows (test_probe) were computed by other code" in line and "--recompute-stale" in line
        assert run(PROBE.format(scale="1.1"), "--recompute-stale") == 0
        after = read_results(out).set_index("method")
        assert after.at["test_probe", "finished"] != before.at["test_probe", "finished"]
        assert after.at["test_probe", "cd"] > 2 * before.at["test_probe", "cd"]  # the new code's result
        assert after.at["test_occ", "finished"] == before.at["test_occ", "finished"]  # unchanged code: kept
    finally:
        METHODS.unregister("test_probe")
        sys.modules.pop("zz_probe_method", None)
        code_digest.cache_clear()


def test_a_mesh_over_the_face_limit_fails_its_jobs_in_one_line_and_the_run_goes_on(fakes, tmp_path):
    import trimesh

    meshes = tmp_path / "meshes"
    meshes.mkdir()
    trimesh.creation.icosphere(5).export(meshes / "big.ply")  # 20,480 faces
    trimesh.creation.box().export(meshes / "small.ply")  # 12 faces
    out = tmp_path / "run"
    code = main(["--methods", "test_sdf", "--mode", "oracle", "--dataset", "meshes", "--data-dir", str(meshes),
                 "--grid", "24", "--eval-points", "5000", "--max-faces", "10000", "--out", str(out),
                 "--cache-dir", str(tmp_path / "cache"), "--plugin", PLUGIN, "--quiet", "--executor", "local"])
    assert code == EXIT_FAILED_TASKS
    df = read_results(out).set_index("shape")
    assert df.loc["small", "status"] == "ok" and df.loc["big", "status"] == "failed"
    assert df.loc["big", "error"] == (f"loading: ShapeTooLarge: {meshes / 'big.ply'}: stores 20,480 faces, over the "
                                      f"limit of 10,000 (--max-faces); not read")


def test_a_file_whose_header_declares_too_many_faces_is_refused_before_its_body_is_read(fakes, tmp_path):
    """The header says 30M faces, the body holds none: a loader would fail on the body; the size
    check refuses the file on its header alone, which is what bounds a job's memory."""
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    (meshes / "huge.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                                      b"property float y\nproperty float z\nelement face 30000000\n"
                                      b"property list uchar int vertex_indices\nend_header\n")
    out = tmp_path / "run"
    code = main(["--methods", "test_sdf", "--mode", "oracle", "--dataset", "meshes", "--data-dir", str(meshes),
                 "--grid", "24", "--eval-points", "5000", "--out", str(out), "--cache-dir", str(tmp_path / "cache"),
                 "--plugin", PLUGIN, "--quiet", "--executor", "local"])
    assert code == EXIT_FAILED_TASKS
    df = read_results(out)
    assert list(df.error) == [f"loading: ShapeTooLarge: {meshes / 'huge.ply'}: stores 30,000,000 faces, over the "
                              f"limit of 5,000,000 (--max-faces); not read"]


def test_pc_points_over_the_point_limit_are_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["--task", "reconstruct", "--methods", "poisson", "--pc-points", "2000", "--max-points", "1000",
                 "--out", str(out)]) == EXIT_REFUSED
    assert "--pc-points 2000 is over the limit of 1000 points a job may hold (--max-points)" in one_error_line(capsys)
    assert not out.exists()


def test_a_cloud_over_the_point_limit_is_too_large():
    from datasets.io import Shape
    from tasks.load import ShapeTooLarge, check_size

    cloud = Shape("scan", np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), source="/data/scan.xyz",
                  points=np.zeros((1001, 3)))
    check_size(cloud, max_faces=10, max_points=1001)
    with pytest.raises(ShapeTooLarge, match=r"^/data/scan.xyz: 1,001 points, over the limit of 1,000 \(--max-points\)$"):
        check_size(cloud, max_faces=10, max_points=1000)
