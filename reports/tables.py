"""Paper tables from a results frame: summary.md / summary.tex, timing.csv / timing.md.

Input contract (``benchmark.runner.results_frame``): one row per (shape, method, seed) job with
``shape, method, seed, status ('ok'|'failed'), error``, raw metric columns (never scaled: ``cd, nc,
f1_<tau>, ecd, ef1``, ``ecd_flag`` = the prediction had no sharp-edge point so ``ecd`` is NaN),
validity columns (``n_vertices, n_faces, boundary_edges, nonmanifold_edges, components, watertight``)
and wall-clock timings in seconds in columns ending in ``_s``. ``floor`` has one row per shape with
the same metric columns (GT against an independent resample of itself, SPEC section 7).

Aggregation: every statistic of a method is over its successful jobs (status 'ok'), i.e. over
shapes x seeds; failed jobs are counted, never averaged. NaN metric values (ECD of a prediction
without edge points) are skipped by the mean/median/std and counted in the ``ECD NaN`` column.
std is the sample standard deviation (ddof = 1). Metrics are shown in the paper's units: the raw
value times the preset's table multiplier (``default``: CD x 1e3, ECD x 1e2; ``ndc``: CD x 1e5, ECD
x 1e2), three decimals. Best per column (lowest CD/ECD, highest NC/F1/EF1, compared at the printed
precision, ties all bold) is bold among methods; the floor row is a reference, never bold.

Every table is built once as a :class:`Table` (strings + bold flags) and written as Markdown
(pandas ``to_markdown`` / tabulate), LaTeX (booktabs, written here) or HTML (``reports.html``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

DASH = "–"
DIGITS = 3

#: Default table multipliers when no preset information is available (SPEC section 7, ``default``).
DEFAULT_SCALES = {"cd": 1e3, "ecd": 1e2}
METRIC_NAMES = {"cd": "CD", "nc": "NC", "ecd": "ECD", "ef1": "EF1"}
LOWER_IS_BETTER = {"cd", "ecd"}
VALIDITY_COLUMNS = (
    ("n_vertices", "#V", "mean"),
    ("n_faces", "#F", "mean"),
    ("boundary_edges", "boundary edges", "mean"),
    ("nonmanifold_edges", "non-manifold edges", "mean"),
    ("components", "components", "mean"),
    ("watertight", "watertight %", "percent"),
)
STAGE_LABELS = {
    "load_s": "loading",
    "sample_s": "sampling",
    "label_s": "labelling",
    "fit_s": "fitting",
    "query_s": "field queries",
    "extract_s": "extraction",
    "metrics_s": "metrics",
    "total_s": "total",
}
STAGE_ORDER = tuple(STAGE_LABELS)


# ---------------------------------------------------------------------------------------------
# Metric specification (which columns, in which units)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MetricSpec:
    """One reported metric: result column, display name, table multiplier, better direction."""

    column: str
    name: str
    scale: float = 1.0
    lower_is_better: bool = False

    @property
    def arrow(self) -> str:
        return "↓" if self.lower_is_better else "↑"

    @property
    def scale_text(self) -> str:
        """'×1e3' for a power-of-ten multiplier, '×2.5' otherwise, '' for 1."""
        if self.scale == 1:
            return ""
        exponent = math.log10(self.scale)
        if abs(exponent - round(exponent)) < 1e-9:
            return f"×1e{round(exponent)}"
        return f"×{self.scale:g}"

    @property
    def header(self) -> str:
        """Plain-text header, e.g. 'CD ×1e3 ↓'."""
        return " ".join(part for part in (self.name, self.scale_text, self.arrow) if part)

    @property
    def tex_header(self) -> str:
        scale = ""
        if self.scale != 1:
            exponent = math.log10(self.scale)
            if abs(exponent - round(exponent)) < 1e-9:
                scale = rf" ($\times 10^{{{round(exponent)}}}$)"
            else:
                scale = rf" ($\times {self.scale:g}$)"
        arrow = r"$\downarrow$" if self.lower_is_better else r"$\uparrow$"
        return f"{tex_escape(self.name)}{scale} {arrow}"


def tau_from_column(column: str) -> float | None:
    """F1 threshold of an ``f1_<digits>`` column: 'f1_005' -> 0.005, 'f1_01' -> 0.01 (the digits
    follow '0.'; benchmark.metrics names them this way). None for other names."""
    match = re.fullmatch(r"f1_(\d+)", column)
    return float("0." + match.group(1)) if match else None


def tau_column(tau: float) -> str:
    """Inverse of :func:`tau_from_column`: 0.005 -> 'f1_005'."""
    text = f"{tau:.10f}".rstrip("0").rstrip(".")
    return f"f1_{text[2:]}" if text.startswith("0.") else "f1_" + text.replace(".", "_")


def preset_info(config: dict | None) -> dict:
    """The metric protocol as a dict: ``config['metric_preset']`` when it is a dict; when it is a
    name, the fields of ``benchmark.metrics.PRESETS[name]`` (if importable); {} when unknown."""
    config = config or {}
    preset = config.get("metric_preset")
    if isinstance(preset, dict):
        return dict(preset)
    if hasattr(preset, "to_dict"):
        return dict(preset.to_dict())
    if isinstance(preset, str):
        try:
            from benchmark.metrics import PRESETS
        except Exception:  # noqa: BLE001 -- tables must work from the frames alone
            return {"name": preset}
        if preset in PRESETS:
            return dict(PRESETS[preset].to_dict())
        return {"name": preset}
    return {}


def metric_specs(config: dict | None, columns) -> list[MetricSpec]:
    """The reported metrics, in paper order (CD, NC, F1@tau..., ECD, EF1), restricted to ``columns``.

    Multipliers and F1 thresholds come from the preset (``cd_scale``, ``ecd_scale``,
    ``f1_thresholds``); without preset information, from the ``f1_*`` columns present and the
    ``default`` multipliers (CD x 1e3, ECD x 1e2).
    """
    columns = list(columns)
    info = preset_info(config)
    taus = info.get("f1_thresholds")
    if taus:
        f1_columns = [tau_column(float(t)) for t in taus]
    else:
        f1_columns = sorted((c for c in columns if tau_from_column(c) is not None), key=tau_from_column)
    scales = dict(DEFAULT_SCALES)
    for key in ("cd", "ecd"):
        if info.get(f"{key}_scale") is not None:
            scales[key] = float(info[f"{key}_scale"])
    specs = [MetricSpec("cd", "CD", scales["cd"], True), MetricSpec("nc", "NC")]
    specs += [MetricSpec(c, f"F1@{tau_from_column(c):g}") for c in f1_columns]
    specs += [MetricSpec("ecd", "ECD", scales["ecd"], True), MetricSpec("ef1", "EF1")]
    return [s for s in specs if s.column in columns]


# ---------------------------------------------------------------------------------------------
# Input checks and small helpers
# ---------------------------------------------------------------------------------------------


def check_results(results: pd.DataFrame, what: str = "results") -> pd.DataFrame:
    """A copy with the bookkeeping columns normalised; one-line ValueError on a bad frame."""
    if not isinstance(results, pd.DataFrame):
        raise ValueError(f"{what} must be a pandas DataFrame, got {type(results).__name__}")
    missing = [c for c in ("shape", "method") if c not in results.columns]
    if missing:
        raise ValueError(f"{what} frame lacks column(s) {', '.join(missing)}")
    df = results.copy()
    df["shape"] = df["shape"].astype(str)
    df["method"] = df["method"].astype(str)
    if "status" not in df.columns:
        df["status"] = "ok"
    df["status"] = df["status"].fillna("failed").astype(str)
    if "seed" not in df.columns:
        df["seed"] = 0
    if "error" not in df.columns:
        df["error"] = None
    return df


def check_floor(floor) -> pd.DataFrame | None:
    """A copy of the floor frame (None when absent or empty); 'shape' as text when present."""
    if floor is None:
        return None
    if not isinstance(floor, pd.DataFrame):
        raise ValueError(f"floor must be a pandas DataFrame or None, got {type(floor).__name__}")
    if not len(floor):
        return None
    df = floor.copy()
    if "shape" in df.columns:
        df["shape"] = df["shape"].astype(str)
    if "status" in df.columns:  # a floor row that could not be computed is not a reference
        df = df[df["status"].fillna("ok").astype(str) == "ok"]
    return df if len(df) else None


def as_bool(values: pd.Series) -> pd.Series:
    """0/1, True/False, 'yes'/'true' (SQLite gives ints) -> bool; NaN -> False."""
    if values.dtype == bool:
        return values
    text = values.astype(str).str.strip().str.lower()
    numeric = pd.to_numeric(values, errors="coerce")
    return (numeric.fillna(0) > 0.5) | text.isin(("true", "yes"))


def ok_jobs(results: pd.DataFrame) -> pd.DataFrame:
    return results[results["status"] == "ok"]


def method_order(results: pd.DataFrame, config: dict | None = None) -> list[str]:
    """Methods in the run's order (``config['methods']``), then any others in order of appearance."""
    present = list(dict.fromkeys(results["method"].astype(str)))
    wanted = [m for m in (config or {}).get("methods", []) or [] if m in present]
    return wanted + [m for m in present if m not in wanted]


