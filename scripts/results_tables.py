"""The generated tables of docs/RESULTS.md and README's headline, made from the per-job CSVs of
docs/results/ (scripts/export_results.py) and the rows of the reference sets (references/NAME/rows.csv,
runner/references.py) so that text and data cannot drift apart.

    python scripts/results_tables.py           # rewrite every generated block in place
    python scripts/results_tables.py --check   # exit 1, naming the blocks that differ

A generated block sits between ``<!-- generated: NAME -->`` and ``<!-- /generated -->`` in a
Markdown file; NAME is a key of :data:`BLOCKS`, whose spec names the CSVs, the rows and the
metrics. Everything a block shows is computed here from its CSVs, by one rule each:

* per shape: the mean over its seeds' ok jobs (a seed's NaN skipped);
* a row's statistic over the shapes with a value: mean, median; a metric that is NaN for some
  shapes (ECD of a prediction without sharp-edge points, or a value the edge search could not make)
  is taken over the others, and the cell counts the rest as "(N NaN)";
* the 95% interval: the percentile bootstrap of the mean over the shapes
  (:func:`reports.significance.bootstrap_mean_ci`, 2,000 resamples, seed 0);
* scales and better directions: the default metric preset's (CD x1e3, ECD x1e2;
  :func:`foundation.metrics.presets.MetricPreset.headline_metrics`); faces in thousands;
* rounding: Python's format to the digits shown (CD and ECD 2 decimals, the others 3);
* bold: the best mean of a column and every row not significantly worse than it (paired Wilcoxon
  over the shapes both have, p < 0.05: :func:`reports.significance.tied_with_best`), as in every
  table the runs write;
* paired: for two rows, the shapes where each is better (ties and NaN counted in neither) and the
  two-sided Wilcoxon p over the shapes both have (:func:`reports.significance.paired_wilcoxon`);
* the paper's values and orderings: scripts/paper_table.py's (``PaperValues``).
"""

from __future__ import annotations

import argparse
import re
import sys
import textwrap
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from foundation.metrics.presets import PRESETS  # noqa: E402
from reports.significance import against_best, bootstrap_mean_ci, paired_wilcoxon, tied_with_best  # noqa: E402
import paper_table  # noqa: E402  (scripts/paper_table.py: the paper's values beside ours, its orderings)

RESULTS = REPO / "docs" / "results"
#: The files whose generated blocks this script owns.
DOCUMENTS = (REPO / "docs" / "RESULTS.md", REPO / "README.md")
HEADLINE = {m.column: m for m in PRESETS["default"].headline_metrics()}
#: Display name, scale and decimals of each metric a table can show.
METRICS = {**{k: (m.name, m.scale, 2 if m.scale != 1 else 3) for k, m in HEADLINE.items()},
           "eprecision": ("EF1 precision", 1.0, 3), "erecall": ("EF1 recall", 1.0, 3),
           "n_faces": ("faces", 1e-3, 0), "total_s": ("s", 1.0, 1), "peak_rss_mib": ("peak GiB", 1 / 1024, 2)}
METRICS.update({"hit_edges": ("hit edges", 1.0, 0), "false_hit_edges": ("false hits", 1.0, 0),
                "missed_edges": ("missed edges", 1.0, 0), "s_error_h": ("s error (h)", 1.0, 3),
                "normal_error_deg": ("normal error (deg)", 1.0, 2)})
#: Columns that describe a job's cost or a diagnosis, not its quality: never bold, never paired.
COST = {"n_faces", "total_s", "peak_rss_mib", "hit_edges", "false_hit_edges", "missed_edges", "s_error_h",
        "normal_error_deg"}
LOWER_IS_BETTER = {k for k, m in HEADLINE.items() if m.lower_is_better} | COST
#: Line width of a generated sentence (the documents' own).
WIDTH = 100
BLOCK = re.compile(r"(<!-- generated: (?P<name>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /generated -->)", re.S)


@dataclass(frozen=True)
class Row:
    """A table row: the jobs of ``csv`` (a file of docs/results/, or a path from the checkout's root:
    a reference set's ``references/NAME/rows.csv``) whose columns equal ``where``."""

    label: str
    csv: str
    where: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Summary:
    """Rows x metrics: each cell the mean (and median: ``medians``) over the shapes, with the
    interval of the mean for the metrics of ``intervals``."""

    head: str
    rows: tuple[Row, ...]
    metrics: tuple[str, ...]
    medians: tuple[str, ...] = ("cd", "ecd", "ef1")
    intervals: tuple[str, ...] = ()


