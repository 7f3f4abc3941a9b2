"""The runner (benchmark.runner, run_benchmark.py): CLI validation, the output contract, failures,
resume after SIGKILL, caches and the report subcommand.

Runs use small test-only methods (registered by :func:`register_fakes`, passed to workers with
``--plugin tests.test_runner:register_fakes``) on the exact fields (oracle mode), so they do not
depend on the real methods' fitting budgets; an end-to-end test with the registered methods runs when
they exist.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmark import runner
from benchmark.runner import RESULT_COLUMNS, ConfigError, JobSpec, main, parse_method_params, run_job
from methods.base import Extraction, Method, _REGISTRY, register_method

REPO = Path(__file__).resolve().parents[1]
PLUGIN = "tests.test_runner:register_fakes"


# ---------------------------------------------------------------------------------------------
# test-only methods: marching cubes on the exact SDF / occupancy, and one whose extractor raises
# ---------------------------------------------------------------------------------------------


class _FakeGridMethod(Method):
    input_kind = "points"
    output_dim = 1
    extractor = "marching cubes"
    kind = "sdf"

    def training_targets(self, fields, samples):
        return {"target": np.asarray(getattr(fields, self.kind)(samples.points), dtype=np.float32)}

    def loss(self, prediction, targets, inputs=None, model=None):
        import torch

        target = targets["target"].reshape(prediction.shape)
        if self.kind == "sdf":
            return torch.abs(prediction.clamp(-0.1, 0.1) - target.clamp(-0.1, 0.1)).mean()
        return torch.nn.functional.binary_cross_entropy_with_logits(prediction, target)

    def neural_grid(self, model, N, device):
        import torch

        from benchmark.grid import grid_points

        t = time.perf_counter()
        points = torch.as_tensor(grid_points(N, np.float32).reshape(-1, 3), device=device)
        with torch.no_grad():
            values = torch.cat([model(chunk) for chunk in points.split(65536)]).reshape(N, N, N)
        if self.kind == "occupancy":
            values = torch.sigmoid(values)
        return values.cpu().numpy(), {"query_s": time.perf_counter() - t}

    def oracle_grid(self, fields, N, cache=None):
        from benchmark.fields import cached_grid_fields

        t = time.perf_counter()
        grid = cached_grid_fields(fields, N, self.kind, cache_dir=cache)
        return grid, {"query_s": time.perf_counter() - t}

    def extract(self, grid_field, N, query=None):
        from methods.marching_cubes import marching_cubes_grid

        t = time.perf_counter()
        if self.kind == "sdf":
            V, F = marching_cubes_grid(grid_field, self.params["level"], inside="low")
        else:
            V, F = marching_cubes_grid(grid_field, 0.5, inside="high")
        return Extraction(V, F, {"extract_mc_s": time.perf_counter() - t})


class FakeSDF(_FakeGridMethod):
    name = "test_sdf"
    description = "test-only: marching cubes on the exact SDF"
    default_params = {"level": 0.0}


class FakeOcc(_FakeGridMethod):
    name = "test_occ"
    description = "test-only: marching cubes on the exact occupancy"
    kind = "occupancy"
    default_params = {}


class FakeBroken(_FakeGridMethod):
    name = "test_broken"
    description = "test-only: its extractor always raises"
    default_params = {}

    def extract(self, grid_field, N, query=None):
        raise RuntimeError("boom: extractor failed\nsecond line")


class FakeNaN(FakeSDF):
    name = "test_nan"
    description = "test-only: its training loss is NaN"

    def loss(self, prediction, targets, inputs=None, model=None):
        return super().loss(prediction, targets) * float("nan")


FAKES = (FakeSDF, FakeOcc, FakeBroken, FakeNaN)


def register_fakes() -> None:
    """Register the test-only methods (idempotent; also called in worker processes)."""
    for cls in FAKES:
        register_method(cls)


@pytest.fixture
def fakes():
    register_fakes()
    yield
    for cls in FAKES:  # keep the registry clean for other test modules
        _REGISTRY.pop(cls.name, None)


def oracle_args(out: Path, cache: Path, *extra: str) -> list[str]:
    return ["--methods", "test_sdf", "test_occ", "--mode", "oracle", "--grid", "32", "--eval-points", "20000",
            "--limit", "2", "--out", str(out), "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet", *extra]


def read_results(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "results.csv")


# ---------------------------------------------------------------------------------------------
# configuration and command line
# ---------------------------------------------------------------------------------------------


def test_parse_method_params():
    got = parse_method_params(["sals.o_threshold=0.2", "sals.faces=quad2", "udf.clamp=true", "bof.x=[1, 2]"])
    assert got == {"sals": {"o_threshold": 0.2, "faces": "quad2"}, "udf": {"clamp": True}, "bof": {"x": [1, 2]}}
    for bad in ("o_threshold=0.2", "sals.o_threshold", ".x=1"):
        with pytest.raises(ConfigError, match="METHOD.NAME=VALUE"):
            parse_method_params([bad])


@pytest.mark.parametrize("args, message", [
    (["--methods", "nope"], "unknown method 'nope'"),
    (["--grid", "4"], "--grid must be >= 8"),
    (["--eval-points", "10"], "--eval-points must be >= 1000"),
    (["--dataset", "meshes", "--data-dir", "/no/such/dir"], "--data-dir /no/such/dir: does not exist"),
    (["--list", "/no/such/list.txt"], "--list /no/such/list.txt: does not exist"),
    (["--dataset", "nosuch"], "unknown dataset 'nosuch'"),
    (["--method-param", "test_sdf.nope=1"], "has no parameter"),
    (["--method-param", "bogus"], "METHOD.NAME=VALUE"),
    (["--seed", "-1"], "--seed values must be >= 0"),
    (["--workers", "0"], "--workers must be >= 1"),
    (["--address", "auto"], "--address only applies to --executor ray"),
    (["--limit", "0"], "--limit must be >= 1"),
    (["--plugin", "no_such_module_xyz"], "--plugin no_such_module_xyz"),
])
def test_bad_options_fail_with_one_line_before_any_work(fakes, tmp_path, capsys, args, message):
    out = tmp_path / "run"
    base = ["--methods", "test_sdf", "--mode", "oracle", "--out", str(out), "--plugin", PLUGIN]
    code = main(base + args)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert message in err
    assert not out.exists()  # nothing was started


def test_argparse_errors_are_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--mode", "sometimes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--mode" in err


def test_help_and_bad_flag_through_the_script():
    py = sys.executable
    proc = subprocess.run([py, "run_benchmark.py", "--help"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0
    for option in ("--methods", "--dataset", "--grid", "--eval-points", "--executor", "--resume", "--method-param"):
        assert option in proc.stdout
    proc = subprocess.run([py, "run_benchmark.py", "--grid", "3", "--mode", "oracle"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0 and "--grid" in proc.stderr


def test_job_hash_depends_on_result_defining_settings_only():
    base = dict(dataset="builtin", dataset_options={}, shape="a", method="sdf", params={}, mode="oracle",
                budget="quick", grid=32, eval_points=None, metric_preset="default", seed=0)
    a = JobSpec(**base)
    assert a.key == JobSpec(**base, cache_dir="/elsewhere", threads=3).key      # where/how it runs: same job
    assert a.key == JobSpec(**{**base, "budget": "paper"}).key                  # oracle ignores the budget
    assert a.key == JobSpec(**{**base, "dataset_options": {"limit": 2}}).key     # a limit picks shapes, not content
    for change in ({"seed": 1}, {"grid": 64}, {"params": {"level": 0.1}}, {"mode": "neural"}, {"shape": "b"}):
        assert JobSpec(**{**base, **change}).key != a.key, change


# ---------------------------------------------------------------------------------------------
# a whole run: contract, failure, resume, cache, report
# ---------------------------------------------------------------------------------------------


def test_oracle_run_writes_the_contract(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache)) == 0
    df = read_results(out)
    assert list(df.columns[: len(RESULT_COLUMNS)]) == list(RESULT_COLUMNS)
    assert len(df) == 4 and (df.status == "ok").all()
    shapes = json.loads((out / "config.json").read_text())["shapes"]
    assert len(shapes) == 2
    assert list(df["shape"]) == [shapes[0]] * 2 + [shapes[1]] * 2          # table order: shape, then method
    assert list(df["method"]) == ["test_sdf", "test_occ"] * 2
    h = 2 / 31
    # exact-field marching cubes on a 32^3 grid: the surface is within a fraction of a cell of the GT
    assert (df["cd"] < h).all() and (df["cd"] > 0).all()
    assert (df["n_faces"] > 100).all() and (df["extract_s"] >= 0).all() and (df["metrics_s"] > 0).all()
    assert df["fit_s"].isna().all()                                        # oracle mode fits nothing
    # meshes: GT + one per method, PLY in the canonical frame, matching the recorded counts
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
    cfg = json.loads((out / "config.json").read_text())
    for key in ("methods", "grid", "seeds", "metric_protocol", "environment", "dataset", "shapes", "eval_points"):
        assert key in cfg
    env = cfg["environment"]
    assert {"numpy", "torch", "trimesh", "scipy", "pandas"} <= set(env["versions"]) and "cpu_model" in env
    with sqlite3.connect(out / "results.db") as con:
        n, hashes = con.execute("SELECT count(*), count(DISTINCT config_hash) FROM jobs").fetchone()
    assert n == hashes == 4


def test_failing_job_is_recorded_and_the_run_goes_on(fakes, tmp_path, capsys):
    out, cache = tmp_path / "run", tmp_path / "cache"
    args = oracle_args(out, cache)
    args[args.index("test_occ")] = "test_broken"
    assert main(args) == 0
    df = read_results(out)
    ok, failed = df[df.method == "test_sdf"], df[df.method == "test_broken"]
    assert (ok.status == "ok").all() and len(ok) == 2
    assert (failed.status == "failed").all() and len(failed) == 2
    assert (failed.error == "extracting: RuntimeError: boom: extractor failed").all()  # one line, with the stage
    assert failed.cd.isna().all()
    with sqlite3.connect(out / "results.db") as con:
        tb = con.execute("SELECT traceback FROM jobs WHERE status='failed'").fetchone()[0]
    assert "second line" in tb and "Traceback" in tb
    assert "FAILED" not in capsys.readouterr().out


def test_rerun_skips_finished_jobs_and_retries_failed(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache, "--no-cache")) == 0
    before = read_results(out).set_index(["shape", "method"])
    with sqlite3.connect(out / "results.db") as con:  # pretend one job failed
        con.execute("UPDATE jobs SET status='failed', cd=NULL WHERE rowid = (SELECT min(rowid) FROM jobs)")
    assert main(oracle_args(out, cache, "--no-cache", "--resume")) == 0
    after = read_results(out).set_index(["shape", "method"])
    assert (after.status == "ok").all() and len(after) == 4
    rerun = after.finished != before.finished
    assert rerun.sum() == 1                                          # only the failed job ran again
    assert int(after.loc[rerun, "attempts"].iloc[0]) == 2
    pd.testing.assert_series_equal(after.cd, before.cd)               # and reproduced its numbers exactly


def test_out_dir_with_another_protocol_is_refused(fakes, tmp_path, capsys):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache)) == 0
    args = oracle_args(out, cache)
    args[args.index("32")] = "40"
    assert main(args) == 2
    assert "different grid" in capsys.readouterr().err


def test_mesh_cache_is_reused_across_runs(fakes, tmp_path):
    cache = tmp_path / "cache"
    assert main(oracle_args(tmp_path / "a", cache)) == 0
    assert main(oracle_args(tmp_path / "b", cache)) == 0
    a, b = read_results(tmp_path / "a"), read_results(tmp_path / "b")
    assert a["cache"].isna().all() and (b["cache"] == "mesh").all()
    metric_cols = ["cd", "nc", "f1_005", "f1_01", "ecd", "ef1", "n_vertices", "n_faces"]
    pd.testing.assert_frame_equal(a[metric_cols], b[metric_cols])
    assert (cache / "fields").is_dir() and any((cache / "meshes").iterdir())


def test_report_subcommand_regenerates_results(fakes, tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    assert main(oracle_args(out, cache)) == 0
    again = tmp_path / "again"
    assert main(["report", str(out), "--out", str(again)]) == 0
    pd.testing.assert_frame_equal(read_results(out), read_results(again))
    assert main(["report", str(tmp_path / "nothing")]) == 2


def test_run_job_never_raises_on_a_bad_shape(fakes, tmp_path):
    spec = JobSpec(dataset="builtin", dataset_options={}, shape="no_such_shape", method="test_sdf", params={},
                   mode="oracle", budget="quick", grid=16, eval_points=2000, metric_preset="default", seed=0,
                   plugins=(PLUGIN,))
    result = run_job(spec)
    assert result.status == "failed" and result.error.startswith("loading: DatasetError")
    assert "\n" not in result.error and result.timings["total_s"] >= 0


def test_neural_run_fits_caches_weights_and_records_nan_loss(fakes, tmp_path):
    pytest.importorskip("methods.fitting")
    cache = tmp_path / "cache"
    args = ["--methods", "test_sdf", "test_nan", "--mode", "neural", "--budget", "tiny", "--grid", "24",
            "--eval-points", "5000", "--limit", "1", "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet",
            "--threads", "1"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
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


# ---------------------------------------------------------------------------------------------
# killed mid-run: at most the in-flight job is lost; --resume finishes without recomputing
# ---------------------------------------------------------------------------------------------


def test_sigkill_then_resume(tmp_path):
    out, cache = tmp_path / "run", tmp_path / "cache"
    args = [sys.executable, "run_benchmark.py", "--methods", "test_sdf", "test_occ", "--mode", "oracle",
            "--grid", "24", "--eval-points", "5000", "--seed", "0", "1", "2", "--out", str(out), "--no-cache",
            "--plugin", PLUGIN, "--quiet"]
    proc = subprocess.Popen(args, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "SALSBENCH_CACHE": str(cache)})
    db = out / "results.db"
    deadline = time.monotonic() + 120
    landed = 0
    while time.monotonic() < deadline and proc.poll() is None:
        if db.is_file():
            try:
                with sqlite3.connect(db, timeout=1) as con:
                    landed = con.execute("SELECT count(*) FROM jobs WHERE status='ok'").fetchone()[0]
            except sqlite3.Error:
                landed = 0
            if landed >= 1:
                break
        time.sleep(0.02)
    assert proc.poll() is None, f"run ended before it could be killed: {proc.stderr.read().decode()[-500:]}"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    with sqlite3.connect(db) as con:
        before = dict(con.execute("SELECT config_hash, finished FROM jobs WHERE status='ok'").fetchall())
    assert 1 <= len(before) < 24                       # 4 shapes x 2 methods x 3 seeds in all
    assert not (out / "results.csv").exists()           # the kill came before the end

    resumed = subprocess.run([sys.executable, "run_benchmark.py", "--resume", "--out", str(out)], cwd=REPO,
                             capture_output=True, text=True, timeout=300,
                             env={**os.environ, "SALSBENCH_CACHE": str(cache)})
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    import re

    done = int(re.search(r"(\d+) already done", resumed.stderr).group(1))  # jobs + floor tasks skipped
    assert done >= len(before)
    df = read_results(out)
    assert len(df) == 24 and (df.status == "ok").all()
    with sqlite3.connect(db) as con:
        after = dict(con.execute("SELECT config_hash, finished FROM jobs").fetchall())
    assert all(after[h] == t for h, t in before.items())  # finished jobs were not recomputed


# ---------------------------------------------------------------------------------------------
# the registered methods end to end (skipped while they are not all there)
# ---------------------------------------------------------------------------------------------


def _real_methods():
    from methods.base import available_methods

    return [m for m in ("bof", "sdf", "udf", "sals") if m in available_methods()]


def test_registered_methods_oracle_end_to_end(tmp_path):
    methods = _real_methods()
    if len(methods) < 4:
        pytest.skip(f"only {methods} of bof/sdf/udf/sals are registered so far")
    out = tmp_path / "run"
    code = main(["--methods", *methods, "--mode", "oracle", "--grid", "32", "--eval-points", "20000", "--limit", "1",
                 "--out", str(out), "--cache-dir", str(tmp_path / "cache"), "--quiet"])
    assert code == 0
    df = read_results(out)
    assert list(df.method) == methods and (df.status == "ok").all(), df[["method", "error"]]
    assert (df.cd < 2 / 31).all()