def shape_order(results: pd.DataFrame, floor: pd.DataFrame | None, config: dict | None = None) -> list[str]:
    present = list(dict.fromkeys(list(results["shape"].astype(str)) + (
        list(floor["shape"].astype(str)) if floor is not None and "shape" in floor.columns else [])))
    wanted = [s for s in (config or {}).get("shapes", []) or [] if s in present]
    return wanted + [s for s in present if s not in wanted]


def fmt(value, digits: int = DIGITS) -> str:
    """Fixed-point text; NaN/None -> an en dash."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return DASH
    return f"{value:.{digits}f}"


def numeric(frame: pd.DataFrame, column: str) -> pd.Series:
    if column not in frame.columns:
        return pd.Series(np.nan, index=frame.index, dtype=float)
    return pd.to_numeric(frame[column], errors="coerce").astype(float)


def best_flags(values: list[float], lower_is_better: bool, digits: int = DIGITS) -> list[bool]:
    """True where the value (rounded to the printed precision) is the best of the finite ones."""
    rounded = [round(v, digits) if v is not None and np.isfinite(v) else None for v in values]
    finite = [v for v in rounded if v is not None]
    if not finite:
        return [False] * len(values)
    best = min(finite) if lower_is_better else max(finite)
    return [v is not None and v == best for v in rounded]


# ---------------------------------------------------------------------------------------------
# Table structure and writers
# ---------------------------------------------------------------------------------------------


@dataclass
class Cell:
    text: str
    bold: bool = False
    title: str | None = None  # hover text in HTML (e.g. an error message)


@dataclass
class Table:
    """A rendered-agnostic table: headers, per-column alignment ('l'/'r'), rows of cells, and a
    kind per row ('method', 'floor', 'sum', 'total', 'step', 'run') for styling."""

    key: str
    title: str
    caption: str
    headers: list[str]
    tex_headers: list[str]
    align: list[str]
    rows: list[list[Cell]] = field(default_factory=list)
    row_kinds: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def add(self, cells: list[Cell], kind: str = "method") -> None:
        if len(cells) != len(self.headers):
            raise ValueError(f"table {self.key}: row has {len(cells)} cells for {len(self.headers)} columns")
        self.rows.append(cells)
        self.row_kinds.append(kind)

    def column(self, header: str) -> list[str]:
        """Plain texts of one column (tests, HTML)."""
        k = self.headers.index(header)
        return [r[k].text for r in self.rows]


def table_markdown(table: Table) -> str:
    """GitHub Markdown via pandas/tabulate; bold cells as **x**."""
    body = [[f"**{c.text}**" if c.bold and c.text != DASH else c.text for c in row] for row in table.rows]
    frame = pd.DataFrame(body, columns=table.headers)
    if frame.empty:
        return "| " + " | ".join(table.headers) + " |\n|" + "---|" * len(table.headers) + "\n"
    colalign = ["left" if a == "l" else "right" for a in table.align]
    return frame.to_markdown(index=False, disable_numparse=True, colalign=colalign) + "\n"


_TEX_REPLACE = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "×": r"$\times$",
    "↓": r"$\downarrow$",
    "↑": r"$\uparrow$",
    "–": "--",
    "—": "---",
    "±": r"$\pm$",
    "≤": r"$\leq$",
    "≥": r"$\geq$",
    "·": r"$\cdot$",
    "³": r"$^3$",
    "²": r"$^2$",
    "|": r"$|$",
    "<": r"$<$",
    ">": r"$>$",
}
_TEX_PATTERN = re.compile("|".join(re.escape(k) for k in _TEX_REPLACE))


def tex_escape(text: str) -> str:
    """Plain (unicode) text -> LaTeX source, escaping the specials and mapping ×, ↓, ↑, – etc."""
    return _TEX_PATTERN.sub(lambda m: _TEX_REPLACE[m.group(0)], str(text))


def table_latex(table: Table) -> str:
    """A booktabs ``table`` float (needs ``\\usepackage{booktabs}``); bold as \\textbf{x}."""
    spec = "".join(table.align)
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\small",
        rf"\caption{{{tex_escape(table.title)}. {tex_escape(table.caption)}}}",
        rf"\label{{tab:salsbench-{table.key}}}",
        rf"\begin{{tabular}}{{{spec}}}",
        r"\toprule",
        " & ".join(table.tex_headers) + r" \\",
        r"\midrule",
    ]
    previous = None
    for row, kind in zip(table.rows, table.row_kinds):
        if previous is not None and kind != previous and "floor" in (kind, previous):
            lines.append(r"\midrule")
        cells = [rf"\textbf{{{tex_escape(c.text)}}}" if c.bold and c.text != DASH else tex_escape(c.text) for c in row]
        if kind == "floor":
            cells = [rf"\textit{{{c}}}" for c in cells]
        lines.append(" & ".join(cells) + r" \\")
        previous = kind
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# Protocol caption
# ---------------------------------------------------------------------------------------------


def _join(values) -> str:
    if isinstance(values, (list, tuple)):
        return ", ".join(str(v) for v in values)
    return str(values)


def protocol_items(config: dict | None, results: pd.DataFrame | None = None) -> list[tuple[str, str]]:
    """(label, value) pairs describing the protocol, for captions and the HTML page."""
    config = config or {}
    info = preset_info(config)
    items: list[tuple[str, str]] = []
    dataset = config.get("dataset")
    n_shapes = results["shape"].nunique() if results is not None and len(results) else None
    if dataset is not None or n_shapes is not None:
        items.append(("dataset", f"{dataset or '?'}" + (f" ({n_shapes} shapes)" if n_shapes is not None else "")))
    for key in ("mode", "budget"):
        if config.get(key) is not None:
            items.append((key, str(config[key])))
    if config.get("grid") is not None:
        items.append(("grid", f"{config['grid']}³ points on [-1, 1]³"))
    seeds = config.get("seeds")
    if seeds is None and results is not None and "seed" in results.columns and len(results):
        seeds = sorted(pd.unique(results["seed"]).tolist())
    if seeds is not None:
        items.append(("seeds", _join(seeds)))
    name = info.get("name") or (config.get("metric_preset") if isinstance(config.get("metric_preset"), str) else None)
    if name:
        items.append(("metric preset", str(name)))
    frame = info.get("frame")
    if frame:
        items.append(("frame", {
            "canonical": "GT canonical frame (bbox centred, largest side 1.99)",
            "diag1": "GT bbox centred, diagonal 1 (NDC)",
        }.get(frame, str(frame))))
    n_points = config.get("eval_points_effective") or config.get("eval_points") or info.get("n_points")
    if n_points:
        items.append(("points per mesh", f"{int(n_points):,}"))
    if info.get("f1_thresholds"):
        items.append(("F1 thresholds", _join([f"{float(t):g}" for t in info["f1_thresholds"]])))
    if info.get("edge_radius") is not None:
        unit = " D" if info.get("edge_units") == "gt_diagonal" else ""
        text = f"r = {float(info['edge_radius']):g}{unit}"
        if info.get("edge_dot_threshold") is not None:
            text += f", |n·n| < {float(info['edge_dot_threshold']):g}"
        items.append(("sharp-edge points", text))
        if info.get("ef1_threshold") is not None:
            items.append(("EF1 threshold", f"{float(info['ef1_threshold']):g}{unit}"))
        if unit:
            items.append(("D", "GT bounding-box diagonal"))
    if info.get("chamfer"):
        items.append(("CD form", {"l1_half_mean": "½(mean d(g→P) + mean d(p→G)), unsquared",
                                   "squared_sum": "mean d(g→P)² + mean d(p→G)²"}.get(info["chamfer"], str(info["chamfer"]))))
    if "empty_edge_fallback" in info:
        k = info["empty_edge_fallback"]
        items.append(("no predicted edge points", "ECD NaN (counted), EF1 = 0" if not k else f"{k} origin points scored"))
    known = {"name", "frame", "n_points", "f1_thresholds", "edge_radius", "edge_units", "edge_dot_threshold",
             "ef1_threshold", "chamfer", "ecd", "cd_scale", "ecd_scale", "empty_edge_fallback"}
    for key, value in info.items():
        if key not in known and not isinstance(value, (dict, list)):
            items.append((key.replace("_", " "), str(value)))
    if not info and config.get("metric_protocol"):
        items.append(("metrics", str(config["metric_protocol"])))
    return items


def device_text(config: dict | None, results: pd.DataFrame | None = None) -> str:
    """'cpu (AMD EPYC ...)' from the config, else the device column of the results."""
    config = config or {}
    env = config.get("environment") if isinstance(config.get("environment"), dict) else {}
    look = {**env, **{k: v for k, v in config.items() if v}}  # top-level keys win over environment
    device = look.get("device")
    if not device and results is not None and "device" in results.columns:
        devices = [str(d) for d in pd.unique(results["device"].dropna())]
        device = ", ".join(devices) if devices else None
    extra = [str(look[k]) for k in ("gpu", "cpu_model", "cpu") if look.get(k)]
    text = str(device) if device else "device not recorded"
    extra = [e for e in extra if e not in text]
    return text + (f" ({'; '.join(extra)})" if extra else "")


def protocol_caption(config: dict | None, results: pd.DataFrame | None = None) -> str:
    return "Protocol: " + "; ".join(f"{k}: {v}" for k, v in protocol_items(config, results)) + "."


# ---------------------------------------------------------------------------------------------
# Summary statistics
# ---------------------------------------------------------------------------------------------


def method_statistics(results: pd.DataFrame, floor: pd.DataFrame | None, specs: list[MetricSpec],
                      methods: list[str]) -> dict[str, pd.DataFrame]:
    """{'mean'|'median'|'std': DataFrame indexed by method (+ 'floor'), columns = metric columns,
    values scaled to table units}, plus 'counts' (jobs, failed, ok, ecd_nan per method)."""
    ok = ok_jobs(results)
    out = {}
    for stat in ("mean", "median", "std"):
        rows = {}
        for m in methods:
            sel = ok[ok["method"] == m]
            rows[m] = {s.column: getattr(numeric(sel, s.column), stat)() * s.scale for s in specs}
        if floor is not None and len(floor):
            rows["floor"] = {s.column: getattr(numeric(floor, s.column), stat)() * s.scale for s in specs}
        out[stat] = pd.DataFrame.from_dict(rows, orient="index", columns=[s.column for s in specs])
    counts = {}
    for m in methods:
        sel = results[results["method"] == m]
        good = ok_jobs(sel)
        if "ecd_flag" in good.columns:
            nan_ecd = int((as_bool(good["ecd_flag"]) | numeric(good, "ecd").isna()).sum()) if "ecd" in good.columns else int(as_bool(good["ecd_flag"]).sum())
        else:
            nan_ecd = int(numeric(good, "ecd").isna().sum()) if "ecd" in good.columns else 0
        counts[m] = {"jobs": len(sel), "failed": int((sel["status"] != "ok").sum()), "ok": len(good),
                     "ecd_nan": nan_ecd}
    if floor is not None and len(floor):
        flag = as_bool(floor["ecd_flag"]) if "ecd_flag" in floor.columns else pd.Series(False, index=floor.index)
        counts["floor"] = {"jobs": len(floor), "failed": np.nan, "ok": len(floor),
                           "ecd_nan": int((flag | numeric(floor, "ecd").isna()).sum()) if "ecd" in floor.columns else 0}
    out["counts"] = pd.DataFrame.from_dict(counts, orient="index")
    return out


FLOOR_LABEL = "floor (GT vs resample)"


def statistic_table(stats: dict[str, pd.DataFrame], specs: list[MetricSpec], methods: list[str], stat: str,
                    caption: str, key: str, bold: bool = True, row_label=None) -> Table:
    """Methods x metrics table of one statistic, with the jobs/failed counts and 'ECD NaN' next to ECD."""
    headers, tex_headers, align = ["method", "jobs", "failed"], ["method", "jobs", "failed"], ["l", "r", "r"]
    for s in specs:
        headers.append(s.header)
        tex_headers.append(s.tex_header)
        align.append("r")
        if s.column == "ecd":
            headers.append("ECD NaN")
            tex_headers.append("ECD NaN")
            align.append("r")
    title = {"mean": "Mean over shapes and seeds", "median": "Median over shapes and seeds",
             "std": "Standard deviation over shapes and seeds"}[stat]
    table = Table(key, title, caption, headers, tex_headers, align)
    values, counts = stats[stat], stats["counts"]
    flags = {s.column: best_flags([values.at[m, s.column] for m in methods], s.lower_is_better)
             if bold and stat != "std" else [False] * len(methods) for s in specs}
    labels = list(methods) + (["floor"] if "floor" in values.index else [])
    for i, m in enumerate(labels):
        c = counts.loc[m]
        cells = [Cell(FLOOR_LABEL if m == "floor" else (row_label(m) if row_label else m)),
                 Cell(str(int(c["jobs"]))), Cell(DASH if m == "floor" else str(int(c["failed"])))]
        for s in specs:
            cells.append(Cell(fmt(values.at[m, s.column]), bold=(m != "floor" and flags[s.column][i])))
            if s.column == "ecd":
                cells.append(Cell(str(int(c["ecd_nan"]))))
        table.add(cells, "floor" if m == "floor" else "method")
    return table


def validity_table(results: pd.DataFrame, floor: pd.DataFrame | None, methods: list[str], caption: str) -> Table:
    """Mean mesh-validity counts of the predictions per method (GT row from the floor frame)."""
    present = [(c, h, how) for c, h, how in VALIDITY_COLUMNS if c in results.columns]
    headers = ["method", "jobs ok"] + [h for _, h, _ in present]
    table = Table("validity", "Mesh validity of the predictions (mean over successful jobs)", caption,
                  headers, [tex_escape(h) for h in headers], ["l"] + ["r"] * (len(headers) - 1))
    ok = ok_jobs(results)

    def row(frame: pd.DataFrame) -> list[Cell]:
        cells = []
        for c, _, how in present:
            if c not in frame.columns or not len(frame):
                cells.append(Cell(DASH))
            elif how == "percent":
                vals = frame[c].dropna()
                cells.append(Cell(fmt(100.0 * as_bool(vals).mean(), 0) if len(vals) else DASH))
            else:
                v = numeric(frame, c).mean()
                cells.append(Cell(fmt(v, 0 if c.startswith("n_") else 1)))
        return cells

    for m in methods:
        sel = ok[ok["method"] == m]
        table.add([Cell(m), Cell(str(len(sel)))] + row(sel))
    if floor is not None and len(floor) and any(c in floor.columns for c, _, _ in present):
        table.add([Cell("GT"), Cell(str(len(floor)))] + row(floor), "floor")
    return table


def per_shape_table(results: pd.DataFrame, floor: pd.DataFrame | None, spec: MetricSpec, methods: list[str],
                    shapes: list[str], caption: str) -> Table:
    """Shapes x methods (mean over the seeds of successful jobs) for one metric; 'failed' where
    every seed failed; 'NaN' where the metric is undefined (no predicted edge points). Best per row
    in bold; the floor column is a reference."""
    has_floor = floor is not None and "shape" in floor.columns and spec.column in floor.columns
    headers = ["shape"] + methods + (["floor"] if has_floor else [])
    table = Table(f"shape-{spec.column}", f"Per shape: {spec.header} (mean over seeds)", caption, headers,
                  ["shape"] + [tex_escape(m) for m in methods] + (["floor"] if has_floor else []),
                  ["l"] + ["r"] * (len(headers) - 1))
    for shape in shapes:
        values, texts, titles = [], [], []
        for m in methods:
            jobs = results[(results["shape"] == shape) & (results["method"] == m)]
            good = ok_jobs(jobs)
            if not len(jobs):
                values.append(np.nan), texts.append(DASH), titles.append(None)
            elif not len(good):
                values.append(np.nan), texts.append("failed")
                titles.append(str(jobs["error"].dropna().iloc[0]) if jobs["error"].notna().any() else None)
            else:
                v = numeric(good, spec.column).mean() * spec.scale
                values.append(v)
                texts.append(fmt(v) if np.isfinite(v) else "NaN")
                titles.append(None)
        flags = best_flags(values, spec.lower_is_better)
        cells = [Cell(shape)] + [Cell(t, b, title) for t, b, title in zip(texts, flags, titles)]
        if has_floor:
            fv = numeric(floor[floor["shape"].astype(str) == shape], spec.column).mean() * spec.scale
            cells.append(Cell(fmt(fv)))
        table.add(cells)
    return table


def failed_jobs(results: pd.DataFrame) -> pd.DataFrame:
    """shape, method, seed, error of every job whose status is not 'ok'."""
    bad = results[results["status"] != "ok"]
    return bad[["shape", "method", "seed", "error"]].reset_index(drop=True)


@dataclass
class Summary:
    """Everything the writers need, computed once."""

    specs: list[MetricSpec]
    methods: list[str]
    shapes: list[str]
    stats: dict[str, pd.DataFrame]
    tables: dict[str, Table]
    caption: str
    failed: pd.DataFrame


def build_summary(results: pd.DataFrame, floor: pd.DataFrame | None, config: dict | None) -> Summary:
    results = check_results(results)
    floor = check_floor(floor)
    specs = metric_specs(config, results.columns)
    methods = method_order(results, config)
    shapes = shape_order(results, floor, config)
    stats = method_statistics(results, floor, specs, methods)
    caption = protocol_caption(config, results)
    notes = ("Statistics over successful jobs (shapes × seeds); failed jobs are counted, not averaged. "
             "ECD NaN: jobs whose prediction has no sharp-edge point (ECD undefined, excluded from the ECD "
             "statistics; EF1 = 0 is included). Floor: GT against an independent resample of itself "
             "(the protocol's sampling noise). Best method per column in bold.")
    tables = {
        "mean": statistic_table(stats, specs, methods, "mean", caption, "mean"),
        "median": statistic_table(stats, specs, methods, "median", caption, "median"),
        "std": statistic_table(stats, specs, methods, "std", caption, "std", bold=False),
        "validity": validity_table(results, floor, methods, caption),
    }
    tables["mean"].notes.append(notes)
    tables["std"].notes.append("Sample standard deviation (ddof = 1) over successful jobs; – with fewer than 2.")
    for s in specs:
        if s.column in ("cd", "ecd"):
            tables[f"shape-{s.column}"] = per_shape_table(results, floor, s, methods, shapes, caption)
    return Summary(specs, methods, shapes, stats, tables, caption, failed_jobs(results))


def summary_markdown(summary: Summary, title: str) -> str:
    parts = [f"# {title}", "", summary.caption, ""]
    for table in summary.tables.values():
        parts += [f"## {table.title}", "", table_markdown(table)]
        parts += [f"*{n}*" + "\n" for n in table.notes]
    if len(summary.failed):
        parts += ["## Failed jobs", ""]
        parts += [f"- {r.shape} / {r.method} / seed {r.seed}: {one_line(r.error)}" for r in summary.failed.itertuples()]
        parts.append("")
    return "\n".join(parts)


def summary_latex(summary: Summary, title: str) -> str:
    head = [f"% {title}: generated by salsbench (reports.tables). Needs \\usepackage{{booktabs}}.", ""]
    return "\n".join(head) + "\n".join(table_latex(t) for t in summary.tables.values())


def one_line(text) -> str:
    if text is None or (isinstance(text, float) and not np.isfinite(text)):
        return "(no error text recorded)"
    return " ".join(str(text).split())


# ---------------------------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------------------------


def timing_stages(columns) -> list[tuple[str, str, str]]:
    """(column, label, level) for the timing columns present, in pipeline order. level: 'stage'
    (summed), 'step' (a sub-step '<stage>_<step>_s' of a stage present, not summed), 'total'."""
    cols = [c for c in columns if str(c).endswith("_s")]
    stages = [c for c in STAGE_ORDER if c in cols and c != "total_s"]
    parents = {c[:-2] for c in stages}
    steps = {}
    others = []
    for c in cols:
        if c in STAGE_LABELS:
            continue
        parent = next((p for p in parents if c.startswith(p + "_")), None)
        if parent:
            steps.setdefault(parent + "_s", []).append(c)
        else:
            others.append(c)
    out = []
    for c in stages:
        if c == "metrics_s":  # unknown stages go before scoring
            out += [(o, o[:-2].replace("_", " "), "stage") for o in others]
        out.append((c, STAGE_LABELS[c], "stage"))
        for step in steps.get(c, []):
            out.append((step, f"{STAGE_LABELS[c]}: {step[len(c) - 1:-2].replace('_', ' ')}", "step"))
    if "metrics_s" not in stages:
        out += [(o, o[:-2].replace("_", " "), "stage") for o in others]
    if "total_s" in cols:
        out.append(("total_s", "total", "total"))
    return out


def timing_frame(results: pd.DataFrame, config: dict | None = None) -> pd.DataFrame:
    """Tidy timing statistics: method, stage (column), label, level, n_jobs, mean_s, median_s,
    std_s, device. Over successful jobs (all jobs of a method when none succeeded). A row
    'sum_of_stages' per method is the sum of the stage means (sub-steps and total excluded)."""
    results = check_results(results)
    stages = timing_stages(results.columns)
    device = device_text(config, results)
    rows = []
    for m in method_order(results, config):
        jobs = results[results["method"] == m]
        good = ok_jobs(jobs)
        use = good if len(good) else jobs
        total_of_stages = 0.0
        for col, label, level in stages:
            if level == "total":
                rows.append(dict(method=m, stage="sum_of_stages", label="sum of stages", level="sum",
                                 n_jobs=len(use), mean_s=total_of_stages, median_s=np.nan, std_s=np.nan, device=device))
            v = numeric(use, col)
            if not v.notna().any():  # a stage this method does not have (another method's sub-step)
                continue
            mean = v.mean()
            rows.append(dict(method=m, stage=col, label=label, level=level, n_jobs=int(v.notna().sum()),
                             mean_s=mean, median_s=v.median(), std_s=v.std(), device=device))
            if level == "stage" and np.isfinite(mean):
                total_of_stages += mean
        if not any(level == "total" for _, _, level in stages):
            rows.append(dict(method=m, stage="sum_of_stages", label="sum of stages", level="sum", n_jobs=len(use),
                             mean_s=total_of_stages, median_s=np.nan, std_s=np.nan, device=device))
    columns = ["method", "stage", "label", "level", "n_jobs", "mean_s", "median_s", "std_s", "device"]
    return pd.DataFrame(rows, columns=columns)


def timing_table(timing: pd.DataFrame, stat: str, caption: str, label_of=None) -> Table:
    """Stages x methods table of one timing statistic ('mean_s' or 'median_s'), seconds."""
    methods = list(dict.fromkeys(timing["method"]))
    headers = ["stage"] + [label_of(m) if label_of else m for m in methods]
    title = {"mean_s": "Wall-clock seconds per job (mean)", "median_s": "Wall-clock seconds per job (median)"}[stat]
    table = Table(f"timing-{stat[:-2]}", title, caption, headers, [tex_escape(h) for h in headers],
                  ["l"] + ["r"] * len(methods))
    order = list(dict.fromkeys(zip(timing["stage"], timing["label"], timing["level"])))
    pipeline = [c for c, _, _ in timing_stages(list(dict.fromkeys(timing["stage"])))]
    pipeline.insert(pipeline.index("total_s") if "total_s" in pipeline else len(pipeline), "sum_of_stages")
    order.sort(key=lambda o: pipeline.index(o[0]) if o[0] in pipeline else len(pipeline))
    if stat != "mean_s":
        order = [o for o in order if o[2] != "sum"]
    for stage, label, level in order:
        cells = [Cell(("  " if level == "step" else "") + label, bold=level in ("total", "sum"))]
        for m in methods:
            sel = timing[(timing["method"] == m) & (timing["stage"] == stage)]
            cells.append(Cell(fmt(float(sel[stat].iloc[0]), 2) if len(sel) else DASH))
        table.add(cells, level)
    return table


def timing_caption(timing: pd.DataFrame, config: dict | None, results: pd.DataFrame | None = None) -> str:
    n = timing.groupby("method")["n_jobs"].max() if len(timing) else pd.Series(dtype=int)
    jobs = ", ".join(f"{m}: {int(k)}" for m, k in n.items())
    cached = ""
    if results is not None and "cache" in results.columns:
        n_cached = int(results["cache"].notna().sum() - (results["cache"].astype(str).str.strip() == "").sum())
        if n_cached:
            cached = (f" {n_cached} job(s) reused cached results: their stage times are those of the job that "
                      f"computed them, their total is the time actually spent, so the total can be below the sum.")
    return (f"Wall-clock seconds per job (shape × seed), over successful jobs ({jobs}). Device: "
            f"{device_text(config, results)}. Extraction sub-steps (indented) are part of extraction and "
            f"not added again; 'sum of stages' adds the stage means; 'total' is the job's wall time "
            f"(includes loading and bookkeeping).{cached} Machines shared with other work give noisy "
            f"absolute times: compare methods within one run.")


def timing_markdown(timing: pd.DataFrame, caption: str, title: str) -> str:
    parts = [f"# {title}", "", caption, ""]
    for stat in ("mean_s", "median_s"):
        table = timing_table(timing, stat, caption)
        parts += [f"## {table.title}", "", table_markdown(table)]
    return "\n".join(parts)


# ---------------------------------------------------------------------------------------------
# Writers
# ---------------------------------------------------------------------------------------------


def report_title(config: dict | None) -> str:
    dataset = (config or {}).get("dataset")
    return f"salsbench summary: {dataset}" if dataset else "salsbench summary"


def write_tables(results: pd.DataFrame, floor: pd.DataFrame | None, config: dict | None, out_dir: Path,
                 summary: Summary | None = None) -> dict[str, Path]:
    """summary.md, summary.tex, timing.csv, timing.md in ``out_dir``; returns {name: path}."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = summary or build_summary(results, floor, config)
    title = report_title(config)
    paths = {"summary.md": out_dir / "summary.md", "summary.tex": out_dir / "summary.tex",
             "timing.csv": out_dir / "timing.csv", "timing.md": out_dir / "timing.md"}
    paths["summary.md"].write_text(summary_markdown(summary, title), encoding="utf-8")
    paths["summary.tex"].write_text(summary_latex(summary, title), encoding="utf-8")
    checked = check_results(results)
    timing = timing_frame(checked, config)
    timing.to_csv(paths["timing.csv"], index=False, float_format="%.6g")
    paths["timing.md"].write_text(
        timing_markdown(timing, timing_caption(timing, config, checked), "salsbench timing"), encoding="utf-8")
    return paths


