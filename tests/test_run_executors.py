"""Executors (runner.executors): local, process and Ray give the same results; failures are recorded.

Tolerance: oracle mode is deterministic (exact fields, seeded metric samples, no thread-count
dependent reductions), so the tables of the three executors must be *identical*; only timings,
host/device strings and timestamps may differ. (Neural fits differ at most in the last bits between
thread counts: local uses all cores, process ``cores // workers``.)

The Ray tests start one local instance (2 CPUs) for the module and skip, with the reason, when ray
is not installed.
"""

from __future__ import annotations

import json
import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from runner.executors import (LocalExecutor, ProcessExecutor, WorkerLost, ray_available, start_local_ray,
                              threads_per_worker)
from runner.cli import EXIT_FAILED_TASKS, main

REPO = Path(__file__).resolve().parents[1]
RAY_OK, RAY_REASON = ray_available()


# ---------------------------------------------------------------------------------------------
# trivial tasks (module level: picklable by reference for spawned processes and Ray workers)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Spec:
    i: int
    die: bool = False
    uses_fitting: bool = False

    @property
    def label(self) -> str:
        return f"task{self.i}"


def _square(spec: _Spec, progress=None):
    if progress is not None:
        progress("computing", loss=float(spec.i))
    if spec.die:
        os._exit(17)  # simulate a worker killed by the OOM killer / a segfault
    return spec.i * spec.i


def test_threads_per_worker():
    assert threads_per_worker(1, cores=2) == 2
    assert threads_per_worker(2, cores=2) == 1
    assert threads_per_worker(4, cores=2) == 1      # never 0
    assert threads_per_worker(3, cores=16) == 5


