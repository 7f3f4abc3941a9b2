"""scripts/paper_table.py: the paper's value beside our mean, median, interval and ratio, on a
hand-built table; the ordering check says where the paper's order holds."""

from pathlib import Path

import numpy as np
import pandas as pd

from tests.scripts import load_script


def test_ours_beside_the_papers_values_and_the_orderings():
    script = load_script("paper_table")
    jobs = pd.DataFrame({"shape": list("abcd") * 2, "method": ["sals"] * 4 + ["sdf"] * 4,
                         "status": ["ok"] * 7 + ["failed"],
                         "ecd": [0.01, 0.02, 0.03, np.nan, 0.05, 0.06, 0.07, np.nan],
                         "ef1": [0.6, 0.8, 0.7, 0.5, 0.2, 0.3, 0.1, np.nan]})
    reference = pd.DataFrame({"table": "encode", "method": ["sals", "sdf"], "metric": ["ecd", "ecd"],
                              "value": [0.02, 0.07], "source": "test"})
    table = script.line_by_line(jobs, reference).set_index("method")
    assert table.at["sals", "paper"] == "2.000" and table.at["sals", "ours: mean"] == "2.000"  # x1e2
    assert table.at["sals", "median"] == "2.000" and table.at["sals", "ours / paper"] == "1.00"
    assert table.at["sals", "jobs"] == "3 (+1 NaN)" and table.at["sdf", "jobs"] == "3"  # the failed job not at all
    assert table.at["sdf", "ours / paper"] == f"{0.06 / 0.07:.2f}"
    order = script.orderings(jobs, reference).iloc[0]
    assert (order["paper: better"], order["ours: better"], order["holds"], order["shapes"]) == ("sals", "sals",
                                                                                               "yes", 3)