@dataclass(frozen=True)
class Paired:
    """Pairs of rows x metrics: where each is better, and the paired p."""

    pairs: tuple[tuple[Row, Row], ...]
    metrics: tuple[str, ...]


@dataclass(frozen=True)
class Across:
    """One metric, rows x columns: a cell is the jobs of its row that also match its column's
    ``where`` (e.g. a grid); ``stat`` 'mean / median' (bold by the paired test within a column),
    'median' or 'max' (cost columns: never bold)."""

    head: str
    metric: str
    rows: tuple[Row, ...]
    columns: tuple[tuple[str, dict], ...]
    stat: str = "mean / median"


@dataclass(frozen=True)
class PairedAcross:
    """Pairs of rows x columns for one metric: where each is better, and the paired p, per column."""

    metric: str
    pairs: tuple[tuple[Row, Row], ...]
    columns: tuple[tuple[str, dict], ...]


@dataclass(frozen=True)
class PaperValues:
    """Every value the paper's ``table`` (encode or reconstruct) reports for the methods of ``csv``,
    ours beside it (:func:`paper_table.line_by_line`); with ``orderings``, the paper's pairwise
    orderings against ours instead (:func:`paper_table.orderings`)."""

    csv: str
    table: str = "encode"
    orderings: bool = False


@dataclass(frozen=True)
class ReferenceListing:
    """The shipped reference sets (``run_benchmark.py references``): name, protocol, rows, commits,
    CPU, and whether their metric code is this checkout's."""


@dataclass(frozen=True)
class Headline:
    """A sentence whose numbers come from the CSVs: each ``{NAME}`` of ``text`` is the number
    :func:`fact` of ``rows`` names so; the text is wrapped at :data:`WIDTH`."""

    text: str
    rows: tuple[Row, ...]


@lru_cache(maxsize=None)
def _csv(name: str) -> pd.DataFrame:
    path = REPO / name if "/" in name else RESULTS / name
    return pd.read_csv(path, keep_default_na=False, na_values=[""], dtype={"exact": str})


def per_shape(row: Row) -> pd.DataFrame:
    """Shapes x metrics of ``row``: each shape's mean over its seeds' ok jobs (NaN skipped)."""
    jobs = _csv(row.csv)
    keep = np.ones(len(jobs), bool)
    for column, value in row.where.items():
        keep &= jobs[column].astype(str).to_numpy() == str(value)
    if "status" in jobs:
        failed = jobs[keep & (jobs["status"] != "ok").to_numpy()]
        if len(failed):
            raise ValueError(f"{row.csv} {row.where}: {len(failed)} failed jobs; a table needs every job ok")
    chosen = jobs[keep]
    columns = [c for c in METRICS if c in chosen]
    return chosen.groupby("shape")[columns].mean()


def _within(row: Row, where: dict) -> Row:
    return Row(row.label, row.csv, {**row.where, **where})


def _number(value: float, metric: str) -> str:
    _, scale, digits = METRICS[metric]
    if not np.isfinite(value):
        return "–"
    if metric == "n_faces":
        return f"{value * scale:.0f}k" if value * scale >= 10 else f"{value * scale:.1f}k"
    return f"{value * scale:.{digits}f}"


def p_text(p: float) -> str:
    """A p value: two significant digits from 0.01 on, one below ('3e-6')."""
    if not np.isfinite(p):
        return "–"
    if p >= 0.01:
        return f"{p:.2g}"
    mantissa, exponent = f"{p:.0e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _cell(values: pd.Series, metric: str, summary: Summary) -> str:
    """The cell of ``values`` (one per shape); "–" where the row has no job (not run)."""
    if values.empty:
        return "–"
    finite = values.dropna()
    text = _number(finite.mean(), metric)
    if metric in summary.medians:
        text += f" / {_number(finite.median(), metric)}"
    if metric in summary.intervals:
        low, high = bootstrap_mean_ci(finite.to_numpy())
        text += f" [{_number(low, metric)}, {_number(high, metric)}]"
    if len(finite) < len(values):
        text += f" ({len(values) - len(finite)} NaN)"
    return text


def _some(frame: pd.DataFrame, row: Row) -> pd.DataFrame:
    if frame.empty:
        raise ValueError(f"{row.csv}: no job with {row.where}")
    return frame


