"""The regression comparator: what counts as moved, the ranking check, the data manifest."""

import hashlib

import numpy as np
import pandas as pd
import pytest

from runner.regression import (BASELINES, SPREAD_MARGIN, TIERS, RegressionError, Tier, Tolerance, compare,
                                      mean_tolerances_of, measure_spread, merge_spread, read_list,
                                      spread_tolerances, verify_manifest)
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
    assert compare(frame(), frame(), TIERS["neural"], spread_tolerances(spread(), frame())).empty


def spread(cd_by_seed=((0, 0.004), (1, 0.0045), (2, 0.0035))):
    """The table of frame() run at a few seeds on two float paths, sals's CD set per seed (both shapes)."""
    runs = []
    for path in ("default", "native"):
        for seed, cd in cd_by_seed:
            run = frame({(s, "sals", "cd"): cd for s in ("a", "b")}).assign(seed=seed, float_path=path)
            run.loc[run.method == "sdf", "ecd"] = 0.07 + 0.001 * seed  # sdf's ECD mean moves by up to 0.002
            runs.append(run)
    return pd.concat(runs, ignore_index=True)


def test_spread_tolerances_are_the_margin_times_the_largest_deviation_of_a_runs_mean():
    tol = spread_tolerances(spread(), frame())
    # sals CD: baseline mean 0.004, run means 0.004, 0.0045, 0.0035 -> largest deviation 0.0005
    assert tol.at["sals", "cd"] == pytest.approx(SPREAD_MARGIN * 0.0005)
    assert tol.at["sdf", "ecd"] == pytest.approx(SPREAD_MARGIN * 0.002)
    assert tol.at["sdf", "cd"] == 0.0 and tol.at["sals", "ecd"] == 0.0


def test_a_spread_measured_for_one_method_replaces_only_that_methods_rows():
    committed = spread()
    remeasured = spread(cd_by_seed=((0, 0.003), (1, 0.0031))).query("method == 'sals'")
    merged = merge_spread(committed, remeasured)
    pd.testing.assert_frame_equal(merged[merged.method == "sdf"].reset_index(drop=True),
                                  committed[committed.method == "sdf"].reset_index(drop=True))
    assert sorted(merged[merged.method == "sals"].cd.unique()) == [0.003, 0.0031]
    assert len(merged) == len(committed) - 12 + 8  # sals: 2 paths x 3 seeds x 2 shapes out, 2 x 2 x 2 in


def test_each_float_path_of_a_spread_fits_into_its_own_cache(tmp_path, monkeypatch):
    runs = []

    def run_tier(tier, data_dir, out_dir, workers, extra_args=(), env=None, methods=None):
        runs.append((extra_args, env.get("ATEN_CPU_CAPABILITY")))
        return frame()

    monkeypatch.setattr("runner.regression.run_tier", run_tier)
    spread = measure_spread(TIERS["neural"], tmp_path, tmp_path / "work", (0, 1), 2, paths=("default", "avx2"))
    caches = [args[args.index("--cache-dir") + 1] for args, _ in runs]
    assert caches == [str(tmp_path / "work" / "default" / "cache"), str(tmp_path / "work" / "avx2" / "cache")]
    assert all(args[-3:] == ("--seed", "0", "1") for args, _ in runs) and [c for _, c in runs] == ["default", "avx2"]
    assert sorted(spread.float_path.unique()) == ["avx2", "default"]


def test_new_baselines_come_from_fresh_fits_in_their_own_cache(tmp_path, monkeypatch):
    from runner import regression

    runs, written = [], []
    monkeypatch.setattr(regression, "verify_manifest", lambda data_dir: [])
    monkeypatch.setattr(regression, "run_tier", lambda tier, data_dir, out_dir, workers, extra_args=(), env=None,
                        methods=None: runs.append((extra_args, methods)) or frame())
    monkeypatch.setattr(regression, "update_baselines", lambda tier, results, work: written.append(tier.name))
    assert regression.main(["--tier", "neural", "--update-baselines", "--methods", "sals", "sdf",
                            "--data-dir", str(tmp_path), "--work-dir", str(tmp_path / "work")]) == 0
    assert runs == [(("--cache-dir", str(tmp_path / "work" / "cache")), ["sals", "sdf"])] and written == ["neural"]