# ---------------------------------------------------------------------------------------------
# Several runs side by side
# ---------------------------------------------------------------------------------------------


@dataclass
class Run:
    label: str
    results: pd.DataFrame
    floor: pd.DataFrame | None
    config: dict
    meshes_dir: Path | None = None


def as_runs(run_frames) -> list[Run]:
    """Accept (label, results, floor, config[, meshes_dir]) tuples or dicts with keys
    name|label, results, floor, config[, meshes_dir] (benchmark.runner's report command)."""
    runs = []
    for i, item in enumerate(run_frames):
        if isinstance(item, Run):
            runs.append(item)
        elif isinstance(item, dict):
            runs.append(Run(str(item.get("label") or item.get("name") or f"run{i + 1}"), item["results"],
                            item.get("floor"), item.get("config") or {}, item.get("meshes_dir")))
        else:
            item = tuple(item)
            if len(item) not in (4, 5):
                raise ValueError(f"run {i + 1}: expected (label, results, floor, config[, meshes_dir]), got {len(item)} items")
            runs.append(Run(str(item[0]), item[1], item[2], item[3] or {}, item[4] if len(item) == 5 else None))
    if not runs:
        raise ValueError("compare_runs needs at least one run")
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):  # make labels unique: a, a -> a, a (2)
        seen: dict[str, int] = {}
        for r in runs:
            seen[r.label] = seen.get(r.label, 0) + 1
            if seen[r.label] > 1:
                r.label = f"{r.label} ({seen[r.label]})"
    return runs