def render_summary(summary: Summary) -> str:
    frames = [_some(per_shape(row), row) for row in summary.rows]
    shapes = sorted(set().union(*(f.index for f in frames)))
    cells = [[row.label] for row in summary.rows]
    for metric in summary.metrics:
        matrix = np.array([f[metric].reindex(shapes).to_numpy(dtype=float) for f in frames])
        means = np.array([np.nanmean(m) if np.isfinite(m).any() else np.nan for m in matrix])
        lower = metric in LOWER_IS_BETTER
        if metric in COST or not np.isfinite(means).any():
            bold = [False] * len(means)
        else:
            best = int(np.nanargmin(means) if lower else np.nanargmax(means))
            _, _, worse = against_best(matrix, best, lower)
            bold, _ = tied_with_best(means, worse, lower)
        for i, f in enumerate(frames):
            text = _cell(f[metric], metric, summary)
            cells[i].append(f"**{text}**" if bold[i] else text)
    head = [summary.head] + [METRICS[m][0] for m in summary.metrics]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return "\n".join(lines + ["| " + " | ".join(c) + " |" for c in cells])


def render_across(across: Across) -> str:
    metric = across.metric
    head = [across.head] + [label for label, _ in across.columns]
    cells = [[row.label] for row in across.rows]
    grid = [[per_shape(_within(row, where)) for row in across.rows] for _, where in across.columns]
    for i, row in enumerate(across.rows):  # a row may lack a column (not run there), never every column
        if all(column[i].empty for column in grid):
            _some(grid[0][i], _within(row, across.columns[0][1]))
    for frames in grid:
        values = [f[metric] for f in frames]
        if across.stat == "mean / median":
            shapes = sorted(set().union(*(f.index for f in frames)))
            matrix = np.array([v.reindex(shapes).to_numpy(dtype=float) for v in values])
            means = np.array([np.nanmean(m) if np.isfinite(m).any() else np.nan for m in matrix])
            lower = metric in LOWER_IS_BETTER
            if metric not in COST and np.isfinite(means).any():
                best = int(np.nanargmin(means) if lower else np.nanargmax(means))
                bold, _ = tied_with_best(means, against_best(matrix, best, lower)[2], lower)
            else:
                bold = [False] * len(means)
            texts = [_cell(v, metric, Summary("", (), (metric,))) for v in values]
        else:
            bold = [False] * len(values)
            texts = ["–" if v.empty else _number(float(v.median() if across.stat == "median" else v.max()), metric)
                     for v in values]
        for i, text in enumerate(texts):
            cells[i].append(f"**{text}**" if bold[i] else text)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return "\n".join(lines + ["| " + " | ".join(c) + " |" for c in cells])


def render_paired_across(paired: PairedAcross) -> str:
    head = ["pair"] + [label for label, _ in paired.columns]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for a, b in paired.pairs:
        cells = [f"{a.label} vs {b.label}"]
        for _, where in paired.columns:  # a pair may lack a column (a row not run there): '–'
            a_in, b_in = _within(a, where), _within(b, where)
            missing = per_shape(a_in).empty or per_shape(b_in).empty
            cells.append("–" if missing else _pair_text(a_in, b_in, paired.metric))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _pair_text(a: Row, b: Row, metric: str) -> str:
    wins_a, wins_b, p, _ = better_counts(a, b, metric)
    first, second = ((a.label, wins_a), (b.label, wins_b)) if wins_a >= wins_b else ((b.label, wins_b),
                                                                                     (a.label, wins_a))
    return f"{first[0]} {first[1]}, {second[0]} {second[1]} (p = {p_text(p)})"


def better_counts(a: Row, b: Row, metric: str) -> tuple[int, int, float, int]:
    """(shapes where a is better, where b is, the two-sided paired Wilcoxon p, shapes both have)."""
    x, y = _some(per_shape(a), a)[metric], _some(per_shape(b), b)[metric]
    x, y = x.align(y, join="inner")
    both = np.isfinite(x.to_numpy()) & np.isfinite(y.to_numpy())
    d = (x - y).to_numpy()[both] * (1 if metric in LOWER_IS_BETTER else -1)
    return int((d < 0).sum()), int((d > 0).sum()), paired_wilcoxon(x.to_numpy(), y.to_numpy()), int(both.sum())


