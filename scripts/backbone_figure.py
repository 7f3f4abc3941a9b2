"""The backbone figure of docs/RESULTS.md (section 16): each metric's mean over the parts against the
mean seconds of the fits, one line per row and backbone: the plain MLP (the `mlp` budget at each step
count of docs/results/backbone-mlp-scaling.csv) and the feature grid (the `cpu` budget, 3,000 steps,
from the 128^3 rows of docs/results/resolution-unseen.csv, the same 12 parts). A row that extracts
another's fit (sals-ndc, sdf-ndc) is drawn at the seconds of that fit; only the parts every step count
has are used, so each line is over the same parts.

    python scripts/backbone_figure.py [--out docs/figures/backbone-mlp-scaling.svg]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from reports.plots import STYLE, metric_panels, panels_svg  # noqa: E402

MLP_CSV = REPO / "docs/results/backbone-mlp-scaling.csv"
GRID_CSV = REPO / "docs/results/resolution-unseen.csv"
#: The rows drawn, and the row whose fit each one extracts.
FITTED_BY = {"sals": "sals", "sals-ndc": "sals", "sdf": "sdf", "sdf-ndc": "sdf"}
METRICS = (("ef1", "EF1 (higher is better)", 1.0), ("ecd", "ECD x1e2", 1e2), ("cd", "CD x1e3", 1e3))
COLORS = {"sals": "#1f77b4", "sals-ndc": "#17becf", "sdf": "#d62728", "sdf-ndc": "#ff7f0e"}


def _fit_seconds(jobs: pd.DataFrame, by: list[str]) -> pd.Series:
    """Each job's seconds of the fit it extracts (its own row's fit_s for the fitting rows)."""
    fits = jobs[jobs["method"].isin(set(FITTED_BY.values()))].set_index(["method", *by])["fit_s"]
    keys = pd.MultiIndex.from_arrays([jobs["method"].map(FITTED_BY), *(jobs[c] for c in by)])
    return pd.Series(fits.reindex(keys).to_numpy(), index=jobs.index)


def curves() -> pd.DataFrame:
    """method, backbone, steps, fit seconds, metric means over the parts every point has."""
    mlp = pd.read_csv(MLP_CSV)
    mlp = mlp[(mlp["status"] == "ok") & mlp["method"].isin(FITTED_BY)]
    complete = mlp.groupby("shape")["steps"].nunique()
    parts = set(complete[complete == mlp["steps"].nunique()].index)
    mlp = mlp[mlp["shape"].isin(parts)].copy()
    mlp["fit_seconds"] = _fit_seconds(mlp, ["shape", "steps"])
    mlp["backbone"] = "MLP"
    grid = pd.read_csv(GRID_CSV)
    grid = grid[grid["shape"].isin(parts) & grid["method"].isin(FITTED_BY) & (grid["mode"] == "neural")]
    fits = grid[grid["grid"] == grid["grid"].min()].set_index(["method", "shape"])["fit_s"]  # the job that fitted
    grid = grid[grid["grid"] == 128].copy()
    grid["fit_seconds"] = fits.reindex(pd.MultiIndex.from_arrays([grid["method"].map(FITTED_BY), grid["shape"]])).to_numpy()
    grid["steps"], grid["backbone"] = 3000, "grid"
    both = pd.concat([mlp, grid], ignore_index=True)
    columns = ["fit_seconds", *(m for m, _, _ in METRICS)]
    return both.groupby(["method", "backbone", "steps"])[columns].mean().reset_index().assign(parts=len(parts))


def draw(points: pd.DataFrame) -> bytes:
    with matplotlib.rc_context(STYLE):
        fig, axes, nrows = metric_panels(len(METRICS))
        for ax, (metric, label, scale) in zip(axes, METRICS):
            for (method, backbone), line in points.groupby(["method", "backbone"], sort=False):
                line = line.sort_values("steps")
                ax.plot(line["fit_seconds"], scale * line[metric], marker="o" if backbone == "MLP" else "s",
                        linestyle="-" if backbone == "MLP" else "none", color=COLORS[method],
                        label=f"{method} ({backbone})", markerfacecolor="white" if backbone == "grid" else COLORS[method])
                for _, p in line.iterrows():
                    ax.annotate(f"{int(p['steps']) // 1000}k", (p["fit_seconds"], scale * p[metric]), fontsize=6,
                                xytext=(3, 3), textcoords="offset points")
            ax.set_xscale("log")
            ax.set_xlabel(f"mean fit seconds ({int(points['parts'].iloc[0])} parts)")
            ax.set_ylabel(label)
        return panels_svg(fig, axes, len(METRICS), nrows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python scripts/backbone_figure.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs/figures/backbone-mlp-scaling.svg")
    args = parser.parse_args(argv)
    points = curves()
    args.out.write_bytes(draw(points))
    print(points.round(4).to_string(index=False))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
