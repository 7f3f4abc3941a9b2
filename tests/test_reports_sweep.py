"""Sweep report contract (reports.sweep) from hand-made frames that follow the run layer's contract.

The o-threshold frame (SWEEP): 2 shapes (cube, sphere) x methods sals, bof, one seed, a sweep of
``sals.o_threshold`` in [0.1, 0.5]. CD (raw) of sals per (value, shape): 0.1 -> 0.002, 0.004;
0.5 -> 0.006, 0.010, so the table's mean CD (x1e3) is 3.000 and 8.000. bof does not depend on the
key (NaN in ``sweep.sals.o_threshold``): CD 0.001, 0.003 -> 2.000 in both rows. The oracle ceiling
of sals: 0.1 -> 0.001, 0.002 (1.500); 0.5 -> 0.003, 0.005 (4.000). Boundary edges: 4 per job at
0.5, 0 at 0.1. The cube sals job at 0.1 has its weights from the cache: 1 fit at 0.1, 2 at 0.5.
So the ordinary summary, neural jobs only, has sals CD mean (2 + 4 + 6 + 10) / 4 = 5.500.
Bold compares the methods within one value: bof is the best CD at both values and sals, sharing
only 2 shapes with it (under 6, no test can reach p < 0.05), ties with it (bold, †).
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

import reports
from reports.sweep import COMBINED, axis_scale, build_sweep, run_mode_results, sweep_plot
from tests.test_reports_tables import CONTEXT, md_tables

SHAPES = ["cube", "sphere"]
SWEEP = dict(CONTEXT, methods=["sals", "bof"], shapes=SHAPES, seeds=[0], sweep={"sals.o_threshold": [0.1, 0.5]})
CD = {("sals", "neural", 0.1): (0.002, 0.004), ("sals", "neural", 0.5): (0.006, 0.010),
      ("sals", "oracle", 0.1): (0.001, 0.002), ("sals", "oracle", 0.5): (0.003, 0.005),
      ("bof", "neural", np.nan): (0.001, 0.003)}


def job(shape, method, mode, cd, **extra) -> dict:
    return dict(shape=shape, method=method, mode=mode, seed=0, status="ok", error=None, cd=cd, nc=0.9, f1_005=0.5,
                f1_01=0.8, ecd=10 * cd, ef1=0.5, empty_prediction=0, ecd_flag=0, n_faces=100, boundary_edges=0,
                nonmanifold_edges=0, fit_s=np.nan if mode == "oracle" else 10.0, cache=None, **extra)


def threshold_results() -> pd.DataFrame:
    rows = [job(shape, m, mode, cd, **{"sweep.sals.o_threshold": v})
            for (m, mode, v), cds in CD.items() for shape, cd in zip(SHAPES, cds)]
    frame = pd.DataFrame(rows)
    frame.loc[frame["sweep.sals.o_threshold"] == 0.5, "boundary_edges"] = 4
    cached = (frame["shape"] == "cube") & (frame["method"] == "sals") & (frame["mode"] == "neural")
    frame.loc[cached & (frame["sweep.sals.o_threshold"] == 0.1), "cache"] = "weights,mesh"
    return frame


def rows_of(table) -> dict[tuple, dict[str, str]]:
    """{(lead cells...): {header: text}} of a Table; lead = the columns up to 'series'."""
    lead = table.headers.index("series") + 1
    return {tuple(c.text for c in row[:lead]): {h: c.text for h, c in zip(table.headers, row)} for row in table.rows}


@pytest.fixture(scope="module")
def threshold():
    return build_sweep(threshold_results(), SWEEP)


def test_threshold_table_means_broadcast_and_ceiling(threshold):
    table = threshold.tables["sweep-sals.o_threshold"]
    rows = rows_of(table)
    assert list(rows) == [(v, s) for v in ("0.1", "0.5") for s in ("sals", "bof", "sals (oracle)")]
    cd = {k: r["CD ×1e3 ↓"] for k, r in rows.items()}
    assert (cd["0.1", "sals"], cd["0.5", "sals"]) == ("3.000†", "8.000†")  # 2 shapes: tied with bof by construction
    assert (cd["0.1", "sals (oracle)"], cd["0.5", "sals (oracle)"]) == ("1.500", "4.000")
    assert rows["0.1", "bof"] == {**rows["0.5", "bof"], "sals.o_threshold": "0.1"}  # broadcast: same jobs, same numbers
    assert cd["0.1", "bof"] == "2.000"
    assert [k for k, kind in zip(rows, table.row_kinds) if kind == "floor"] == [("0.1", "sals (oracle)"),
                                                                                 ("0.5", "sals (oracle)")]
    assert (rows["0.1", "sals"]["boundary edges"], rows["0.5", "sals"]["boundary edges"]) == ("0.0", "4.0")
    fits = [rows[k]["fits"] for k in (("0.1", "sals"), ("0.5", "sals"), ("0.1", "sals (oracle)"))]
    assert fits == ["1", "2", "0"]  # the cube's 0.1 weights came from the cache; oracle jobs fit nothing
    assert "bof does not depend on sals.o_threshold: the same jobs for each of its values." in table.caption
    assert "sals (oracle)" in table.caption and "Protocol:" in table.caption
    assert "tied by construction: 0.1 / sals (CD, ECD); 0.5 / sals (CD, ECD)." in table.caption
    assert rows_of(threshold.tables["sweep-sals.o_threshold-median"])["0.5", "sals"]["CD ×1e3 ↓"] == "8.000†"


def test_ordinary_tables_get_no_ceiling_rows(tmp_path):
    results = threshold_results()
    assert set(run_mode_results(results, SWEEP)["mode"]) == {"neural"}
    paths = reports.write_reports(results, None, SWEEP, tmp_path)
    text = paths["summary.md"].read_text()
    mean = md_tables(text)["Mean over shapes and seeds"]
    col = {h: i for i, h in enumerate(mean[0])}
    sals = next(r for r in mean[1:] if r[0] == "sals")
    assert sals[col["jobs"]] == "4" and "5.500" in sals[col["CD ×1e3 ↓"]]  # neural jobs only (bold, interval aside)
    assert "oracle" not in "".join(sum(mean, []))
    assert r"sweep: sals.o\_threshold (0.1, 0.5)" in text  # the summary's protocol says it pools a sweep


def test_two_keys_marginals_and_combinations():
    """grid in [32, 64] x sals.normals in [True, False] (0/1 in the frame, as SQLite returns them).
    sals CD (x1e3): grid 32 -> 4, grid 64 -> 2, plus 1 without normals; bof (no normals
    parameter): grid 32 -> 6, 64 -> 3. The run layer's ``fitted`` flag: sals fits at grid 32 only
    (the grid 64 jobs reuse the weights)."""
    context = dict(SWEEP, sweep={"grid": [32, 64], "sals.normals": [True, False]})
    rows = [job(shape, "sals", "neural", (4 if grid == 32 else 2) * 1e-3 + (0 if normals else 1e-3),
                fitted=int(grid == 32), **{"sweep.grid": grid, "sweep.sals.normals": int(normals)})
            for shape in SHAPES for grid in (32, 64) for normals in (True, False)]
    rows += [job(shape, "bof", "neural", (6 if grid == 32 else 3) * 1e-3,
                 **{"sweep.grid": grid, "sweep.sals.normals": None}) for shape in SHAPES for grid in (32, 64)]
    sweep = build_sweep(pd.DataFrame(rows), context)
    grid, normals = rows_of(sweep.tables["sweep-grid"]), rows_of(sweep.tables["sweep-sals.normals"])
    combos = rows_of(sweep.tables[f"sweep-{COMBINED}"])
    assert sorted({k[0] for k in grid}) == ["32", "64"] and [k[0] for k in normals][::2] == ["True", "False"]
    assert {k[:2] for k in combos} == {("32", "True"), ("32", "False"), ("64", "True"), ("64", "False")}
    assert len(combos) == 8  # 4 combinations x (sals, bof)
    cd = "CD ×1e3 ↓"
    assert (grid["32", "sals"][cd], grid["64", "sals"][cd]) == ("4.500", "2.500")  # pooled over normals; best
    assert (grid["32", "sals"]["fits"], grid["64", "sals"]["fits"], grid["32", "sals"]["jobs"]) == ("4", "0", "4")
    assert (normals["True", "sals"][cd], normals["False", "sals"][cd]) == ("3.000", "4.000")  # pooled over grid
    assert normals["True", "bof"][cd] == normals["False", "bof"][cd] == "4.500†"  # broadcast; 2 shapes: a tie
    assert (combos["32", "False", "sals"][cd], combos["32", "False", "bof"][cd]) == ("5.000", "6.000†")
    assert "pooled over every value of sals.normals (the marginal)" in sweep.tables["sweep-grid"].caption
    assert sweep_plot(sweep, "sals.normals").startswith(b"<?xml")


@pytest.mark.parametrize("values, scale", [
    ([1e5, 1e6, 1e7], "log"), ([1000, 100000], "log"), ([100000, 1000000], "log"), ([0.1, 0.5], "linear"),
    ([0.02, 0.05, 0.1, 0.5], "log"), ([64, 128, 256], "linear"),
    ([-1, 100], "linear"), (["fan4", "quad2"], "categorical"), ([True, False], "categorical")])
def test_axis_scale(values, scale):
    assert axis_scale(values) == scale


def test_write_reports_sweep_files_and_section_order(tmp_path):
    paths = reports.write_reports(threshold_results(), None, SWEEP, tmp_path / "sweep")
    assert {"sweep.md", "sweep.tex", "sweep.csv"} <= set(paths)
    page = paths["report.html"].read_text()
    assert page.index('id="sweep"') < page.index('id="summary"')
    tex = paths["sweep.tex"].read_text()
    assert tex.count(r"\begin{table}") == tex.count(r"\end{tabular}") == 2 and r"\toprule" in tex  # mean, median
    for spec, inner in re.findall(r"\\begin\{tabular\}\{([lr]+)\}(.*?)\\end\{tabular\}", tex, flags=re.S):
        rows = [line for line in inner.splitlines() if line.endswith("\\\\")]
        assert all(len(re.split(r"(?<!\\)&", line)) == len(spec) for line in rows)
    assert "sals (oracle)" in paths["sweep.md"].read_text()
    csv = pd.read_csv(paths["sweep.csv"])
    cd = csv[(csv["quantity"] == "cd")].set_index(["value", "series"])
    assert cd.loc[(0.5, "sals"), "mean"] == pytest.approx(8.0) and cd.loc[(0.5, "sals"), "n_jobs"] == 2
    assert cd.loc[(0.1, "bof"), "broadcast"] and cd.loc[(0.1, "sals (oracle)"), "ceiling"]
    assert cd.loc[(0.1, "sals"), "scale"] == 1000
    plain = reports.write_reports(threshold_results().query("mode == 'neural'"), None, CONTEXT | {
        "methods": ["sals", "bof"], "shapes": SHAPES}, tmp_path / "plain")
    assert not any(name.startswith("sweep") for name in plain) and not list((tmp_path / "plain").glob("sweep*"))
    assert 'id="sweep"' not in plain["report.html"].read_text()


def noisy_results() -> pd.DataFrame:
    """20 shapes; bof (broadcast over the key) CD (raw) 0.002 + 0.0001 i on shape i. At 0.1, sals
    differs from it by (-1)^i (i + 1) 1e-5: a mean 0.005 (x1e3) lower, signed ranks all but balanced
    (p ~ 0.85), inside the noise. At 0.5, sals is 0.0005 (0.5 x1e3) worse on every shape. The oracle
    ceiling, below both everywhere, is a reference."""
    shapes = [f"shape{i:02d}" for i in range(20)]
    rows = []
    for i, shape in enumerate(shapes):
        base = 0.002 + 1e-4 * i
        rows += [job(shape, "bof", "neural", base, **{"sweep.sals.o_threshold": np.nan}),
                 job(shape, "sals", "neural", base + (-1) ** i * (i + 1) * 1e-5, **{"sweep.sals.o_threshold": 0.1}),
                 job(shape, "sals", "neural", base + 5e-4, **{"sweep.sals.o_threshold": 0.5})]
        rows += [job(shape, "sals", "oracle", base / 2, **{"sweep.sals.o_threshold": v}) for v in (0.1, 0.5)]
    return pd.DataFrame(rows), shapes


@pytest.fixture(scope="module")
def noisy():
    results, shapes = noisy_results()
    return build_sweep(results, dict(SWEEP, shapes=shapes))


def cells_of(table) -> dict[tuple, dict[str, object]]:
    """{(lead cells...): {header: Cell}} of a Table."""
    lead = table.headers.index("series") + 1
    return {tuple(c.text for c in row[:lead]): dict(zip(table.headers, row)) for row in table.rows}


def test_sweep_bold_is_the_best_and_its_ties_within_one_value(noisy):
    for key in ("sweep-sals.o_threshold", "sweep-sals.o_threshold-median"):
        cd = {k: cells["CD ×1e3 ↓"] for k, cells in cells_of(noisy.tables[key]).items()}
        # 0.1: a tiny noisy difference over 20 shapes -> both bold, the one not best marked as a tie
        assert cd["0.1", "sals"].bold and cd["0.1", "bof"].bold
        assert [cd["0.1", s].text.endswith("†") for s in ("sals", "bof")] == [False, True]
        # 0.5: a large consistent difference -> the winner alone, no tie mark
        assert (cd["0.5", "bof"].bold, cd["0.5", "sals"].bold) == (True, False)
        assert not cd["0.5", "bof"].text.endswith("†") and not cd["0.5", "sals"].text.endswith("†")
        # the ceiling is the lowest everywhere but a reference: never bold, never a tie
        assert not any(cd[v, "sals (oracle)"].bold or "†" in cd[v, "sals (oracle)"].text for v in ("0.1", "0.5"))
    caption = noisy.tables["sweep-sals.o_threshold"].caption
    assert "Bold compares the methods within one value of sals.o_threshold" in caption
    assert "tied by construction" not in caption  # 20 paired shapes: the test decides
    assert "p-values in sweep.csv" in caption


def test_sweep_means_carry_their_interval(noisy):
    table = noisy.tables["sweep-sals.o_threshold"]
    cells = cells_of(table)
    assert cells["0.5", "sals"]["NC ↑"].detail == "[0.900, 0.900]"  # a constant column: [c, c]
    assert cells["0.1", "sals (oracle)"]["NC ↑"].detail == "[0.900, 0.900]"  # references too
    low, high = map(float, cells["0.5", "bof"]["CD ×1e3 ↓"].detail.strip("[]").split(", "))
    assert low < float(cells["0.5", "bof"]["CD ×1e3 ↓"].text) < high  # 2 + 0.1 i over 20 shapes: 2.950
    assert cells["0.5", "bof"]["#F"].detail == ""  # validity means: no interval
    assert all(c.detail == "" for row in noisy.tables["sweep-sals.o_threshold-median"].rows for c in row)
    markdown = reports.sweep.sweep_markdown(noisy, SWEEP)
    assert r"**0.900** \[0.900, 0.900\]" in markdown and r"**2.950** \[" in markdown  # bof's CD at 0.5


def test_sweep_csv_intervals_and_p_values(noisy, tmp_path):
    reports.sweep.write_sweep(noisy, SWEEP, tmp_path)
    csv = pd.read_csv(tmp_path / "sweep.csv").set_index(["value", "series", "quantity"])
    assert csv.loc[(0.5, "sals", "nc"), ["ci_low", "ci_high"]].tolist() == [0.9, 0.9]
    assert csv.loc[(0.5, "sals", "cd"), "p_vs_best"] < 0.05 < csv.loc[(0.1, "bof", "cd"), "p_vs_best"]
    assert np.isnan(csv.loc[(0.5, "bof", "cd"), "p_vs_best"])  # the best itself
    assert np.isfinite(csv.loc[(0.5, "sals (oracle)", "cd"), "ci_low"])  # a reference still has its interval
    assert csv.loc[[(0.5, "sals (oracle)", "cd"), (0.5, "sals", "n_faces")], "p_vs_best"].isna().all()
    assert csv.loc[(0.5, "sals", "n_faces"), ["ci_low", "ci_high"]].isna().all()


def test_a_budget_sweep_plots_each_metric_against_its_fit_seconds():
    from reports.sweep import cost_plot

    context = dict(CONTEXT, methods=["sals", "sdf"], shapes=SHAPES, seeds=[0], sweep={"budget.steps": [750, 3000]})
    rows = [job(shape, m, "neural", cd, **{"sweep.budget.steps": v}) | {"fit_s": seconds}
            for m, scale in (("sals", 1.0), ("sdf", 2.0)) for v, seconds in ((750, 6.0), (3000, 24.0))
            for shape, cd in zip(SHAPES, (0.002 * scale * 3000 / v, 0.004 * scale * 3000 / v))]
    sweep = build_sweep(pd.DataFrame(rows), context)
    seconds = sweep.stats["budget.steps"]["mean"]["fit_s"].unstack("@series")
    assert seconds.loc[0, "sals"] == 6.0 and seconds.loc[1, "sdf"] == 24.0  # the x of each point: mean fit seconds
    assert cost_plot(sweep, "budget.steps").startswith(b"<?xml")
    assert cost_plot(build_sweep(threshold_results(), SWEEP), "sals.o_threshold") is not None  # fits ran there too
    oracle = threshold_results().assign(fit_s=np.nan)
    assert cost_plot(build_sweep(oracle, SWEEP), "sals.o_threshold") is None  # nothing fitted: no cost axis
    assert 'metrics against the fit seconds' in reports.sweep.sweep_html(sweep)


def test_a_method_extracting_anothers_fits_is_plotted_at_that_fits_seconds():
    from reports.sweep import cost_seconds

    context = dict(CONTEXT, methods=["sdf", "sdf-ndc"], shapes=SHAPES, seeds=[0],
                   sweep={"budget.steps": [750, 3000]})
    rows = [job(shape, m, "neural", 0.002, **{"sweep.budget.steps": v})
            | {"fit_s": seconds if m == "sdf" else np.nan, "cache": "" if m == "sdf" else "weights"}
            for m in ("sdf", "sdf-ndc") for v, seconds in ((750, 6.0), (3000, 24.0)) for shape in SHAPES]
    sweep = build_sweep(pd.DataFrame(rows), context)
    assert sweep.stats["budget.steps"]["mean"]["fit_s"].unstack("@series")["sdf-ndc"].isna().all()
    seconds = cost_seconds(sweep, "budget.steps")
    assert seconds["sdf-ndc"].tolist() == [6.0, 24.0] == seconds["sdf"].tolist()  # sdf-ndc extracts sdf's fits