def render_paired(paired: Paired) -> str:
    head = ["pair"] + [METRICS[m][0] for m in paired.metrics]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for a, b in paired.pairs:
        cells = [f"{a.label} vs {b.label}"]
        for metric in paired.metrics:
            cells.append(_pair_text(a, b, metric))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def fact(name: str, rows: tuple[Row, ...]) -> str:
    """One named number of ``rows`` for a sentence: ``shapes`` (the first row's), ``LABEL.METRIC``
    (the row's mean) or ``A>B.METRIC`` (the shapes where row A is better than row B)."""
    if name == "shapes":
        return str(len(per_shape(rows[0])))
    by_label = {row.label: row for row in rows}
    what, _, metric = name.rpartition(".")
    if ">" in what:
        a, b = what.split(">")
        return str(better_counts(by_label[a], by_label[b], metric)[0])
    return _number(_some(per_shape(by_label[what]), by_label[what])[metric].mean(), metric)


def _markdown(frame: pd.DataFrame) -> str:
    """A frame as a Markdown table of the documents' form (cells as they are)."""
    lines = ["| " + " | ".join(frame.columns) + " |", "|" + "---|" * len(frame.columns)]
    return "\n".join(lines + ["| " + " | ".join(map(str, r)) + " |" for r in frame.itertuples(index=False)])


def render_paper(spec: PaperValues) -> str:
    jobs = _csv(spec.csv)
    reference = pd.read_csv(paper_table.REFERENCE)
    reference = reference[(reference["table"] == spec.table) & reference["method"].isin(set(jobs["method"]))
                          & reference["metric"].isin(set(jobs.columns))]
    frame = (paper_table.orderings if spec.orderings else paper_table.line_by_line)(jobs, reference)
    frame["metric"] = [METRICS[m][0] for m in frame["metric"]]
    if spec.orderings:
        frame["p (paired Wilcoxon)"] = [p_text(float(p)) for p in frame["p (paired Wilcoxon)"]]
    return _markdown(frame)


def render_listing() -> str:
    from runner.references import listing

    frame = listing()
    return _markdown(frame)


def render(spec) -> str:
    if isinstance(spec, ReferenceListing):
        return render_listing()
    if isinstance(spec, PaperValues):
        return render_paper(spec)
    if isinstance(spec, Summary):
        return render_summary(spec)
    if isinstance(spec, Paired):
        return render_paired(spec)
    if isinstance(spec, Across):
        return render_across(spec)
    if isinstance(spec, PairedAcross):
        return render_paired_across(spec)
    text = re.sub(r"\{([^{}]+)\}", lambda m: fact(m[1], spec.rows), spec.text)
    return textwrap.fill(" ".join(text.split()), width=WIDTH, break_on_hyphens=False)


UNSEEN12 = "sals-ndc-unseen12-encode.csv"
UNSEEN12_ORACLE = "sals-ndc-unseen12-oracle.csv"
UNSEEN12_PARTS = "sals-ndc-unseen12-decompose.csv"
UNSEEN93 = "references/abc-unseen93-encode/rows.csv"
PAPER50 = "references/paper-abc50-encode/rows.csv"
PAPER50_ORACLE = "references/paper-abc50-oracle/rows.csv"


def _rows(csv: str, *methods: str, **where) -> tuple[Row, ...]:
    return tuple(Row(m, csv, {"method": m, **where}) for m in methods)


RESOLUTION = "resolution-unseen.csv"
RESOLUTION_ORACLE = "resolution-unseen-oracle.csv"
RESOLUTION_PARTS = "resolution-decompose-sals.csv"
RESOLUTION_JOBS = "resolution-decompose-sals-jobs.csv"
GRID_ROWS = ("sals", "sals-ndc", "sdf", "sdf-ndc", "udf", "udf-dualmesh", "udf-ndc", "bof")
GRIDS = tuple((f"{n}^3", {"grid": n}) for n in (64, 128, 256))
GRIDS_512 = GRIDS + (("512^3", {"grid": 512}),)
#: The grids of the neural resolution tables: 384^3 holds the row that does not fit 512^3.
GRIDS_ALL = GRIDS + (("384^3", {"grid": 384}), ("512^3", {"grid": 512}))
RN = {m: Row(m, RESOLUTION, {"method": m}) for m in GRID_ROWS}
S93 = _rows(UNSEEN93, "sals", "sals-ndc", "sdf", "sdf-ndc")
O50 = _rows(PAPER50_ORACLE, "sals", "sdf-ndc")
P50 = _rows(PAPER50, "sals", "sdf", "sdf-ndc")
PAPER50_RECON = "references/paper-abc50-reconstruct/rows.csv"
PAPER50_SCAN = "references/paper-abc50-reconstruct-scan/rows.csv"
PAIRS50 = "references/paper-nonmanifold50-encode/rows.csv"
PAIRS50_ORACLE = "references/paper-nonmanifold50-oracle/rows.csv"
ENCODE_ROWS = ("sals", "sals-ndc", "sdf", "sdf-ndc", "udf", "udf-dualmesh", "udf-ndc", "udf-dcudf", "bof", "nglod",
               "uodf")
