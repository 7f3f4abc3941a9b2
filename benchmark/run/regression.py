"""Regression check on a frozen ABC subset against committed baseline tables.

    python -m benchmark.run.regression                      # run both tiers, compare, exit 1 on drift
    python -m benchmark.run.regression --tier oracle        # one tier
    python -m benchmark.run.regression --update-baselines   # rewrite reports/baselines/<tier>/ (review the diff!)

The subset is ``reports/baselines/abc_subset.txt`` (5 meshes of ``../shared/data/abc``) plus the two
non-manifold pairs of ``abc_subset_nonmanifold.txt``; ``abc_subset.sha256`` pins every file, so a
changed mesh is reported instead of silently used. Each tier is an ordinary ``run_benchmark.py``
run (the user's command), and its ``results.csv`` is compared with the committed one.

Tiers and tolerances (a value passes when ``|now - baseline| <= atol + rtol * |baseline|``):

* ``oracle``: exact fields, all four methods, grid 128, seed 0. Deterministic: the same machine
  gives bit-identical tables, so the tolerance only absorbs floating-point noise across CPUs/BLAS
  (rtol 1e-5 on metrics; mesh counts rtol 1e-3, i.e. a handful of faces out of ~10^5).
* ``neural``: the ``tiny-grid`` budget (the feature-grid backbone of the default ``cpu`` budget at
  CI size), all four methods, grid 64, seed 0. On one machine the tier is deterministic (same seed,
  same thread count: identical tables). Another CPU can change float reduction order, and a fit may
  then drift like a new seed; the seed-0 vs seed-1 spread of this tier bounds that, measured on the
  28 jobs: median relative change CD 4.7%, NC 0.7%, F1@0.005 5.0%, F1@0.01 1.7%, ECD 11%, EF1 18%
  (p90: CD 30%, ECD 41%, EF1 54%). Tolerances sit a little above that median (CD 8%, NC 1%,
  F1@0.005 8% + 0.02, F1@0.01 5% + 0.02, ECD 15% + 1e-3, EF1 25% + 0.03), and the ranking of methods
  on the means of CD and ECD must not flip where the baseline gap exceeds twice the tolerance. A
  broken loss or extractor moves far more than that (see tests/test_run_regression.py).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.run.schema import columns, regression_columns
from methods.base import available_methods

REPO = Path(__file__).resolve().parents[2]
BASELINES = REPO / "reports" / "baselines"
DEFAULT_DATA_DIR = REPO.parent / "shared" / "data" / "abc"
KEY = ["shape", "method", "seed"]


@dataclass(frozen=True)
class Tolerance:
    rtol: float
    atol: float = 0.0


@dataclass(frozen=True)
class Tier:
    name: str
    run_args: tuple[str, ...]
    tolerances: dict[str, Tolerance]
    check_ranking: bool = False
    ranking_metrics: tuple[str, ...] = ()
    notes: str = ""


#: Mesh counts compared by every tier (from the result schema).
_COUNTS = tuple(c.name for c in columns("validity") if c.regression)

TIERS: dict[str, Tier] = {
    "oracle": Tier(
        name="oracle",
        run_args=("--mode", "oracle", "--grid", "128", "--eval-points", "200000", "--seed", "0"),
        tolerances={
            **{m: Tolerance(1e-5, 1e-8) for m in ("cd", "nc", "f1_005", "f1_01", "ecd", "ef1")},
            **{c: Tolerance(1e-3, 2) for c in _COUNTS},
        },
        notes="deterministic; tolerance covers cross-CPU floating-point noise only",
    ),
    "neural": Tier(
        name="neural",
        run_args=("--mode", "neural", "--budget", "tiny-grid", "--grid", "64", "--eval-points", "100000", "--seed", "0"),
        tolerances={
            "cd": Tolerance(0.08, 1e-4),
            "nc": Tolerance(0.01, 0.0),
            "f1_005": Tolerance(0.08, 0.02),
            "f1_01": Tolerance(0.05, 0.02),
            "ecd": Tolerance(0.15, 1e-3),
            "ef1": Tolerance(0.25, 0.03),
        },
        check_ranking=True,
        ranking_metrics=("cd", "ecd"),
        notes="tiny-grid budget; deterministic on one machine; tolerances near the median seed-to-seed spread",
    ),
}


class RegressionError(RuntimeError):
    pass


def read_list(path: Path) -> list[str]:
    return [ln.strip() for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def verify_manifest(data_dir: Path, manifest: Path = BASELINES / "abc_subset.sha256") -> list[str]:
    """Problems with the pinned files (missing or changed); empty when every SHA-256 matches."""
    problems = []
    for line in manifest.read_text().splitlines():
        if not line.strip():
            continue
        digest, name = line.split(maxsplit=1)
        path = data_dir / name.strip()
        if not path.is_file():
            problems.append(f"{path}: missing (pinned by {manifest.name})")
            continue
        actual = hashlib.sha256(path.read_bytes()).hexdigest()
        if actual != digest:
            problems.append(f"{path}: SHA-256 {actual[:12]}... differs from the pinned {digest[:12]}...")
    return problems


def run_tier(tier: Tier, data_dir: Path, out_dir: Path, python: str = sys.executable,
             extra_args: tuple[str, ...] = ()) -> pd.DataFrame:
    """Run the tier's two benchmark runs (subset + non-manifold pairs); return their results."""
    frames = []
    for dataset, list_file in (("abc", "abc_subset.txt"), ("abc-nonmanifold", "abc_subset_nonmanifold.txt")):
        run_dir = out_dir / f"{tier.name}-{dataset}"
        cmd = [
            python, str(REPO / "run_benchmark.py"), "--methods", *available_methods(), "--dataset", dataset,
            "--data-dir", str(data_dir), "--list", str(BASELINES / list_file), "--out", str(run_dir),
            "--quiet", *tier.run_args, *extra_args,
        ]
        print("$ " + " ".join(cmd), flush=True)
        proc = subprocess.run(cmd, cwd=REPO)
        if proc.returncode not in (0, 3):  # 3: finished with failed jobs (compared as status changes)
            raise RegressionError(f"run_benchmark.py exited with {proc.returncode} for tier {tier.name} ({dataset})")
        frames.append(pd.read_csv(run_dir / "results.csv"))
    return pd.concat(frames, ignore_index=True)


