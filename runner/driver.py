"""The driver: runs every task of a plan not yet finished in its run directory, one writer only.

Order of work: take the directory's lock (:meth:`RunDirectory.lock`), write ``config.json`` (the
merged configuration, the resolved plan and the environment), then hand the unfinished tasks to
the executor and commit each result to ``results.db`` as it arrives (its mesh to
``meshes/<shape>/<method>.ply``). At the end ``results.csv``, ``floor.csv`` and the reports are
written (:mod:`runner.export`). Resume is by key: a task whose key has an ``ok`` row is
skipped; failed tasks run again.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

from tasks.cache import task_code_digest
from runner.config import ConfigError
from runner.plan import Plan, build_tasks
from runner.job import failed_from_exception, now_iso, run_task
from runner.records import ResultsDB
from runner.rundir import RunDirectory
from tasks.context import TaskResult


@dataclass(frozen=True)
class RunOutcome:
    """How a run ended: the directory; tasks of the plan ok / failed in the database at the end;
    tasks found done before this invocation."""

    run_dir: Path
    ok: int
    failed: int
    skipped: int


def record_result(db: ResultsDB, run_dir: RunDirectory, result: TaskResult, first_seed: int, code: str) -> None:
    """Write the mesh bytes (if any) and commit the row (``code``: the digest of the code that
    computed it): the driver's only writing path."""
    spec = result.spec
    mesh_path = None
    if result.mesh_ply is not None:
        stem = "gt" if result.kind == "floor" else "_".join(
            [spec.method] + ([spec.variant] if spec.variant else []) + ([] if spec.seed == first_seed else
                                                                       [f"seed{spec.seed}"]))
        mesh_path = run_dir.mesh_relpath(spec.shape, stem)
        run_dir.write_mesh(mesh_path, result.mesh_ply)
    common = {"shape": spec.shape, "shape_hash": result.shape_hash, "shape_kind": result.shape_kind,
              "status": result.status, "error": result.error, "seed": spec.seed, "eval_points": spec.eval_points,
              "metric_preset": spec.metric_preset, "mesh_path": mesh_path, "finished": result.finished, "code": code}
    if result.kind == "floor":
        db.write_floor({"floor_hash": result.key, "source": result.shape_info.get("source"),
                        "gt_vertices": result.shape_info.get("gt_vertices"),
                        "gt_faces": result.shape_info.get("gt_faces"), **common}, result.metrics, result.timings)
        return
    job = {"shape": spec.shape, "method": spec.method, "seed": spec.seed}
    if result.checkpoints:  # before the job row: an ok job row always has its checkpoints
        db.write_checkpoints(result.key, job, result.checkpoints)
    if result.components:  # and its decomposition rows
        db.write_components(result.key, job, result.components)
    db.write_job({
        "config_hash": result.key, "method": spec.method, **spec.table_fields(), "traceback": result.traceback,
        "params": spec.params, "fit_loss": result.fit_loss,
        "attempts": result.attempts, "cache": ",".join(result.cache) or None,
        "cache_rejected": len(result.cache_rejected), "device": result.device, "host": result.host,
        "versions": result.versions, "info": result.info, "started": result.started,
        "used_sensors": result.info.get("used_sensors"), "seen_in_training": result.info.get("seen_in_training"),
        "precision": result.info.get("precision"), **common,
    }, result.metrics, result.timings, sweep=spec.sweep, fitted=int(bool(result.info.get("fitted"))))


def fresh_results(db: ResultsDB, table: str, tasks: list, codes: dict[str, str], recompute: bool,
                  where: Path) -> set[str]:
    """Keys of the tasks with an ``ok`` row computed by the current code. A finished task whose code
    changed is refused (ConfigError, one line) unless ``recompute``, which runs it again."""
    done = db.ok_codes(table)
    stale = [t for t in tasks if t.key in done and done[t.key] != codes[t.key]]
    if stale and not recompute:
        what = sorted({t.method if t.kind == "job" else "floor" for t in stale})
        raise ConfigError(f"{where}: {len(stale)} finished {table} rows ({', '.join(what)}) were computed by other "
                          f"code than today's; pass --recompute-stale to recompute them, or use another --out")
    return {t.key for t in tasks if t.key in done} - {t.key for t in stale}


def _schedule(plan: Plan, todo: list, trained: frozenset[str] = frozenset()):
    """Sort key of the tasks, in three groups. First the jobs that fit or train their own network
    (or need none), shape by shape in table order, so a run stopped part-way has whole shapes.
    Then the floors (a shape's GT against a resample of itself: the shortest tasks of a run), so
    that they fill the end of the fitting jobs: two workers finish within about a floor of each
    other instead of one fitting the last network alone, and a worker that would wait on a network
    still training takes a floor first. Last, the jobs whose network an earlier job fits or trains
    (a sweep of extraction settings; every shape of a learned reconstruction method): parallel
    workers do not wait on each other's fits but find the weights in the cache. These followers are
    ordered by when their network's first job comes: those of a network trained early run while a
    later one still trains (a K sweep: K = 10 and 20 reconstruct while K = 50 trains), rather than
    one worker waiting on the last network's lock with ready jobs queued behind it. Jobs of a
    network in ``trained`` (fit identities the cache already holds) wait on nothing and keep the
    table order in the first group."""
    order = {s: i for i, s in enumerate(plan.shapes)}
    first: dict[str, int] = {}  # fit identity -> rank of the job that fits it, in table order
    rank: dict[str, tuple[int, int]] = {}
    for t in sorted(todo, key=lambda t: (order[t.shape], 0 if t.kind == "floor" else 1)):
        fit = t.fit_identity() if t.kind == "job" else None
        if t.kind == "floor":
            rank[t.key] = (1, 0)
        elif fit is None or fit in trained:
            rank[t.key] = (0, 0)
        elif fit in first:
            rank[t.key] = (2, first[fit])
        else:
            first[fit] = len(first)
            rank[t.key] = (0, 0)
    return lambda t: (*rank[t.key], order[t.shape])


