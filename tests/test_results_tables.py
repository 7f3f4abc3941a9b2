"""scripts/results_tables.py: the generated blocks of docs/RESULTS.md and README equal what their
CSVs give (the drift test), and the rules that make them, on a hand-built CSV."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.scripts import load_script

script = load_script("results_tables")


def test_every_generated_block_equals_what_its_csvs_give():
    """Text and data cannot drift: re-making every block of RESULTS.md and README changes nothing
    (after an intended change of a CSV or a spec: python scripts/results_tables.py)."""
    names = []
    for path in script.DOCUMENTS:
        text = path.read_text(encoding="utf-8")
        new, changed = script.update(text, str(path))
        assert not changed, f"{path.name}: blocks that differ from their CSVs: {changed}"
        assert new == text
        names += [m["name"] for m in script.BLOCK.finditer(text)]
    assert sorted(names) == sorted(script.BLOCKS)  # every spec is shown, each once


@pytest.fixture
def hand_csv(tmp_path, monkeypatch):
    """Four shapes, two methods; 'b' has a NaN ECD on shape s3 and loses on every shape."""
    jobs = pd.DataFrame({"shape": [f"s{i}" for i in range(4)] * 2, "method": ["a"] * 4 + ["b"] * 4,
                         "seed": 0, "status": "ok",
                         "cd": [1e-3, 2e-3, 3e-3, 4e-3, 2e-3, 3e-3, 4e-3, 9e-3],
                         "ecd": [0.01, 0.02, 0.03, 0.04, 0.02, 0.03, 0.05, np.nan],
                         "ef1": [0.9, 0.8, 0.7, 0.6, 0.5, 0.5, 0.5, 0.5],
                         "n_faces": [1000, 3000, 5000, 7000, 20000, 20000, 20000, 20000]})
    jobs.to_csv(tmp_path / "hand.csv", index=False)
    monkeypatch.setattr(script, "RESULTS", tmp_path)
    script._csv.cache_clear()
    yield [script.Row(m, "hand.csv", {"method": m}) for m in ("a", "b")]
    script._csv.cache_clear()


def test_a_summary_is_mean_median_with_nan_counted_and_bold_by_the_paired_test(hand_csv):
    table = script.render(script.Summary("rows", tuple(hand_csv), ("cd", "ecd", "ef1", "n_faces"),
                                         intervals=("ef1",)))
    lines = table.splitlines()
    assert lines[0] == "| rows | CD | ECD | EF1 | faces |"
    a, b = (line.split(" | ") for line in lines[2:])
    # CD x1e3: a mean 2.50, median 2.50; b mean 4.50, median 3.50. Four pairs cannot reach p < 0.05
    # (two-sided, smallest p 2 / 2^4), so b ties with the best: both bold.
    assert a[1] == "**2.50 / 2.50**" and b[1] == "**4.50 / 3.50**"
    # ECD x1e2: b over its 3 finite shapes (2, 3, 5), the NaN counted
    assert a[2] == "**2.50 / 2.50**" and b[2] == "**3.33 / 3.00 (1 NaN)**"
    low, high = script.bootstrap_mean_ci(np.array([0.9, 0.8, 0.7, 0.6]))
    assert a[3] == f"**0.750 / 0.750 [{low:.3f}, {high:.3f}]**"
    assert a[4] == "4.0k |" and b[4] == "20k |"  # faces: thousands, never bold


def test_paired_counts_the_shapes_each_wins_and_the_two_sided_p(hand_csv):
    a, b = hand_csv
    assert script.better_counts(a, b, "cd")[:2] == (4, 0)
    assert script.better_counts(a, b, "ecd")[1:] == (0, script.paired_wilcoxon([0.01, 0.02, 0.03],
                                                                              [0.02, 0.03, 0.05]), 3)
    (line,) = script.render(script.Paired(((b, a),), ("ef1",))).splitlines()[2:]
    assert line == f"| b vs a | a 4, b 0 (p = {script.p_text(script.paired_wilcoxon([.9, .8, .7, .6], [.5] * 4))}) |"
    sentence = script.render(script.Headline("{a>b.ef1} of {shapes}, mean {a.ef1} against {b.ef1}", tuple(hand_csv)))
    assert sentence == "4 of 4, mean 0.750 against 0.500"


def test_p_values_read_by_one_rule():
    assert [script.p_text(p) for p in (0.5, 0.0123, 0.00098, 3.2e-6, np.nan)] == ["0.5", "0.012", "1e-3", "3e-6", "–"]


def test_failed_jobs_and_unknown_blocks_are_refused(hand_csv, tmp_path):
    jobs = pd.read_csv(tmp_path / "hand.csv")
    jobs.loc[0, "status"] = "failed"
    jobs.to_csv(tmp_path / "hand.csv", index=False)
    script._csv.cache_clear()
    with pytest.raises(ValueError, match="1 failed jobs"):
        script.per_shape(hand_csv[0])
    nobody = script.Row("c", "hand.csv", {"method": "c"})  # a mistyped method is refused, never an empty row
    with pytest.raises(ValueError, match="no job with"):
        script.render(script.Summary("rows", (nobody,), ("cd",)))
    with pytest.raises(ValueError, match="no job with"):
        script.render(script.Across("rows", "cd", (nobody,), (("all", {}),)))
    with pytest.raises(ValueError, match="unknown generated block 'nope'"):
        script.update("<!-- generated: nope -->\nx\n<!-- /generated -->", "doc.md")


def test_across_columns_each_cell_is_its_rows_jobs_at_the_columns_value(tmp_path, monkeypatch):
    """Two methods at two grids: 'a' better at 64 on every shape, 'b' at 128; peak memory by its max."""
    rows = []
    for N, (ea, eb) in ((64, (0.9, 0.5)), (128, (0.4, 0.8))):
        for i in range(3):
            rows += [{"shape": f"s{i}", "method": m, "grid": N, "status": "ok", "ef1": e + 0.01 * i,
                      "peak_rss_mib": 1024.0 * (1 + i) * N / 64} for m, e in (("a", ea), ("b", eb))]
    pd.DataFrame(rows).to_csv(tmp_path / "grids.csv", index=False)
    monkeypatch.setattr(script, "RESULTS", tmp_path)
    script._csv.cache_clear()
    a, b = (script.Row(m, "grids.csv", {"method": m}) for m in ("a", "b"))
    columns = (("64^3", {"grid": 64}), ("128^3", {"grid": 128}))
    table = script.render(script.Across("method", "ef1", (a, b), columns)).splitlines()
    assert table[0] == "| method | 64^3 | 128^3 |"
    assert table[2] == "| a | **0.910 / 0.910** | **0.410 / 0.410** |"  # 3 pairs: no p < 0.05, both tie
    assert table[3] == "| b | **0.510 / 0.510** | **0.810 / 0.810** |"
    peak = script.render(script.Across("method", "peak_rss_mib", (a,), columns, stat="max")).splitlines()
    assert peak[2] == "| a | 3.00 | 6.00 |"  # GiB, the largest job's
    (pair,) = script.render(script.PairedAcross("ef1", ((a, b),), columns)).splitlines()[2:]
    assert pair == "| a vs b | a 3, b 0 (p = 0.25) | b 3, a 0 (p = 0.25) |"
    script._csv.cache_clear()


def test_the_papers_values_beside_ours_name_the_metrics_as_the_tables_do(tmp_path, monkeypatch):
    jobs = pd.DataFrame({"shape": list("abcd") * 2, "method": ["sals"] * 4 + ["sdf"] * 4, "status": "ok",
                         "ef1": [0.6, 0.8, 0.7, 0.5, 0.2, 0.3, 0.1, 0.4]})
    jobs.to_csv(tmp_path / "hand.csv", index=False)
    monkeypatch.setattr(script, "RESULTS", tmp_path)
    script._csv.cache_clear()
    values = script.render(script.PaperValues("hand.csv")).splitlines()
    assert values[0] == "| method | metric | paper | ours: mean | median | 95% interval | ours / paper | jobs |"
    assert values[2].startswith("| sals | EF1 | 0.601 | 0.650 | 0.650 |")  # the paper's SALS EF1 (paper-reference.csv)
    order = script.render(script.PaperValues("hand.csv", orderings=True)).splitlines()
    assert order[2] == "| EF1 | sals vs sdf | sals | sals | yes | 4 | 0.12 |"  # 4 pairs: p = 2 / 2^4
    script._csv.cache_clear()
