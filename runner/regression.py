"""Regression check on a frozen ABC subset against committed baseline tables.

    python -m runner.regression                      # run both tiers, compare, exit 1 on drift
                                                     # (exit 4: the ABC subset's folder is absent)
    python -m runner.regression --tier oracle        # one tier
    python -m runner.regression --update-baselines   # rewrite reports/baselines/<tier>/ (review the diff!)

The subset is ``reports/baselines/abc_subset.txt`` (5 meshes of ``../shared/data/abc``) plus the two
non-manifold pairs of ``abc_subset_nonmanifold.txt``; ``abc_subset.sha256`` pins every file, so a
changed mesh is reported instead of silently used. Each tier is an ordinary ``run_benchmark.py``
run (the user's command), and its ``results.csv`` is compared with the committed one.

Tiers and tolerances (a value passes when ``|now - baseline| <= atol + rtol * |baseline|``):

* ``oracle``: exact fields, grid 128, seed 0. Deterministic on every CPU: the analytic extractors
  compute in float64 and the network extractors evaluate their networks in float64 rounded to
  float32 (:mod:`methods.extractors.ndc`), so the tolerance only absorbs the last digits (rtol 1e-5
  on metrics; mesh counts rtol 1e-3, i.e. a handful of faces out of ~10^5).
* ``neural``: the ``tiny-grid`` budget (the feature-grid backbone of the default ``cpu`` budget at
  CI size), all four methods, grid 64, seed 0. On one machine the tier is deterministic (same seed,
  same thread count: identical tables). On another CPU torch's kernels round differently and a fit
  diverges like a change of seed, so per-job values are left to the oracle tier: this tier compares
  each method's *mean* of each metric over the subset's jobs, and the ranking of the methods on
  those means. Its tolerances are derived from ``reports/baselines/neural/spread.csv``, the tier run
  at seeds 0-4 on every CPU float path (``python -m runner.regression --tier neural
  --measure-spread 0 1 2 3 4``): per method and metric, :data:`SPREAD_MARGIN` times the largest
  distance of a (path, seed) mean from the baseline's mean. Job statuses are still compared per job.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from foundation.schema import columns, regression_columns
from datasets.manifest import verify_manifest as manifest_problems
from methods.base import METHODS, available_methods
from methods.core.device import FLOAT_PATHS, float_path_environment
from runner.executors import available_cores
from runner.provenance import REPO

BASELINES = REPO / "reports" / "baselines"
DEFAULT_DATA_DIR = REPO.parent / "shared" / "data" / "abc"
KEY = ["shape", "method", "seed"]


@dataclass(frozen=True)
class Tolerance:
    rtol: float
    atol: float = 0.0


@dataclass(frozen=True)
class Tier:
    """A regression tier: its run's arguments and how its results are compared.

    ``tolerances``: per metric, for per-job comparison (``compare_means`` False). ``compare_means``:
    compare each method's mean over the jobs instead, within the tolerances derived from the tier's
    ``spread.csv`` (:func:`spread_tolerances`); ``ranking_metrics``: metrics whose order of the
    methods' means must hold where the baseline's gap is clear."""

    name: str
    run_args: tuple[str, ...]
    tolerances: dict[str, Tolerance]
    check_ranking: bool = False
    ranking_metrics: tuple[str, ...] = ()
    compare_means: bool = False
    notes: str = ""


#: A mean may move this many times the largest seed x float-path deviation measured for it.
SPREAD_MARGIN = 1.5
METRICS = ("cd", "nc", "f1_005", "f1_01", "ecd", "ef1")


#: Mesh counts compared by every tier (from the result schema).
_COUNTS = tuple(c.name for c in columns("validity") if c.regression)

TIERS: dict[str, Tier] = {
    "oracle": Tier(
        name="oracle",
        run_args=("--mode", "oracle", "--grid", "128", "--eval-points", "200000", "--seed", "0"),
        tolerances={
            **{m: Tolerance(1e-5, 1e-8) for m in METRICS},
            **{c: Tolerance(1e-3, 2) for c in _COUNTS},
        },
        notes="deterministic on every CPU; the tolerance covers the last digits only",
    ),
    "neural": Tier(
        name="neural",
        run_args=("--mode", "neural", "--budget", "tiny-grid", "--grid", "64", "--eval-points", "100000", "--seed", "0"),
        tolerances={},
        check_ranking=True,
        ranking_metrics=("cd", "ecd"),
        compare_means=True,
        notes=f"tiny-grid budget; per-method means within {SPREAD_MARGIN}x the seed x float-path spread",
    ),
}


class RegressionError(RuntimeError):
    pass


def read_list(path: Path) -> list[str]:
    return [ln.strip() for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def verify_manifest(data_dir: Path, manifest: Path = BASELINES / "abc_subset.sha256") -> list[str]:
    """Problems with the subset's pinned files (missing or changed): :func:`datasets.manifest.verify_manifest`."""
    return manifest_problems(data_dir, manifest)