def comparison_tables(runs: list[Run]) -> list[Table]:
    """One mean table per group of runs sharing a metric protocol (same columns and multipliers):
    rows (run, method) and each run's floor; best per column in bold over all runs of the group."""
    groups: dict[tuple, list[tuple[Run, Summary]]] = {}
    for run in runs:
        s = build_summary(run.results, run.floor, run.config)
        groups.setdefault(tuple(s.specs), []).append((run, s))
    tables = []
    for g, (specs, members) in enumerate(groups.items()):
        specs = list(specs)
        captions = list(dict.fromkeys(s.caption for _, s in members))
        caption = (f"All runs: {captions[0]}" if len(captions) == 1
                   else " ".join(f"[{run.label}] {s.caption}" for run, s in members))
        headers, tex_headers, align = ["run", "method", "jobs", "failed"], ["run", "method", "jobs", "failed"], ["l", "l", "r", "r"]
        for s in specs:
            headers.append(s.header), tex_headers.append(s.tex_header), align.append("r")
            if s.column == "ecd":
                headers.append("ECD NaN"), tex_headers.append("ECD NaN"), align.append("r")
        key = "compare" if len(groups) == 1 else f"compare-{g + 1}"
        table = Table(key, "Runs side by side: mean over shapes and seeds", caption, headers, tex_headers, align)
        entries = [(run, s, m) for run, s in members for m in s.methods]
        flags = {sp.column: best_flags([s.stats["mean"].at[m, sp.column] for _, s, m in entries], sp.lower_is_better)
                 for sp in specs}
        i = 0
        for run, s in members:
            labels = list(s.methods) + (["floor"] if "floor" in s.stats["mean"].index else [])
            for m in labels:
                c = s.stats["counts"].loc[m]
                cells = [Cell(run.label), Cell(FLOOR_LABEL if m == "floor" else m), Cell(str(int(c["jobs"]))),
                         Cell(DASH if m == "floor" else str(int(c["failed"])))]
                for sp in specs:
                    bold = m != "floor" and flags[sp.column][i]
                    cells.append(Cell(fmt(s.stats["mean"].at[m, sp.column]), bold))
                    if sp.column == "ecd":
                        cells.append(Cell(str(int(c["ecd_nan"]))))
                table.add(cells, "floor" if m == "floor" else "method")
                if m != "floor":
                    i += 1
        table.notes.append("Rows: each run's methods and its floor; bold: best over all runs of the table.")
        tables.append(table)
    return tables