def _within(now: float, base: float, tol: Tolerance) -> bool:
    if pd.isna(now) or pd.isna(base):
        return bool(pd.isna(now) and pd.isna(base))
    return abs(float(now) - float(base)) <= tol.atol + tol.rtol * abs(float(base))


def compare(now: pd.DataFrame, baseline: pd.DataFrame, tier: Tier) -> pd.DataFrame:
    """Rows that moved: metric, method, shape, baseline, now, tolerance (empty when all agree)."""
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
        for metric, tol in tier.tolerances.items():
            b, n = r.get(f"{metric}_base"), r.get(f"{metric}_now")
            if b is None and n is None:
                continue
            if not _within(n, b, tol):
                moved.append({**where, "metric": metric, "baseline": b, "now": n,
                              "tolerance": f"rtol {tol.rtol:g}, atol {tol.atol:g}"})
    if tier.check_ranking:
        moved.extend(_ranking_changes(now, baseline, tier))
    return pd.DataFrame(moved, columns=["metric", "method", "shape", "seed", "baseline", "now", "tolerance"])


def _ranking_changes(now: pd.DataFrame, baseline: pd.DataFrame, tier: Tier) -> list[dict]:
    """Pairs of methods whose order on a metric's mean flipped although the baseline gap was clear."""
    out = []
    ok_now, ok_base = now[now.status == "ok"], baseline[baseline.status == "ok"]
    for metric in tier.ranking_metrics:
        mb = ok_base.groupby("method")[metric].mean()
        mn = ok_now.groupby("method")[metric].mean()
        tol = tier.tolerances[metric]
        methods = sorted(set(mb.index) & set(mn.index))
        for i, a in enumerate(methods):
            for b in methods[i + 1:]:
                gap = mb[a] - mb[b]
                clear = abs(gap) > 2 * (tol.atol + tol.rtol * max(abs(mb[a]), abs(mb[b])))
                if clear and np.sign(mn[a] - mn[b]) != np.sign(gap):
                    out.append({"metric": f"{metric} ranking", "method": f"{a} vs {b}", "shape": "(mean)", "seed": "",
                                "baseline": f"{mb[a]:.4g} vs {mb[b]:.4g}", "now": f"{mn[a]:.4g} vs {mn[b]:.4g}",
                                "tolerance": "order kept"})
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmark.run.regression", description=__doc__.split("\n\n")[0])
    parser.add_argument("--tier", choices=[*TIERS, "all"], default="all", help="which tier(s) to run (default: all)")
    parser.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR,
                        help="folder with the ABC meshes of the subset (default: ../shared/data/abc)")
    parser.add_argument("--update-baselines", action="store_true",
                        help="rewrite reports/baselines/<tier>/ from this run instead of comparing")
    parser.add_argument("--work-dir", type=Path, default=None, help="where the runs go (default: a temporary folder)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch threads per job (to measure the neural tier's run-to-run spread: 1 vs 2)")
    args = parser.parse_args(argv)

    if not args.data_dir.is_dir():
        print(f"regression skipped: {args.data_dir} is absent (the ABC subset lives in ../shared/data/abc)")
        return 0
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
    for tier in tiers:
        try:
            extra = ("--threads", str(args.threads)) if args.threads else ()
            results = baseline_columns(run_tier(tier, args.data_dir, work, extra_args=extra))
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
        moved = compare(results, pd.read_csv(baseline_csv), tier)
        if moved.empty:
            print(f"regression tier '{tier.name}': {len(results)} jobs match the baseline ({tier.notes})")
        else:
            failed = True
            print(f"regression tier '{tier.name}': {len(moved)} value(s) moved beyond tolerance:", file=sys.stderr)
            print(moved.to_markdown(index=False), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