def tier_methods(tier: Tier) -> list[str]:
    """The methods a tier checks: those of its committed baseline (a method registered later joins
    when the baseline is re-made with ``--update-baselines``), or every available one without one."""
    path = BASELINES / tier.name / "results.csv"
    if not path.is_file():
        return available_methods()
    known = set(pd.read_csv(path, usecols=["method"])["method"])
    return [m for m in METHODS.names() if m in known]


def run_tier(tier: Tier, data_dir: Path, out_dir: Path, workers: int, python: str = sys.executable,
             extra_args: tuple[str, ...] = (), env: dict[str, str] | None = None,
             methods: list[str] | None = None) -> pd.DataFrame:
    """Run the tier's two benchmark runs (subset + non-manifold pairs) on ``workers`` jobs at a time of
    one torch thread each (the same numbers whatever the count); return their results.

    ``methods`` default to :func:`tier_methods`.

    ``extra_args`` follow the tier's own (a later ``--seed`` replaces the tier's); ``env`` replaces
    the environment of the runs (e.g. with ``ATEN_CPU_CAPABILITY`` set)."""
    frames = []
    for dataset, list_file in (("abc", "abc_subset.txt"), ("abc-nonmanifold", "abc_subset_nonmanifold.txt")):
        run_dir = out_dir / f"{tier.name}-{dataset}"
        cmd = [
            python, str(REPO / "run_benchmark.py"), "--methods", *(methods or tier_methods(tier)), "--dataset", dataset,
            "--data-dir", str(data_dir), "--list", str(BASELINES / list_file), "--out", str(run_dir),
            "--quiet", "--gallery", "0", *_executor_args(workers), "--threads", "1",
            *tier.run_args, *extra_args,
        ]
        print("$ " + " ".join(cmd), flush=True)
        proc = subprocess.run(cmd, cwd=REPO, env=env)
        if proc.returncode not in (0, 3):  # 3: finished with failed jobs (compared as status changes)
            raise RegressionError(f"run_benchmark.py exited with {proc.returncode} for tier {tier.name} ({dataset})")
        frames.append(pd.read_csv(run_dir / "results.csv"))
    return pd.concat(frames, ignore_index=True)


def _executor_args(workers: int) -> tuple[str, ...]:
    """One torch thread per job either way (the same numbers): with one worker the jobs run in the
    run's own process (no worker process to start and import into), else in process workers."""
    if workers == 1:
        return ("--executor", "local")
    return ("--executor", "process", "--workers", str(workers))


def measure_spread(tier: Tier, data_dir: Path, work_dir: Path, seeds: tuple[int, ...],
                   workers: int, paths: tuple[str, ...] = FLOAT_PATHS, methods: list[str] | None = None) -> pd.DataFrame:
    """The tier's jobs (of ``methods``, default the tier's) at every seed of ``seeds`` on every CPU
    float path of ``paths`` (one run per path): the per-job results with a ``float_path`` column, the
    data its tolerances are derived from. Each path's run has its own cache folder under
    ``work_dir``: the cache keys of fitted weights and meshes do not name the float path, so a shared
    cache would hand every path the first path's fits."""
    frames = []
    for path in paths:
        args = ("--cache-dir", str(work_dir / path / "cache"), "--seed", *map(str, seeds))
        results = baseline_columns(run_tier(tier, data_dir, work_dir / path, workers, methods=methods,
                                            extra_args=args, env=float_path_environment(path)))
        frames.append(results.assign(float_path=path))
    return pd.concat(frames, ignore_index=True)