RECON_ROWS = ("sals-knn", "geoudf", "gifs", "cap-udf", "poco", "poisson", "ball-pivoting")
R50, S50 = ({m: Row(m, csv, {"method": m}) for m in RECON_ROWS} for csv in (PAPER50_RECON, PAPER50_SCAN))
N50, NO50 = ({m: Row(m, csv, {"method": m}) for m in ENCODE_ROWS} for csv in (PAIRS50, PAIRS50_ORACLE))
MLP_SCALING = "backbone-mlp-scaling.csv"
MLP_ROWS = ("sals", "sals-ndc", "sdf", "sdf-ndc")
#: The step counts of the `mlp` budget whose 12 parts are all in the CSV.
MLP_STEPS = tuple((f"{n:,} steps", {"steps": n}) for n in (2000, 4000, 8000))
ML = {m: Row(m, MLP_SCALING, {"method": m}) for m in MLP_ROWS}
MLP_PAIRS = ((ML["sals"], ML["sdf-ndc"]), (ML["sals"], ML["sdf"]), (ML["sals-ndc"], ML["sdf-ndc"]),
             (ML["sals-ndc"], ML["sals"]))
#: Each row with the grid backbone (the `cpu` budget, 3,000 steps, 128^3, the same 12 parts) and the MLP.
BACKBONE_PAIRS = tuple((Row(f"{m} MLP {n // 1000}k", MLP_SCALING, {"method": m, "steps": n}),
                        Row(f"{m} grid 3k", RESOLUTION, {"method": m, "grid": 128}))
                       for m in MLP_ROWS for _, where in MLP_STEPS[-1:] for n in (where["steps"],))