def test_the_mean_tier_ignores_per_job_noise_that_averages_out_and_catches_a_moved_mean():
    tier, tol = TIERS["neural"], spread_tolerances(spread(), frame())
    noisy = frame({("a", "sals", "cd"): 0.0049, ("b", "sals", "cd"): 0.0031})  # per job +-22 %, same mean
    assert compare(noisy, frame(), tier, tol).empty
    inside = frame({("a", "sals", "cd"): 0.0047, ("b", "sals", "cd"): 0.0047})  # mean +0.0007 <= 0.00075
    assert compare(inside, frame(), tier, tol).empty
    beyond = frame({("a", "sals", "cd"): 0.0048, ("b", "sals", "cd"): 0.0048})
    moved = compare(beyond, frame(), tier, tol)
    assert moved.metric.tolist() == ["cd (mean)"] and moved.method.tolist() == ["sals"]
    failed = compare(frame({("b", "sdf", "status"): "failed"}), frame(), tier, tol)
    assert "status" in failed.metric.tolist()  # statuses stay per job
    with pytest.raises(RegressionError, match="spread"):
        compare(frame(), frame(), tier, None)


def test_the_committed_neural_spread_gives_a_tolerance_for_every_method_and_metric():
    baseline = pd.read_csv(BASELINES / "neural" / "results.csv")
    tol = mean_tolerances_of(TIERS["neural"], baseline)
    assert set(tol.index) == set(baseline.method) and tol.notna().all().all()
    assert (tol > 0).all().all()
    committed = pd.read_csv(BASELINES / "neural" / "spread.csv")
    assert set(committed.float_path) == {"default", "avx2", "native"} and committed.seed.nunique() >= 5


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


def test_absent_data_is_its_own_exit_status_with_a_first_line_message(tmp_path, capsys):
    from runner.regression import EXIT_NO_DATA, main

    assert main(["--data-dir", str(tmp_path / "absent")]) == EXIT_NO_DATA != 0
    assert capsys.readouterr().out.splitlines()[0].startswith(f"regression not run: {tmp_path / 'absent'} is absent")


@pytest.mark.slow
@requires_shared("abc")
def test_the_oracle_tier_catches_one_ndc_weight_moved_by_a_ten_thousandth_of_a_cell(tmp_path, monkeypatch):
    """The oracle tier's sdf-ndc job of one subset part, run as the tier runs it: with NDC's
    published weights it equals the committed baseline; with one bias of NDC's last layer moved by
    1e-4 (every vertex's x offset shifts by 1e-4 of a cell, 1.6e-6 units) it is caught."""
    from methods.extractors import ndc
    from runner.cli import main
    from runner.regression import baseline_columns

    try:
        published = ndc.load_weights()
    except ndc.WeightsError as exc:
        pytest.skip(str(exc))
    part = read_list(BASELINES / "abc_subset.txt")[0]
    (tmp_path / "list.txt").write_text(part + "\n")
    baseline = pd.read_csv(BASELINES / "oracle" / "results.csv")
    baseline = baseline[(baseline["shape"] == part) & (baseline.method == "sdf-ndc")]
    assert len(baseline) == 1

    def tier_run(name, state):
        monkeypatch.setattr(ndc, "load_weights", lambda path=None: state)
        out = tmp_path / name
        assert main(["--methods", "sdf-ndc", "--dataset", "abc", "--data-dir", str(SHARED_DATA / "abc"),
                     "--list", str(tmp_path / "list.txt"), "--out", str(out), "--cache-dir", str(out / "cache"),
                     "--quiet", "--gallery", "0", "--executor", "local", "--threads", "1",
                     *TIERS["oracle"].run_args]) == 0
        return compare(baseline_columns(pd.read_csv(out / "results.csv")), baseline, TIERS["oracle"])

    assert tier_run("published", published).empty
    moved = dict(published)
    bias = moved["conv_out_float.bias"].clone()
    bias[0] += 1e-4
    moved["conv_out_float.bias"] = bias
    caught = tier_run("moved", moved)
    assert len(caught) >= 1 and set(caught.method) == {"sdf-ndc"}