def session_record(record: dict, previous: dict, execution: dict, tasks: int) -> dict:
    """config.json of this invocation: ``record`` (its config, plan and environment) with when and how
    its tasks run (``started``, ``execution``) and ``sessions``, one entry per invocation that ran
    tasks in this directory (when, how, at which commit, how many tasks). An invocation that finds
    every task done keeps the environment, start and execution of the sessions that computed the
    rows, so the provenance and the timing caption never name a machine or executor that ran nothing."""
    sessions = list(previous.get("sessions") or ())
    if not sessions and previous.get("execution"):  # a directory written before sessions were recorded
        sessions = [{"started": previous.get("started"), "execution": previous["execution"],
                     "git_commit": previous.get("environment", {}).get("git_commit"), "tasks": None}]
    if tasks == 0 and previous.get("execution"):
        kept = {k: previous[k] for k in ("environment", "started", "execution") if k in previous}
        return {**record, **kept, "sessions": sessions}
    started = now_iso()
    sessions.append({"started": started, "execution": execution,
                     "git_commit": record.get("environment", {}).get("git_commit"), "tasks": tasks})
    return {**record, "started": started, "execution": execution, "sessions": sessions}


def _trained_networks(todo: list) -> frozenset[str]:
    """Fit identities of the learned reconstruction jobs in ``todo`` whose network their cache
    already holds (no job of theirs trains)."""
    from methods.base import get_method
    from tasks.trained_networks import network_is_cached

    found: dict[str, bool] = {}
    for t in todo:
        fit = t.fit_identity() if t.kind == "job" and t.task == "reconstruct" and t.cache_dir else None
        if fit is not None and fit not in found:
            method = get_method(t.method, **t.params)
            found[fit] = network_is_cached(method, method.budget(t.budget, t.budget_params), t.train_dirs,
                                           t.cache_dir)
    return frozenset(fit for fit, cached in found.items() if cached)


def run(plan: Plan, run_dir: RunDirectory, record: dict, executor=None) -> RunOutcome:
    """Run the plan's unfinished tasks into ``run_dir`` (which the caller has locked)."""
    from runner.display import Display
    from runner.executors import execution_record, make_executor
    from runner.export import export

    config = plan.config
    db = ResultsDB(run_dir.path / "results.db")  # first: a database of another schema is refused untouched
    floors, jobs = build_tasks(plan)
    codes = {t.key: task_code_digest(t) for t in [*floors, *jobs]}
    try:
        done_jobs = fresh_results(db, "jobs", jobs, codes, config.recompute_stale, run_dir.path)
        done_floors = fresh_results(db, "floor", floors, codes, config.recompute_stale, run_dir.path)
    except ConfigError:
        db.close()
        raise
    attempts = db.attempts()
    todo = [f for f in floors if f.key not in done_floors] + [j for j in jobs if j.key not in done_jobs]
    todo.sort(key=_schedule(plan, todo, _trained_networks(todo)))
    executor = executor or make_executor(config, plan.workers_that_fit(len(todo)))
    run_dir.write_config(session_record(record, run_dir.read_record(), execution_record(executor), len(todo)))
    total = len(floors) + len(jobs)
    skipped = total - len(todo)
    print(f"salsbench: {len(jobs)} jobs + {len(floors)} floor tasks, {skipped} already done, run dir {run_dir.path}",
          file=sys.stderr, flush=True)
    blockwise = [t for t in todo if t.kind == "job" and t.block_wise]
    if blockwise:
        from runner.blocks import run_blocks

        merged = {j.key: j for j in run_blocks(blockwise, run_dir.path, executor, codes)}
        todo = [merged.get(t.key, t) for t in todo]
    display = Display(total, config.quiet, done=skipped)
    t0 = time.perf_counter()
    finished = False
    try:
        for spec, outcome in executor.run(run_task, todo, on_stage=display.stage):
            if isinstance(outcome, BaseException):
                outcome = failed_from_exception(spec, outcome)
            if outcome.kind == "job":
                outcome.attempts = attempts.get(outcome.key, 0) + max(1, outcome.attempts)
            record_result(db, run_dir, outcome, config.seeds[0], codes[outcome.key])
            display.finished(outcome)
        finished = True
    finally:
        display.close()
        wall = time.perf_counter() - t0
        # the report draws its shapes on the workers that ran this session's jobs; in this process when
        # there were none or the run was interrupted (a pool started only to draw costs more than it saves)
        try:
            export(run_dir.path, db=db, record=run_dir.read_record(), gallery=config.gallery,
                   map_shapes=executor.map if finished and todo else map)
        finally:
            executor.close()
        ok = len({t.key for t in floors} & db.ok_hashes("floor")) + len({t.key for t in jobs} & db.ok_hashes("jobs"))
        db.close()
    print(f"salsbench: {ok} ok, {total - ok} failed ({len(todo)} run now, {skipped} done before) in {wall:.1f} s; "
          f"results in {run_dir.path}", file=sys.stderr, flush=True)
    return RunOutcome(run_dir.path, ok, total - ok, skipped)
