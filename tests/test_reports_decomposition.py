"""reports.decomposition: the decomposition tables from job rows and component rows (hand-worked means)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from foundation.metrics import PRESETS
from reports.decomposition import decomposition_frame, decomposition_tables, variant_label
from reports.table import table_markdown

METRICS = [m for m in PRESETS["default"].headline_metrics() if m.column in ("cd", "ef1")]


def frames():
    """sals on shapes a, b (seeds 0, 1 on a); its 'flags' variant failed on b, so b leaves its method's rows."""
    jobs = pd.DataFrame({"shape": ["a", "a", "b", "c"], "method": ["sals", "sals", "sals", "sdf"], "seed": [0, 1, 0, 0],
                         "status": "ok", "cd": [0.004, 0.006, 0.010, 0.002], "ef1": [0.5, 0.7, 0.4, 0.9],
                         "n_faces": [100, 300, 50, 10], "false_hit_edges": [10, 30, 5, np.nan],
                         "wrong_side_points": [np.nan, np.nan, np.nan, 7]})
    components = pd.DataFrame({"shape": ["a", "a", "b", "a", "a", "b", "c"],
                               "method": ["sals"] * 6 + ["sdf"], "seed": [0, 1, 0, 0, 1, 0, 0],
                               "exact": ["flags", "flags", "s", "s", "flags+s", "flags+s", "sign"][:7],
                               "cd": [0.002, 0.002, 0.009, 0.003, 0.001, 0.001, 0.002], "ef1": [0.8, 0.6, 0.5, 0.6, 1.0, 1.0, 0.9],
                               "n_faces": [80, 120, 40, 90, 70, 30, 10]})
    return jobs, components


def test_rows_average_seeds_then_shapes_over_the_shapes_every_variant_has():
    jobs, components = frames()
    frame = decomposition_frame(jobs, components, METRICS, ["sals", "sdf"]).set_index(["method", "variant"])
    assert list(frame.loc["sals"].index) == ["fitted", "exact flags", "exact s", "exact flags, s"]
    fitted = frame.loc[("sals", "fitted")]  # shape a only (b has no 'flags' row): seeds 0.004, 0.006 -> 5e-3
    assert fitted["shapes"] == 1 and fitted["mean.cd"] == pytest.approx(5.0) and fitted["mean.ef1"] == pytest.approx(0.6)
    assert fitted["mean.n_faces"] == pytest.approx(200)
    assert frame.loc[("sals", "exact flags"), "mean.cd"] == pytest.approx(2.0)
    assert frame.loc[("sals", "exact s"), "median.ef1"] == pytest.approx(0.6)
    assert frame.loc[("sdf", "exact sign"), "mean.cd"] == pytest.approx(2.0)
    assert variant_label("flags+s") == "exact flags, s" and variant_label("") == "fitted"


def test_tables_show_the_component_errors_each_method_records():
    jobs, components = frames()
    tables = decomposition_tables(jobs, components, METRICS, ["sals", "sdf"], "caption")
    text = table_markdown(tables["component-errors"])
    assert "false hits" in text and "wrong-side points" in text
    sals = next(r for r in tables["component-errors"].rows if r[0].text == "sals")
    assert [c.text for c in sals] == ["sals", "15", "–", "3"]  # mean of 10, 30, 5 over its 3 jobs
    assert decomposition_tables(jobs, None, METRICS, ["sals"], "c") == {}