#: The tables of a set in full: a row per method, the metrics of the paper's table and the faces.
SET_METRICS = ("cd", "nc", "f1_005", "ecd", "ef1", "n_faces")
#: Every generated block: its name in the documents -> what it shows.
BLOCKS = {
    "references": ReferenceListing(),
    "paper50-values": PaperValues(PAPER50),
    "paper50-orderings": PaperValues(PAPER50, orderings=True),
    "paper50-neural": Summary("50 parts", _rows(PAPER50, *ENCODE_ROWS), SET_METRICS, intervals=("ef1",)),
    "oracle50": Summary("50 parts, oracle", _rows(PAPER50_ORACLE, *ENCODE_ROWS), SET_METRICS, intervals=("ef1",)),
    "recon50-values": PaperValues(PAPER50_RECON, "reconstruct"),
    "recon50-orderings": PaperValues(PAPER50_RECON, "reconstruct", orderings=True),
    "recon50": Summary("50 parts, 40k clean points", tuple(R50.values()), ("cd", "nc", "f1_005", "f1_01", "ecd", "ef1",
                                                                           "n_faces")),
    "recon50-paired": Paired(tuple((R50["sals-knn"], R50[m]) for m in RECON_ROWS[1:]), ("cd", "ecd", "ef1")),
    "scan50-values": PaperValues(PAPER50_SCAN, "reconstruct"),
    "scan50": Summary("50 parts, scan", tuple(S50.values()), ("cd", "nc", "f1_005", "f1_01", "ecd", "ef1", "n_faces")),
    "scan50-cost": Paired(tuple((Row(f"{m} scan", PAPER50_SCAN, {"method": m}),
                                 Row(f"{m} clean", PAPER50_RECON, {"method": m})) for m in RECON_ROWS), ("cd", "ef1")),
    "scan50-paired": Paired(tuple((S50["sals-knn"], S50[m]) for m in RECON_ROWS[1:]), ("cd", "ecd", "ef1")),
    "pairs50": Summary("50 pairs", tuple(N50[m] for m in ENCODE_ROWS if m != "sals-ndc"), SET_METRICS,
                       intervals=("cd", "ef1")),
    "pairs50-paired": Paired(tuple((N50[a], N50[b]) for a, b in (
        ("sals", "udf"), ("sals", "udf-dualmesh"), ("sals", "sdf"), ("sals", "sdf-ndc"), ("udf-dualmesh", "udf"),
        ("sdf-ndc", "udf-dualmesh"), ("sals", "udf-ndc"), ("sdf-ndc", "udf-ndc"), ("sals", "udf-dcudf"),
        ("sals", "bof"), ("sdf", "bof"), ("udf", "bof"), ("sals", "nglod"), ("nglod", "sdf"), ("sals", "uodf"),
        ("udf", "uodf"), ("udf-dualmesh", "uodf"), ("sdf", "uodf"), ("nglod", "uodf"))), ("cd", "ecd", "ef1")),
    "pairs50-oracle": Summary("50 pairs, oracle", tuple(NO50.values()), SET_METRICS, intervals=("cd", "ef1")),
    "pairs50-oracle-paired": Paired(tuple((NO50[a], NO50[b]) for a, b in (
        ("sals", "sdf-ndc"), ("sals", "udf-dualmesh"), ("sals", "udf-ndc"), ("sals", "udf"), ("sals-ndc", "sals"),
        ("sdf-ndc", "udf-ndc"), ("udf-dualmesh", "sdf-ndc"), ("sals", "uodf"), ("sals", "bof"))), ("cd", "ecd", "ef1")),
    "pairs50-oracle-vs-neural": Paired(tuple((Row(f"{m} oracle", PAIRS50_ORACLE, {"method": m}),
                                              Row(f"{m} fitted", PAIRS50, {"method": m}))
                                             for m in ENCODE_ROWS if m != "sals-ndc"), ("cd", "ef1")),
    "unseen12-neural": Summary("12 unseen parts", _rows(UNSEEN12, "sals", "sals-ndc", "sdf", "sdf-ndc"),
                               ("cd", "ecd", "ef1", "nc", "f1_005", "n_faces")),
    "unseen12-decompose": Summary(
        "`sals-ndc`, exact components",
        (Row("sals (fitted flags, for reference)", UNSEEN12, {"method": "sals"}),
         Row("none (learned flags)", UNSEEN12, {"method": "sals-ndc"}),
         *(Row(label, UNSEEN12_PARTS, {"method": "sals-ndc", "exact": exact}) for label, exact in (
             ("flags", "flags"), ("s", "s"), ("normals", "normals"), ("s, normals", "s+normals"),
             ("flags, normals", "flags+normals"), ("flags, s", "flags+s"),
             ("every component exact (= oracle)", "flags+s+normals")))),
        ("cd", "ecd", "ef1", "n_faces"), medians=("ecd", "ef1")),
    "unseen12-paired": Paired(tuple((Row(a, UNSEEN12, {"method": a}), Row(b, UNSEEN12, {"method": b})) for a, b in (
        ("sals-ndc", "sals"), ("sdf-ndc", "sals-ndc"), ("sdf-ndc", "sals"))), ("cd", "ecd", "ef1", "nc")),
    "unseen12-oracle": Summary("12 unseen parts, oracle", _rows(UNSEEN12_ORACLE, "sals", "sals-ndc", "sdf-ndc"),
                               ("cd", "ecd", "ef1", "nc", "n_faces")),
    "unseen93-neural": Summary("93 parts", S93, ("cd", "nc", "f1_005", "ecd", "ef1"), intervals=("cd", "ef1")),
    "unseen93-paired": Paired(((S93[3], S93[0]), (S93[0], S93[2]), (S93[1], S93[0]), (S93[3], S93[1])),
                              ("cd", "ecd", "ef1")),
    "paper50-paired": Paired(((P50[2], P50[0]), (P50[0], P50[1])), ("cd", "ecd", "ef1")),
    "resolution-ef1": Across("EF1, neural", "ef1", tuple(RN.values()), GRIDS_ALL),
    "resolution-ecd": Across("ECD, neural", "ecd", tuple(RN.values()), GRIDS_ALL),
    "resolution-cd": Across("CD, neural", "cd", tuple(RN.values()), GRIDS_ALL),
    "resolution-precision": Across("EF1 precision / recall, neural", "eprecision", tuple(RN.values()), GRIDS_ALL),
    "resolution-recall": Across("EF1 recall, neural", "erecall", tuple(RN.values()), GRIDS_ALL),
    "resolution-paired": PairedAcross("ef1", ((RN["sals"], RN["sdf"]), (RN["sdf-ndc"], RN["sals"]),
                                              (RN["sdf-ndc"], RN["sals-ndc"]), (RN["udf-dualmesh"], RN["sals"])),
                                      GRIDS_512),
    "resolution-paired-cd": PairedAcross("cd", ((RN["sals"], RN["sdf"]), (RN["sdf-ndc"], RN["sals"])), GRIDS_512),
    "resolution-oracle-ef1": Across("EF1, oracle", "ef1", _rows(RESOLUTION_ORACLE, *GRID_ROWS), GRIDS_512),
    "resolution-oracle-precision": Across("EF1 precision, oracle", "eprecision", _rows(RESOLUTION_ORACLE, *GRID_ROWS),
                                          GRIDS_512),
    "resolution-faces": Across(
        "E-DC face rule, oracle `sals`", "ef1",
        tuple(Row(rule, "resolution-edc-faces-oracle.csv", {"sweep.sals.faces": rule})
              for rule in ("fan4", "quad2", "fan4-adaptive")), GRIDS[1:]),
    "resolution-threshold": Summary(
        "`sals` at 256^3, o threshold",
        (Row("0.3", "resolution-threshold-256.csv", {"sweep.sals.o_threshold": 0.3}),
         Row("0.5 (the default)", RESOLUTION, {"method": "sals", "grid": 256}),
         Row("0.7", "resolution-threshold-256.csv", {"sweep.sals.o_threshold": 0.7})),
        ("cd", "ef1", "eprecision", "erecall", "n_faces")),
    "resolution-decompose": Across(
        "`sals`, exact components (6 parts)", "ef1",
        (Row("none (the fitted field)", RESOLUTION_JOBS, {"method": "sals"}),
         *(Row(label, RESOLUTION_PARTS, {"exact": exact}) for label, exact in (
             ("flags", "flags"), ("s", "s"), ("normals", "normals"), ("flags, s", "flags+s"),
             ("flags, normals", "flags+normals"), ("every component exact (= oracle)", "flags+s+normals")))),
        GRIDS[1:]),
    "resolution-decompose-cd": Across(
        "`sals`, exact components (6 parts)", "cd",
        (Row("none (the fitted field)", RESOLUTION_JOBS, {"method": "sals"}),
         Row("flags", RESOLUTION_PARTS, {"exact": "flags"}),
         Row("every component exact (= oracle)", RESOLUTION_PARTS, {"exact": "flags+s+normals"})), GRIDS[1:]),
    "resolution-flags": Summary(
        "`sals`'s fitted flags against the exact edges (6 parts)",
        tuple(Row(label, RESOLUTION_JOBS, {"method": "sals", "grid": n}) for label, n in (("128^3", 128), ("256^3", 256))),
        ("hit_edges", "false_hit_edges", "missed_edges", "s_error_h", "normal_error_deg"), medians=()),
    "resolution-seconds": Across("median s per job (neural)", "total_s", tuple(RN.values()), GRIDS_ALL, stat="median"),
    "resolution-peak": Across("largest peak GiB of a job (neural)", "peak_rss_mib", tuple(RN.values()), GRIDS_ALL,
                              stat="max"),
    "headline": Headline(
        "At the `cpu` budget (3,000 steps, about a minute of fitting per part on one CPU core) on the {shapes} ABC "
        "parts no published network was trained on, **SDF + NDC** (a fitted SDF extracted by Neural Dual "
        "Contouring's published network) beats SALS + E-DC on ECD and EF1 on {sdf-ndc>sals.ecd} and "
        "{sdf-ndc>sals.ef1} of {shapes} parts (mean EF1 {sdf-ndc.ef1} against {sals.ef1}), and SALS with learned "
        "flags (`sals-ndc`) on {sdf-ndc>sals-ndc.ef1}; SALS leads marching cubes on the same fitted SDF (EF1, "
        "{sals>sdf.ef1} of {shapes}).", S93),
    "oracle50-sentence": Headline(
        "With exact fields (oracle, the paper's {shapes} parts) SALS + E-DC against SDF + NDC: EF1 better on\n"
        "{sals>sdf-ndc.ef1} parts and worse on {sdf-ndc>sals.ef1} (mean {sals.ef1} against {sdf-ndc.ef1}), ECD better on\n"
        "{sals>sdf-ndc.ecd} and worse on {sdf-ndc>sals.ecd} (mean x1e2 {sals.ecd} against {sdf-ndc.ecd}).\n", O50),
    "mlp-ef1": Across("EF1, plain MLP", "ef1", tuple(ML.values()), MLP_STEPS),
    "mlp-ecd": Across("ECD, plain MLP", "ecd", tuple(ML.values()), MLP_STEPS),
    "mlp-cd": Across("CD, plain MLP", "cd", tuple(ML.values()), MLP_STEPS),
    "mlp-faces": Across("faces, plain MLP", "n_faces", tuple(ML.values()), MLP_STEPS, stat="median"),
    "mlp-paired": PairedAcross("ef1", MLP_PAIRS, MLP_STEPS),
    "mlp-paired-ecd": PairedAcross("ecd", MLP_PAIRS, MLP_STEPS),
    "mlp-paired-cd": PairedAcross("cd", MLP_PAIRS, MLP_STEPS),
    "mlp-vs-grid": Paired(BACKBONE_PAIRS, ("cd", "ecd", "ef1")),
    "headline-backbone": Headline(
        "With the paper's kind of network instead (a plain Softplus MLP, the `mlp` budget at 2,000, 4,000 and "
        "8,000 steps, up to 6 minutes of fitting per part, where SALS has not converged) on the same {shapes} parts "
        "at 128^3: SDF + NDC beats SALS on EF1 on {sdf-ndc@8000>sals@8000.ef1} of {shapes} at 8,000 steps (mean "
        "{sdf-ndc@8000.ef1} against {sals@8000.ef1}; {sdf-ndc@2000>sals@2000.ef1} and {sdf-ndc@4000>sals@4000.ef1} "
        "at 2,000 and 4,000), and marching cubes beats SALS on {sdf@8000>sals@8000.ef1} of {shapes} (SDF + MC "
        "{sdf@8000.ef1}): with this backbone and budget the paper's ordering does not hold.",
        tuple(Row(f"{m}@{n}", MLP_SCALING, {"method": m, "steps": n}) for n in (8000, 4000, 2000)
              for m in ("sals", "sdf", "sdf-ndc"))),
    "headline-resolution": Headline(
        "Extracting the `cpu` fits of 12 other unseen parts at 64^3, 128^3, 256^3 and 512^3: SDF + NDC leads SALS "
        "at every grid ({sdf-ndc@256>sals@256.ef1} of {shapes} at 256^3, {sdf-ndc@512>sals@512.ef1} at 512^3), while "
        "SALS's lead over marching cubes ({sals@64>sdf@64.ef1} and {sals@128>sdf@128.ef1} of {shapes} parts at 64^3 "
        "and 128^3) is gone at 256^3 and 512^3 (MC better on {sdf@256>sals@256.ef1} and {sdf@512>sals@512.ef1} of "
        "{shapes}).",
        tuple(Row(f"{m}@{n}", RESOLUTION, {"method": m, "grid": n}) for n in (256, 128, 64, 512)
              for m in ("sals", "sdf", "sdf-ndc"))),
}


def update(text: str, where: str = "") -> tuple[str, list[str]]:
    """``text`` with every generated block re-made, and the names of the blocks that changed. An
    unknown block name raises ValueError."""
    changed = []

    def fill(match: re.Match) -> str:
        name = match["name"]
        if name not in BLOCKS:
            raise ValueError(f"{where}: unknown generated block '{name}'; known: {', '.join(BLOCKS)}")
        body = render(BLOCKS[name])
        body = body if body.endswith("\n") else body + "\n"
        if body != match["body"]:
            changed.append(name)
        return match.group(1) + body + match.group(4)

    return BLOCK.sub(fill, text), changed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 when a block differs")
    args = parser.parse_args(argv)
    stale = []
    for path in DOCUMENTS:
        text = path.read_text(encoding="utf-8")
        new, changed = update(text, str(path))
        stale += [f"{path.relative_to(REPO)}: {name}" for name in changed]
        if changed and not args.check:
            path.write_text(new, encoding="utf-8")
    if stale:
        print(("differs from its CSVs: " if args.check else "re-made: ") + "; ".join(stale))
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