def merge_spread(committed: pd.DataFrame, measured: pd.DataFrame) -> pd.DataFrame:
    """``committed`` with the rows of every method that ``measured`` holds replaced by its rows."""
    kept = committed[~committed.method.isin(set(measured.method))]
    return pd.concat([kept, measured], ignore_index=True)


def _within(now: float, base: float, tol: Tolerance) -> bool:
    if pd.isna(now) or pd.isna(base):
        return bool(pd.isna(now) and pd.isna(base))
    return abs(float(now) - float(base)) <= tol.atol + tol.rtol * abs(float(base))


def method_means(results: pd.DataFrame) -> pd.DataFrame:
    """Each method's mean of each metric over its ``ok`` jobs (rows: methods, columns: metrics)."""
    ok = results[results.status == "ok"]
    return ok.groupby("method")[[m for m in METRICS if m in ok.columns]].mean()


def spread_tolerances(spread: pd.DataFrame, baseline: pd.DataFrame, margin: float = SPREAD_MARGIN) -> pd.DataFrame:
    """Per method (rows) and metric (columns) the distance a mean may move: ``margin`` times the
    largest distance, over the (float path, seed) runs of ``spread``, of that run's method mean
    from the baseline's."""
    base = method_means(baseline)
    ok = spread[spread.status == "ok"]
    runs = ok.groupby(["float_path", "seed", "method"])[list(base.columns)].mean()
    methods = runs.index.get_level_values("method")
    deviation = (runs - base.reindex(methods).to_numpy()).abs()
    return margin * deviation.groupby(level="method").max()


def compare(now: pd.DataFrame, baseline: pd.DataFrame, tier: Tier,
            mean_tolerances: pd.DataFrame | None = None) -> pd.DataFrame:
    """Rows that moved: metric, method, shape, baseline, now, tolerance (empty when all agree).

    Job presence and status are compared per job. Metrics: per job within ``tier.tolerances``, or,
    for a ``compare_means`` tier, each method's mean within ``mean_tolerances``
    (:func:`spread_tolerances`)."""
    moved = []
    merged = baseline.merge(now, on=KEY, how="outer", suffixes=("_base", "_now"), indicator=True)
    for r in merged.to_dict("records"):
        where = {"method": r["method"], "shape": r["shape"], "seed": r["seed"]}
        if r["_merge"] != "both":
            side = "baseline only" if r["_merge"] == "left_only" else "new job"
            moved.append({**where, "metric": "job", "baseline": side, "now": "", "tolerance": "present in both"})
            continue
        if r["status_base"] != r["status_now"]:
            moved.append({**where, "metric": "status", "baseline": r["status_base"], "now": r["status_now"],
                          "tolerance": "equal"})
            continue
        for metric, tol in ({} if tier.compare_means else tier.tolerances).items():
            b, n = r.get(f"{metric}_base"), r.get(f"{metric}_now")
            if b is None and n is None:
                continue
            if not _within(n, b, tol):
                moved.append({**where, "metric": metric, "baseline": b, "now": n,
                              "tolerance": f"rtol {tol.rtol:g}, atol {tol.atol:g}"})
    if tier.compare_means:
        if mean_tolerances is None:
            raise RegressionError(f"tier '{tier.name}' compares means: it needs the tolerances of its spread.csv")
        moved.extend(_mean_changes(now, baseline, mean_tolerances))

        def margin(metric, method, base):
            return float(mean_tolerances.at[method, metric])
    else:
        def margin(metric, method, base):
            return tier.tolerances[metric].atol + tier.tolerances[metric].rtol * abs(base)
    if tier.check_ranking:
        moved.extend(_ranking_changes(now, baseline, tier.ranking_metrics, margin))
    return pd.DataFrame(moved, columns=["metric", "method", "shape", "seed", "baseline", "now", "tolerance"])


