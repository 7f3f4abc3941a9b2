"""The regression comparator: what counts as moved, the ranking check, the data manifest."""

import hashlib

import numpy as np
import pandas as pd

from benchmark.run.regression import BASELINES, TIERS, Tier, Tolerance, compare, read_list, verify_manifest
from tests.conftest import SHARED_DATA, requires_shared


def frame(overrides=None):
    rows = []
    for shape in ("a", "b"):
        for method, cd, ecd in (("sals", 0.004, 0.02), ("sdf", 0.006, 0.07)):
            rows.append({"shape": shape, "method": method, "seed": 0, "status": "ok", "cd": cd, "nc": 0.97,
                         "f1_005": 0.6, "f1_01": 0.9, "ecd": ecd, "ef1": 0.5, "n_faces": 1000})
    df = pd.DataFrame(rows)
    for (shape, method, col), value in (overrides or {}).items():
        df.loc[(df["shape"] == shape) & (df.method == method), col] = value
    return df


def test_identical_tables_do_not_move():
    assert compare(frame(), frame(), TIERS["oracle"]).empty
    assert compare(frame(), frame(), TIERS["neural"]).empty


def test_oracle_tier_catches_a_tiny_metric_change_and_reports_it():
    now = frame({("a", "sals", "cd"): 0.004 * (1 + 1e-3)})
    moved = compare(now, frame(), TIERS["oracle"])
    assert len(moved) == 1
    row = moved.iloc[0]
    assert (row.metric, row.method, row["shape"]) == ("cd", "sals", "a")
    assert row.baseline == 0.004 and "rtol" in row.tolerance


def test_within_tolerance_and_nan_handling():
    tier = Tier("t", (), {"cd": Tolerance(0.1, 0.0), "ecd": Tolerance(0.0, 0.0)})
    ok = frame({("a", "sals", "cd"): 0.00439})  # +9.75%: inside the 10% bound
    assert compare(ok, frame(), tier).empty
    both_nan = compare(frame({("a", "sdf", "ecd"): np.nan}), frame({("a", "sdf", "ecd"): np.nan}), tier)
    assert both_nan.empty
    one_nan = compare(frame({("a", "sdf", "ecd"): np.nan}), frame(), tier)
    assert one_nan.metric.tolist() == ["ecd"]


def test_status_change_and_missing_jobs_are_reported():
    now = frame({("b", "sdf", "status"): "failed"})
    assert compare(now, frame(), TIERS["oracle"]).metric.tolist() == ["status"]
    fewer = frame().iloc[:-1]
    assert compare(fewer, frame(), TIERS["oracle"]).metric.tolist() == ["job"]


def test_neural_ranking_flip_is_caught_even_within_per_value_tolerance():
    tier = Tier("t", (), {"cd": Tolerance(10.0, 0.0)}, check_ranking=True, ranking_metrics=("cd",))
    # baseline: sals 0.004 < sdf 0.006 would need a gap > 2 * 10 * 0.006 to count as clear: not clear
    assert compare(frame({("a", "sals", "cd"): 0.02, ("b", "sals", "cd"): 0.02}), frame(), tier).empty
    tier = Tier("t", (), {"cd": Tolerance(0.1, 0.0)}, check_ranking=True, ranking_metrics=("cd",))
    flipped = frame({("a", "sals", "cd"): 0.0059, ("b", "sals", "cd"): 0.0059,
                       ("a", "sdf", "cd"): 0.0041, ("b", "sdf", "cd"): 0.0041})
    moved = compare(flipped, frame(), tier)
    assert "cd ranking" in moved.metric.tolist()


def test_manifest_detects_changed_and_missing_files(tmp_path):
    (tmp_path / "x.ply").write_bytes(b"abc")
    manifest = tmp_path / "m.sha256"
    manifest.write_text(f"{hashlib.sha256(b'abc').hexdigest()}  x.ply\n{'0' * 64}  y.ply\n")
    assert len(verify_manifest(tmp_path, manifest)) == 1  # y missing
    (tmp_path / "x.ply").write_bytes(b"abd")
    problems = verify_manifest(tmp_path, manifest)
    assert any("x.ply" in p and "differs" in p for p in problems)


def test_subset_lists_are_consistent():
    subset = read_list(BASELINES / "abc_subset.txt")
    assert 4 <= len(subset) <= 6
    pairs = [line.split("+") for line in read_list(BASELINES / "abc_subset_nonmanifold.txt")]
    assert len(pairs) == 2 and all(a in subset and b in subset for a, b in pairs)


@requires_shared("abc")
def test_committed_manifest_matches_shared_data():
    assert verify_manifest(SHARED_DATA / "abc") == []
