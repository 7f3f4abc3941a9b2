"""The paper's values beside ours, line by line: docs/RESULTS.md's "The paper's table" from the
per-job CSVs of docs/results/ (scripts/export_results.py) and docs/results/paper-reference.csv.

    python scripts/paper_table.py references/paper-abc50-encode/rows.csv [--table encode]

For every (method, metric) the paper reports: the paper's value; ours as mean, median and the 95%
percentile-bootstrap interval of the mean over the shapes (reports.significance, 2,000 resamples,
seed 0); the ratio ours / paper (of the mean); and the jobs that count (ok jobs with a value; ECD's
NaN, a prediction without edge points, is counted beside it). CD and ECD are printed x1e3 and x1e2.
Then the paper's ordering against ours: per pair of methods with a paper value of the metric, which
one the paper puts first, which one our means do, and the paired Wilcoxon p over the shapes both
have (reports.significance.paired_wilcoxon).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from foundation.metrics.presets import PRESETS  # noqa: E402
from reports.significance import bootstrap_mean_ci, paired_wilcoxon  # noqa: E402

REFERENCE = REPO / "docs" / "results" / "paper-reference.csv"
#: The paper's metrics: the default preset's (its table multipliers and better directions).
HEADLINE = {m.column: m for m in PRESETS["default"].headline_metrics()}
SCALE = {k: m.scale for k, m in HEADLINE.items()}
LOWER_IS_BETTER = {k for k, m in HEADLINE.items() if m.lower_is_better}


def _fmt(value: float, metric: str) -> str:
    return "–" if not np.isfinite(value) else f"{value * SCALE.get(metric, 1.0):.3f}"


def line_by_line(jobs: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """One row per paper value with ours beside it (module docstring)."""
    rows = []
    for ref in reference.itertuples():
        values = jobs[(jobs.method == ref.method) & (jobs.status == "ok")][ref.metric].to_numpy(dtype=float)
        finite = values[np.isfinite(values)]
        low, high = bootstrap_mean_ci(finite) if len(finite) else (np.nan, np.nan)
        mean = float(finite.mean()) if len(finite) else np.nan
        rows.append({"method": ref.method, "metric": ref.metric, "paper": _fmt(ref.value, ref.metric),
                     "ours: mean": _fmt(mean, ref.metric), "median": _fmt(float(np.median(finite)) if len(finite)
                                                                        else np.nan, ref.metric),
                     "95% interval": f"[{_fmt(low, ref.metric)}, {_fmt(high, ref.metric)}]",
                     "ours / paper": "–" if not np.isfinite(mean) else f"{mean / ref.value:.2f}",
                     "jobs": f"{len(finite)}" + (f" (+{len(values) - len(finite)} NaN)" if len(values) > len(finite)
                                                 else "")})
    return pd.DataFrame(rows)


def orderings(jobs: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """Per metric and pair of methods the paper ranks: the paper's better one, ours, and the paired
    Wilcoxon p of our per-shape values (module docstring)."""
    rows = []
    ok = jobs[jobs.status == "ok"]
    for metric, ref in reference.groupby("metric", sort=False):
        paper = dict(zip(ref.method, ref.value))
        for a, b in itertools.combinations(paper, 2):
            wide = ok[ok.method.isin([a, b])].pivot_table(index="shape", columns="method", values=metric)
            if a not in wide or b not in wide:
                continue
            pair = wide[[a, b]].dropna()
            lower = metric in LOWER_IS_BETTER
            paper_first = a if (paper[a] < paper[b]) == lower else b
            ours_first = a if (pair[a].mean() < pair[b].mean()) == lower else b
            rows.append({"metric": metric, "pair": f"{a} vs {b}", "paper: better": paper_first,
                         "ours: better": ours_first, "holds": "yes" if paper_first == ours_first else "no",
                         "shapes": len(pair), "p (paired Wilcoxon)": f"{paired_wilcoxon(pair[a], pair[b]):.2g}"})
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python scripts/paper_table.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("csv", type=Path, nargs="+", help="per-job CSVs (scripts/export_results.py)")
    parser.add_argument("--table", default="encode", choices=("encode", "reconstruct"),
                        help="which of the paper's tables (default encode)")
    parser.add_argument("--input", default=None, help="only the jobs of this input (e.g. uniform or scan)")
    args = parser.parse_args(argv)
    jobs = pd.concat([pd.read_csv(p) for p in args.csv], ignore_index=True)
    if args.input:
        jobs = jobs[jobs["input"] == args.input]
    reference = pd.read_csv(REFERENCE)
    reference = reference[(reference["table"] == args.table) & reference.method.isin(set(jobs.method))]
    print(line_by_line(jobs, reference).to_markdown(index=False))
    print()
    print(orderings(jobs, reference).to_markdown(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