def _mean_changes(now: pd.DataFrame, baseline: pd.DataFrame, tolerances: pd.DataFrame) -> list[dict]:
    """Method means that moved further from the baseline's than their tolerance."""
    out = []
    mb, mn = method_means(baseline), method_means(now)
    for method in mb.index.intersection(mn.index):
        for metric in mb.columns.intersection(mn.columns):
            tol = tolerances.at[method, metric] if method in tolerances.index and metric in tolerances else np.nan
            b, n = mb.at[method, metric], mn.at[method, metric]
            if not np.isfinite(tol):
                raise RegressionError(f"no measured spread for {method} {metric}: re-run --measure-spread")
            if not abs(n - b) <= tol:
                out.append({"metric": f"{metric} (mean)", "method": method, "shape": "(mean)", "seed": "",
                            "baseline": b, "now": n, "tolerance": f"+-{tol:.3g} (spread x {SPREAD_MARGIN:g})"})
    return out


def _ranking_changes(now: pd.DataFrame, baseline: pd.DataFrame, metrics: tuple[str, ...], margin) -> list[dict]:
    """Pairs of methods whose order on a metric's mean flipped although the baseline gap was clear:
    larger than ``margin(metric, method, baseline mean)`` of both methods together."""
    out = []
    mb, mn = method_means(baseline), method_means(now)
    for metric in metrics:
        methods = sorted(set(mb.index) & set(mn.index))
        for i, a in enumerate(methods):
            for b in methods[i + 1:]:
                gap = mb.at[a, metric] - mb.at[b, metric]
                clear = abs(gap) > margin(metric, a, mb.at[a, metric]) + margin(metric, b, mb.at[b, metric])
                if clear and np.sign(mn.at[a, metric] - mn.at[b, metric]) != np.sign(gap):
                    out.append({"metric": f"{metric} ranking", "method": f"{a} vs {b}", "shape": "(mean)", "seed": "",
                                "baseline": f"{mb.at[a, metric]:.4g} vs {mb.at[b, metric]:.4g}",
                                "now": f"{mn.at[a, metric]:.4g} vs {mn.at[b, metric]:.4g}", "tolerance": "order kept"})
    return out


def update_baselines(tier: Tier, results: pd.DataFrame, work_dir: Path) -> None:
    """Rewrite ``reports/baselines/<tier>/``: results.csv (key + metrics) and the runs' summaries."""
    dest = BASELINES / tier.name
    dest.mkdir(parents=True, exist_ok=True)
    results.sort_values(KEY).to_csv(dest / "results.csv", index=False, float_format="%.9g")
    for run_dir in sorted(work_dir.glob(f"{tier.name}-*")):
        summary = run_dir / "summary.md"
        if summary.is_file():
            shutil.copyfile(summary, dest / f"summary_{run_dir.name.removeprefix(tier.name + '-')}.md")
    print(f"baselines of tier '{tier.name}' written to {dest.relative_to(REPO)}: review the diff and commit it")


def baseline_columns(frame: pd.DataFrame) -> pd.DataFrame:
    """The columns the baseline keeps: the key, status, and every metric with a tolerance (timings vary)."""
    keep = KEY + ["status"] + [c for c in regression_columns() if c in frame.columns]
    return frame[[c for c in keep if c in frame.columns]]


def mean_tolerances_of(tier: Tier, baseline: pd.DataFrame) -> pd.DataFrame | None:
    """The mean tolerances of a ``compare_means`` tier, from its committed spread.csv (else None)."""
    if not tier.compare_means:
        return None
    path = BASELINES / tier.name / "spread.csv"
    if not path.is_file():
        raise RegressionError(f"no spread at {path}; measure it with --tier {tier.name} --measure-spread 0 1 2 3 4")
    return spread_tolerances(pd.read_csv(path), baseline)


