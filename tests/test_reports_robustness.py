"""Robustness report contract (reports.robustness) from a hand-made frame.

Two methods (poisson, geoudf), 2 shapes, one seed, a sweep of ``pc_corruption`` over uniform, scan
and noise-1..3 and outliers-1 only. Raw CD per job: poisson 0.001 (uniform), 0.002 (scan), then
0.003 / 0.004 / 0.005 for noise-1..3 and 0.0025 for outliers-1, on both shapes; geoudf 0.0015
(uniform), 0.0015 (scan), 0.001 / 0.006 / 0.007 (noise) and 0.004 (outliers-1). So in the noise
table (x1e3): poisson 1, 2, 3, 4, 5 (monotone from the scan up), geoudf 1.5, 1.5, 1, 6, 7 (not
monotone: level 1 is below the scan); the order by CD flips between level 1 (geoudf first) and
level 2 (poisson first). poisson was given sensors on every scan input.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import reports
from reports.robustness import build_robustness, level_names, overview_table, robustness_plot
from tests.test_reports_sweep import job, rows_of
from tests.test_reports_tables import CONTEXT

SHAPES = ["cube", "sphere"]
LEVELS = ["uniform", "scan", "noise-1", "noise-2", "noise-3", "outliers-1"]
CONTEXT_R = dict(CONTEXT, task="reconstruct", mode="neural", methods=["poisson", "geoudf"], shapes=SHAPES, seeds=[0],
                 sweep={"pc_corruption": LEVELS})
CD = {"poisson": [0.001, 0.002, 0.003, 0.004, 0.005, 0.0025], "geoudf": [0.0015, 0.0015, 0.001, 0.006, 0.007, 0.004]}


def results() -> pd.DataFrame:
    rows = [job(shape, m, "neural", cd, **{"sweep.pc_corruption": level,
                                           "used_sensors": int(m == "poisson" and level != "uniform")})
            for m, cds in CD.items() for level, cd in zip(LEVELS, cds) for shape in SHAPES]
    return pd.DataFrame(rows)


def test_a_table_per_kind_with_uniform_and_scan_as_its_first_levels():
    robustness = build_robustness(results(), CONTEXT_R)
    assert list(robustness.kinds) == ["noise", "outliers"]  # kinds without a graded level get no table
    noise = rows_of(robustness.kinds["noise"].tables["robustness-noise"])
    assert list(noise) == [(lv, m) for lv in ("uniform", "scan", "1", "2", "3") for m in ("poisson", "geoudf")]
    cd = {k: r["CD ×1e3 ↓"].rstrip("†") for k, r in noise.items()}
    assert [cd[lv, "poisson"] for lv in ("uniform", "scan", "1", "2", "3")] == ["1.000", "2.000", "3.000", "4.000",
                                                                               "5.000"]
    assert [cd[lv, "geoudf"] for lv in ("scan", "1", "2")] == ["1.500", "1.000", "6.000"]
    outliers = rows_of(robustness.kinds["outliers"].tables["robustness-outliers"])
    assert list(outliers)[-2:] == [("1", "poisson"), ("1", "geoudf")]  # only the levels swept
    table = robustness.kinds["noise"].tables["robustness-noise"]
    assert table.title.startswith("Robustness to noise: levels")
    assert "Given each input point's sensor position (a scan): poisson;" in " ".join(table.notes)


def test_the_overview_has_a_row_per_input_and_a_column_per_method():
    robustness = build_robustness(results(), CONTEXT_R)
    table = overview_table(robustness, "cd")
    assert table.headers == ["input", "poisson", "geoudf"]
    rows = {r[0].text: [c.text.rstrip("†") for c in r[1:]] for r in table.rows}
    assert list(rows) == LEVELS  # uniform and scan once, then each kind's levels by name
    assert [rows[lv][0] for lv in LEVELS] == ["1.000", "2.000", "3.000", "4.000", "5.000", "2.500"]
    assert [rows[lv][1] for lv in LEVELS] == ["1.500", "1.500", "1.000", "6.000", "7.000", "4.000"]
    noise = robustness.kinds["noise"].tables["robustness-noise"]
    bold = {(r[0].text, r[1].text): r[noise.headers.index("CD ×1e3 ↓")].bold for r in noise.rows}
    assert [[c.bold for c in r[1:]] for r in table.rows[:5]] == [
        [bold[level, "poisson"], bold[level, "geoudf"]] for level in ("uniform", "scan", "1", "2", "3")]
    assert overview_table(robustness, "no-such-metric") is None


def test_order_notes_say_where_the_ordering_changes_and_which_methods_degrade_monotonically():
    notes = build_robustness(results(), CONTEXT_R).notes["noise"]
    assert "Order by mean CD at 1: geoudf (1) < poisson (3)" in notes
    assert "Order by mean CD at 2: poisson (4) < geoudf (6)" in notes
    assert notes[-1] == "Mean CD grows at every step scan -> 1 -> 2 -> 3: poisson; not for geoudf."


@pytest.mark.slow
def test_no_robustness_without_a_corruption_sweep_and_the_files_with_one(tmp_path):
    assert build_robustness(results(), dict(CONTEXT_R, sweep={})) is None
    assert build_robustness(results(), dict(CONTEXT_R, sweep={"pc_corruption": ["uniform", "scan"]})) is None
    assert level_names("density") == ["uniform", "scan", "density-1", "density-2", "density-3"]
    robustness = build_robustness(results(), CONTEXT_R)
    assert robustness_plot(robustness, "cd").startswith(b"<?xml")
    paths = reports.write_reports(results(), None, CONTEXT_R, tmp_path)
    assert {"robustness.md", "robustness.csv"} <= set(paths)
    frame = pd.read_csv(paths["robustness.csv"])
    assert set(frame.kind) == {"noise", "outliers"} and set(frame.key) == {"level"}
    cd = frame[(frame.kind == "noise") & (frame.series == "poisson") & (frame.quantity == "cd")]
    assert np.allclose(cd["mean"], [1, 2, 3, 4, 5])
    assert "## noise" in paths["robustness.md"].read_text()
    assert "## Every input: mean CD ×1e3 ↓" in paths["robustness.md"].read_text()
    assert "Robustness to input corruptions" in paths["report.html"].read_text()