def test_physical_cores_count_smt_siblings_once(monkeypatch, tmp_path):
    """Two packages x 2 cores x 2 SMT threads = 8 CPUs, 4 physical cores; only allowed CPUs count."""
    from runner import executors

    blocks = [f"processor\t: {cpu}\nphysical id\t: {cpu // 4}\ncore id\t\t: {cpu % 2}\n\n" for cpu in range(8)]
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("".join(blocks))
    real_open = open
    monkeypatch.setattr("builtins.open", lambda path, *a, **k: real_open(cpuinfo if path == "/proc/cpuinfo" else path,
                                                                         *a, **k))
    monkeypatch.setattr(executors.os, "sched_getaffinity", lambda pid: set(range(8)), raising=False)
    assert executors.physical_cores() == 4
    monkeypatch.setattr(executors.os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    assert executors.physical_cores() == 2  # CPUs 0 and 2 are core 0, CPU 1 is core 1, of package 0


def test_auto_executor_runs_one_process_per_physical_core_on_a_cpu(monkeypatch):
    """The default executor: process workers (one per physical core, never more than the tasks, one
    torch thread each) for two or more tasks on a CPU; the local executor for a single task."""
    from runner import executors
    from runner.config import RunConfig

    monkeypatch.setattr(executors, "physical_cores", lambda: 4)
    many = executors.make_executor(RunConfig(), 10)
    try:
        assert isinstance(many, ProcessExecutor) and (many.workers, many.threads) == (4, 1)
        assert executors.execution_record(many) == {"executor": "process", "workers": 4, "threads_per_job": 1}
    finally:
        many.close()
    few = executors.make_executor(RunConfig(workers=8, threads=2), 3)
    try:
        assert (few.workers, few.threads) == (3, 2)
    finally:
        few.close()
    one = executors.make_executor(RunConfig(), 1)
    assert isinstance(one, LocalExecutor) and one.threads is None
    assert executors.execution_record(one)["threads_per_job"] == __import__("torch").get_num_threads()
    assert RunConfig().executor == "auto"


def test_pin_threads_sets_the_openmp_variables_and_torchs_pool(monkeypatch):
    """What `train --threads T` and every process worker call: after it, torch runs T intra-op threads
    and a library loaded later (the KD-tree's OpenMP runtime) reads T from OMP_NUM_THREADS."""
    import torch

    from runner.executors import pin_threads

    before = torch.get_num_threads()
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    try:
        pin_threads(1)
        assert torch.get_num_threads() == 1
        assert all(os.environ[v] == "1" for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"))
    finally:
        torch.set_num_threads(before)


def test_local_executor_runs_in_order_with_stages():
    stages = []
    got = list(LocalExecutor().run(_square, [_Spec(i) for i in range(4)], on_stage=lambda *a, **k: stages.append((a, k))))
    assert [(s.i, r) for s, r in got] == [(0, 0), (1, 1), (2, 4), (3, 9)]
    assert (("task2", "computing"), {"loss": 2.0}) in stages


def test_process_executor_same_results_and_stage_reports():
    stages = []
    ex = ProcessExecutor(workers=2, retries=0)
    try:
        got = sorted((s.i, r) for s, r in ex.run(_square, [_Spec(i) for i in range(5)],
                                                 on_stage=lambda label, stage, **k: stages.append(label)))
    finally:
        ex.close()
    assert got == [(i, i * i) for i in range(5)]
    assert ex.threads == threads_per_worker(2)
    assert stages, "stage reports travel back from the workers"


def _pid_of_square(i: int) -> tuple[int, int]:
    return i * i, os.getpid()


def test_process_executor_maps_over_its_workers_in_order():
    """``map`` (the report's drawings after the jobs) runs on the run's worker processes, in the
    items' order (a pool is started where none runs yet); one item runs in this process."""
    ex = ProcessExecutor(workers=2, retries=0)
    try:
        assert ex.map(_pid_of_square, [3]) == [(9, os.getpid())]
        list(ex.run(_square, [_Spec(i) for i in range(2)]))
        workers = set(ex._pool._processes)
        got = ex.map(_pid_of_square, range(6))
    finally:
        ex.close()
    assert [v for v, _ in got] == [i * i for i in range(6)]
    assert {pid for _, pid in got} <= workers
    fresh = ProcessExecutor(workers=2, retries=0)
    try:
        assert [v for v, _ in fresh.map(_pid_of_square, [1, 2, 3])] == [1, 4, 9]
    finally:
        fresh.close()
    assert LocalExecutor().map(_pid_of_square, [2]) == [(4, os.getpid())]


def test_process_executor_dead_worker_is_retried_then_reported():
    ex = ProcessExecutor(workers=2, retries=1)
    try:
        got = {s.i: r for s, r in ex.run(_square, [_Spec(0), _Spec(1, die=True), _Spec(2), _Spec(3)])}
    finally:
        ex.close()
    assert set(got) == {0, 1, 2, 3}                            # nothing lost silently
    assert isinstance(got[1], WorkerLost) and "died 2 time(s)" in str(got[1]) and "(exit status 17)" in str(got[1])
    assert got[0] == 0 and got[2] == 4 and got[3] == 9          # the others finish (retried if caught in the crash)


def _dies_holding_the_progress_lock(spec: _Spec, progress=None):
    if spec.die:  # the race of a worker killed while its queue thread sends progress, made certain
        from runner import executors

        executors._WORKER_QUEUE._wlock.acquire()
        os._exit(17)
    return _square(spec, progress)


def test_a_worker_dead_while_sending_progress_does_not_hang_the_others_or_close():
    import threading

    ex = ProcessExecutor(workers=2, retries=0)
    got, finished = {}, threading.Event()

    def run():
        got.update({s.i: r for s, r in ex.run(_dies_holding_the_progress_lock, [_Spec(i, die=i == 1) for i in range(6)],
                                              on_stage=lambda *a, **k: None)})
        ex.close()
        finished.set()

    threading.Thread(target=run, daemon=True).start()
    assert finished.wait(120), "the run or close() hung on the dead worker's progress lock"
    # how it died is test_process_executor_dead_worker_is_retried_then_reported's subject; this one's
    # worker dies at once, and under CI's load its cause has come back as unknown
    assert isinstance(got[1], WorkerLost) and "died 1 time(s)" in str(got[1])
    assert {i: got[i] for i in (0, 2, 3, 4, 5)} == {0: 0, 2: 4, 3: 9, 4: 16, 5: 25}


def _killed(spec: _Spec, progress=None):
    if spec.die:
        os.kill(os.getpid(), signal.SIGKILL)  # what the kernel's out-of-memory killer does
    return spec.i


def test_a_worker_killed_like_the_oom_killer_does_is_a_failed_job_saying_so():
    ex = ProcessExecutor(workers=2, retries=0)
    try:
        got = {s.i: r for s, r in ex.run(_killed, [_Spec(0), _Spec(1, die=True), _Spec(2)])}
    finally:
        ex.close()
    assert got[0] == 0 and got[2] == 2
    assert isinstance(got[1], WorkerLost) and "killed by SIGKILL: out of memory" in str(got[1])
    assert "\n" not in str(got[1])


@pytest.mark.slow
def test_a_job_past_the_worker_memory_limit_fails_saying_so_and_the_run_goes_on(tmp_path):
    """A generated 2.9M-face torus (under --max-faces) and a box, one process worker capped at 1 GiB:
    the torus's tasks fail with 'out of memory' in their rows, the box's are ok, the worker lives on."""
    import trimesh

    n = 1200  # an n x n torus grid: 2 n^2 triangles; its load alone needs more than the limit
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n, endpoint=False), np.linspace(0, 2 * np.pi, n, endpoint=False),
                       indexing="ij")
    vertices = np.stack([(1 + 0.35 * np.cos(v)) * np.cos(u), (1 + 0.35 * np.cos(v)) * np.sin(u), 0.35 * np.sin(v)],
                        -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b, c, d = i * n + j, (i + 1) % n * n + j, (i + 1) % n * n + (j + 1) % n, i * n + (j + 1) % n
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    trimesh.Trimesh(vertices, faces, process=False).export(meshes / "torus.ply")
    trimesh.creation.box().export(meshes / "box.ply")
    out = tmp_path / "run"
    code = main(["--methods", "sdf", "--mode", "oracle", "--dataset", "meshes", "--data-dir", str(meshes),
                 "--grid", "24", "--eval-points", "5000", "--out", str(out), "--no-cache", "--quiet", "--gallery", "0",
                 "--executor", "process", "--workers", "1", "--worker-memory", "1"])
    assert code == EXIT_FAILED_TASKS
    jobs = pd.read_csv(out / "results.csv").set_index("shape")
    assert jobs.loc["box", "status"] == "ok" and jobs.loc["torus", "status"] == "failed"
    assert jobs.loc["torus", "error"].startswith("loading: out of memory (past the limit of --worker-memory 1 GiB): "
                                                 "MemoryError")
    assert "worker process died" not in jobs.loc["torus", "error"]  # the job failed; its worker did not die


# ---------------------------------------------------------------------------------------------
# the real pipeline: local vs process vs ray on 2 shapes x 2 methods + a corrupt mesh file
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def mesh_dir(tmp_path_factory):
    """A 'meshes' dataset folder: two builtin shapes as OBJ files plus one corrupt file."""
    from datasets import get_dataset, save_mesh

    root = tmp_path_factory.mktemp("meshes")
    ds = get_dataset("builtin")
    for name in ds.names()[:2]:
        shape = ds.load(name)
        save_mesh(root / f"{name}.obj", shape.vertices, shape.faces)
    (root / "zz_corrupt.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\nthis is not a mesh\n")
    return root


def _methods():
    return ["sdf", "sals"]


def _run(mesh_dir: Path, out: Path, cache: Path, *executor: str) -> tuple[pd.DataFrame, float]:
    t = time.perf_counter()
    code = main(["--methods", *_methods(), "--dataset", "meshes", "--data-dir", str(mesh_dir), "--mode", "oracle",
                 "--grid", "40", "--eval-points", "20000", "--out", str(out), "--cache-dir", str(cache),
                 "--no-cache", "--quiet", *executor])
    wall = time.perf_counter() - t
    assert code == EXIT_FAILED_TASKS  # the corrupt file's jobs fail, the others are ok
    return pd.read_csv(out / "results.csv"), wall


VOLATILE = ("started", "finished", "host", "device", "cache", "attempts")


def _stable(df: pd.DataFrame) -> pd.DataFrame:
    keep = [c for c in df.columns if not c.endswith("_s") and c not in VOLATILE]
    return df[keep].reset_index(drop=True)


@pytest.fixture(scope="module")
def local_table(mesh_dir, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("local")
    return _run(mesh_dir, tmp / "run", tmp / "cache", "--executor", "local")


def _check_table(df: pd.DataFrame) -> None:
    good = df[df["shape"] != "zz_corrupt"]
    bad = df[df["shape"] == "zz_corrupt"]
    assert len(good) == 4 and (good.status == "ok").all(), good[["shape", "method", "error"]]
    assert len(bad) == 2 and (bad.status == "failed").all()
    assert bad.error.str.startswith("loading: MeshError").all() and not bad.error.str.contains("\n").any()


def test_local_table_has_the_failure_recorded(local_table):
    _check_table(local_table[0])


@pytest.mark.slow
def test_default_executor_runs_process_workers_and_gives_the_local_table(mesh_dir, tmp_path, local_table, monkeypatch):
    """No --executor: on a CPU with two physical cores or more the jobs run in one process per core
    (at least 2 here), the table is the local one, config.json and timing.md name how they ran."""
    from runner import executors

    monkeypatch.setattr(executors, "physical_cores", lambda: 2)
    df, wall = _run(mesh_dir, tmp_path / "run", tmp_path / "cache")
    _check_table(df)
    pd.testing.assert_frame_equal(_stable(df), _stable(local_table[0]))
    print(f"wall time local {local_table[1]:.1f} s, process(2) {wall:.1f} s, ratio {wall / local_table[1]:.2f}")
    record = json.loads((tmp_path / "run" / "config.json").read_text())
    assert record["execution"] == {"executor": "process", "workers": 2, "threads_per_job": 1}
    assert "executor process, 2 workers x 1 torch thread" in (tmp_path / "run" / "timing.md").read_text()


# ---------------------------------------------------------------------------------------------
# Ray
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ray_instance():
    if not RAY_OK:
        pytest.skip(RAY_REASON)
    import ray

    start_local_ray(2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.slow
@pytest.mark.ray
def test_ray_executor_gives_the_local_table(ray_instance, mesh_dir, tmp_path, local_table):
    df, wall = _run(mesh_dir, tmp_path / "run", tmp_path / "cache", "--executor", "ray")
    _check_table(df)
    pd.testing.assert_frame_equal(_stable(df), _stable(local_table[0]))
    print(f"wall time local {local_table[1]:.1f} s, ray {wall:.1f} s, ratio {wall / local_table[1]:.2f}")


@pytest.mark.ray
def test_ray_dead_worker_is_reported_failed_and_others_finish(ray_instance):
    from runner.executors import RayExecutor

    ex = RayExecutor(retries=0)
    try:
        got = {s.i: r for s, r in ex.run(_square, [_Spec(0), _Spec(1, die=True), _Spec(2)])}
    finally:
        ex.close()
    assert got[0] == 0 and got[2] == 4
    assert isinstance(got[1], Exception)  # WorkerCrashedError: recorded as a failed row by the driver
    assert ray_instance.is_initialized()  # the executor joined the instance and did not shut it down


@pytest.mark.ray
def test_ray_resources_ask_gpus_only_for_fitting_jobs(ray_instance):
    from runner.executors import RayExecutor

    ex = RayExecutor(gpus_per_job=0.5, cpus_per_job=1)
    ex.cluster_gpus = 2.0  # pretend the cluster has GPUs
    assert ex.resources_for(_Spec(0, uses_fitting=True)) == {"num_cpus": 1.0, "num_gpus": 0.5}
    assert ex.resources_for(_Spec(0, uses_fitting=False)) == {"num_cpus": 1.0, "num_gpus": 0.0}
    ex.cluster_gpus = 0.0
    assert ex.resources_for(_Spec(0, uses_fitting=True))["num_gpus"] == 0.0


def test_a_worker_ends_when_the_run_process_is_killed(tmp_path):
    """A process that called exit_with_parent ends within a poll once its parent is killed -9
    (a killed run leaves no worker fitting on)."""
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    if not Path("/proc/self/status").exists():
        pytest.skip("needs /proc to tell a running process from a zombie")
    repo = Path(__file__).resolve().parents[1]
    worker = "from runner.executors import exit_with_parent; exit_with_parent(0.05); import time; time.sleep(60)"
    parent = ("import subprocess, sys, time; "
              f"p = subprocess.Popen([sys.executable, '-c', {worker!r}]); print(p.pid, flush=True); time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", parent], cwd=repo, stdout=subprocess.PIPE, text=True)
    child = int(proc.stdout.readline())
    time.sleep(1.0)  # the child is up and watching
    assert _running(child)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 10
    while _running(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _running(child)


def _running(pid: int) -> bool:
    """The process exists and is not a zombie (an exited child nobody has reaped yet)."""
    from pathlib import Path

    status = Path(f"/proc/{pid}/status")
    try:
        return "\nState:\tZ" not in status.read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False


@pytest.mark.slow
@pytest.mark.ray
def test_two_ray_workers_sharing_one_fit_fit_it_once_and_give_the_local_table(ray_instance, tmp_path):
    """A sweep over an extraction setting gives two jobs per shape that need the same fit; on two Ray
    workers one fits while the other waits on the weights entry's lock and loads it: one fit per
    shape, and the table of a local run on a fresh cache."""
    from tests.fake_methods import PLUGIN

    def run(out, cache, *executor):
        assert main(["--methods", "test_sdf", "--mode", "neural", "--budget", "tiny", "--grid", "24",
                     "--eval-points", "5000", "--limit", "2", "--sweep", "test_sdf.level=0,0.01", "--no-ceiling",
                     "--out", str(out), "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet", "--threads", "1",
                     *executor]) == 0
        return pd.read_csv(out / "results.csv").sort_values(["shape", "sweep.test_sdf.level"]).reset_index(drop=True)

    ray_table = run(tmp_path / "ray", tmp_path / "ray-cache", "--executor", "ray", "--workers", "2")
    local = run(tmp_path / "local", tmp_path / "local-cache", "--executor", "local")
    metrics = ["shape", "sweep.test_sdf.level", "cd", "nc", "f1_005", "ecd", "ef1", "n_vertices", "n_faces"]
    pd.testing.assert_frame_equal(ray_table[metrics], local[metrics])
    assert (ray_table.groupby("shape")["fitted"].sum() == 1).all()