#: The exit status when the subset's folder is absent: neither a pass (0) nor a drift (1), so a CI
#: log tells a run that compared nothing from one that passed.
EXIT_NO_DATA = 4


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m runner.regression", description=__doc__.split("\n\n")[0])
    parser.add_argument("--tier", choices=[*TIERS, "all"], default="all", help="which tier(s) to run (default: all)")
    parser.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR,
                        help="folder with the ABC meshes of the subset (default: ../shared/data/abc)")
    parser.add_argument("--update-baselines", action="store_true",
                        help="rewrite reports/baselines/<tier>/ from this run instead of comparing")
    parser.add_argument("--work-dir", type=Path, default=None, help="where the runs go (default: a temporary folder)")
    parser.add_argument("--workers", type=int, default=available_cores(),
                        help="parallel jobs, one torch thread each (default: the cores, here %(default)s)")
    parser.add_argument("--methods", nargs="+", default=None,
                        help="with --update-baselines: the methods the tier's baseline keeps (default: every "
                             "available method); with --measure-spread: the methods re-measured (the others' "
                             "rows of spread.csv are kept); otherwise those of the committed baseline")
    parser.add_argument("--measure-spread", type=int, nargs="+", metavar="SEED", default=None,
                        help="instead of comparing: run the tier at these seeds on every CPU float path "
                             f"({', '.join(FLOAT_PATHS)}) and write reports/baselines/<tier>/spread.csv")
    args = parser.parse_args(argv)
    if args.methods and not (args.update_baselines or args.measure_spread):
        parser.error("--methods chooses a baseline's methods or the methods a spread re-measures: it needs "
                     "--update-baselines or --measure-spread (a comparison runs the methods of the committed baseline)")

    if not args.data_dir.is_dir():
        print(f"regression not run: {args.data_dir} is absent (the ABC subset lives in ../shared/data/abc); "
              f"exit {EXIT_NO_DATA}")
        return EXIT_NO_DATA
    problems = verify_manifest(args.data_dir)
    if problems:
        print("regression: the pinned ABC subset changed; refusing to compare against it:", file=sys.stderr)
        for p in problems:
            print(f"  {p}", file=sys.stderr)
        return 1

    work = args.work_dir or Path(tempfile.mkdtemp(prefix="salsbench-regression-"))
    work.mkdir(parents=True, exist_ok=True)
    tiers = list(TIERS.values()) if args.tier == "all" else [TIERS[args.tier]]
    failed = False
    if args.measure_spread:
        for tier in tiers:
            spread = measure_spread(tier, args.data_dir, work / f"spread-{tier.name}", tuple(args.measure_spread),
                                    args.workers, methods=args.methods)
            dest = BASELINES / tier.name / "spread.csv"
            if args.methods and dest.is_file():
                spread = merge_spread(pd.read_csv(dest), spread)
            spread.sort_values(["float_path", *KEY]).to_csv(dest, index=False, float_format="%.9g")
            print(f"spread of tier '{tier.name}' ({len(spread)} jobs) written to {dest.relative_to(REPO)}")
        return 0
    for tier in tiers:
        try:
            if args.update_baselines:  # fresh fits: a cached one may come from another float path
                results = baseline_columns(run_tier(tier, args.data_dir, work, args.workers,
                                                    methods=args.methods or available_methods(),
                                                    extra_args=("--cache-dir", str(work / "cache"))))
            else:
                results = baseline_columns(run_tier(tier, args.data_dir, work, args.workers))
        except RegressionError as exc:
            print(f"regression tier '{tier.name}': {exc}", file=sys.stderr)
            failed = True
            continue
        if args.update_baselines:
            update_baselines(tier, results, work)
            continue
        baseline_csv = BASELINES / tier.name / "results.csv"
        if not baseline_csv.is_file():
            print(f"regression tier '{tier.name}': no baseline at {baseline_csv}; create it with --update-baselines",
                  file=sys.stderr)
            failed = True
            continue
        baseline = pd.read_csv(baseline_csv)
        try:
            moved = compare(results, baseline, tier, mean_tolerances_of(tier, baseline))
        except RegressionError as exc:
            print(f"regression tier '{tier.name}': {exc}", file=sys.stderr)
            failed = True
            continue
        if moved.empty:
            print(f"regression tier '{tier.name}': {len(results)} jobs match the baseline ({tier.notes})")
        else:
            failed = True
            print(f"regression tier '{tier.name}': {len(moved)} value(s) moved beyond tolerance:", file=sys.stderr)
            print(moved.to_markdown(index=False), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