def comparison_timing(runs: list[Run]) -> pd.DataFrame:
    frames = []
    for run in runs:
        t = timing_frame(check_results(run.results), run.config)
        t.insert(0, "run", run.label)
        frames.append(t)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def write_comparison_tables(runs: list[Run], out_dir: Path) -> tuple[dict[str, Path], list[Table], pd.DataFrame]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tables = comparison_tables(runs)
    title = "salsbench comparison: " + ", ".join(r.label for r in runs)
    md = [f"# {title}", ""]
    for t in tables:
        md += [f"## {t.title}", "", t.caption, "", table_markdown(t)] + [f"*{n}*\n" for n in t.notes]
    paths = {"summary.md": out_dir / "summary.md", "summary.tex": out_dir / "summary.tex",
             "timing.csv": out_dir / "timing.csv", "timing.md": out_dir / "timing.md"}
    paths["summary.md"].write_text("\n".join(md), encoding="utf-8")
    paths["summary.tex"].write_text(f"% {title}. Needs \\usepackage{{booktabs}}.\n\n" + "\n".join(table_latex(t) for t in tables),
                                    encoding="utf-8")
    timing = comparison_timing(runs)
    timing.to_csv(paths["timing.csv"], index=False, float_format="%.6g")
    tmd = [f"# salsbench timing: {', '.join(r.label for r in runs)}", ""]
    for run in runs:
        sel = timing[timing["run"] == run.label].drop(columns="run")
        cap = timing_caption(sel, run.config, check_results(run.results))
        table = timing_table(sel, "mean_s", cap)
        tmd += [f"## {run.label}: {table.title}", "", cap, "", table_markdown(table)]
    paths["timing.md"].write_text("\n".join(tmd), encoding="utf-8")
    return paths, tables, timing
