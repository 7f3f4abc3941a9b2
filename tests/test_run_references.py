"""Reference sets (runner.references): a set made from a finished run joins another run's tables
(summary.md, statistics.csv, report.html; never timing), and a run that cannot be joined to it is
refused before any work with one line: another protocol, a stale metric code, other shape bytes, a
row name in both. The slow tests join the shipped sets on the SALS paper's parts, and re-compute one
shipped row to the stored digits."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from runner.cli import EXIT_REFUSED, main
from runner.references import (REFERENCES_DIR, ROW_COLUMNS, find_reference, read_reference, reference_names,
                               write_reference)
from tests.conftest import SHARED_DATA
from tests.fake_methods import PLUGIN

REPO = Path(__file__).resolve().parents[1]


def run_args(out: Path, cache: Path, *extra: str, methods=("test_occ",)) -> list[str]:
    return ["--methods", *methods, "--mode", "oracle", "--grid", "32", "--eval-points", "20000", "--limit", "2",
            "--out", str(out), "--cache-dir", str(cache), "--plugin", PLUGIN, "--quiet", "--executor", "local",
            "--gallery", "0", *extra]


def head_commit() -> str:
    try:
        done = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, timeout=10)
    except OSError:
        done = None
    if done is None or done.returncode != 0:
        pytest.skip("not a git checkout: a set records the commit whose code made its rows")
    return done.stdout.strip()


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """The run of test_sdf on 2 built-in shapes and the set made of it by ``references make``, as
    from a clean checkout at HEAD."""
    from contextlib import ExitStack

    from methods.base import registered_method
    from tests.fake_methods import FAKES

    commit = head_commit()
    root = tmp_path_factory.mktemp("references")
    with ExitStack() as stack, pytest.MonkeyPatch.context() as patch:
        for cls, order in FAKES:
            stack.enter_context(registered_method(cls, order=order))
        patch.setattr("runner.provenance.git_state", lambda: {"git_commit": commit, "git_dirty": False})
        assert main(run_args(root / "a", root / "cache", methods=("test_sdf",))) == 0
        assert main(["references", "make", str(root / "a"), "--name", "mine", "--into", str(root / "refs"),
                     "--description", "test_sdf on 2 shapes"]) == 0
    return root


@pytest.fixture
def made_set(first_run, fakes, tmp_path):
    """A copy of the set of :func:`first_run` (its folder) and the run's cache."""
    import shutil

    folder = tmp_path / "refs" / "mine"
    shutil.copytree(first_run / "refs" / "mine", folder)
    (tmp_path / "a").symlink_to(first_run / "a")
    return folder, first_run / "cache"


@pytest.fixture
def crafted_set(fakes, tmp_path):
    """A set written by hand under this checkout's metric code: the protocol of :func:`run_args`, the
    first 2 built-in shapes with their bytes' digests, a test_sdf row each (CD 0.01 and 0.02)."""
    from datasets import get_dataset
    from datasets.manifest import shape_bytes_digest
    from tasks.cache import metric_code_digest

    dataset = get_dataset("builtin")
    shapes = dataset.names()[:2]
    rows = pd.DataFrame({"shape": shapes, "method": "test_sdf", "seed": 0, "mode": "oracle", "input": "mesh",
                         "cd": [0.01, 0.02], "nc": 0.9, "f1_005": 0.5, "f1_01": 0.6, "ecd": 0.1, "ef1": 0.2,
                         "n_faces": 1000, "status": "ok", "commit": "abc1234"})
    manifest = {"name": "mine", "description": "test_sdf on 2 shapes",
                "protocol": {"task": "encode", "mode": "oracle", "input": "mesh", "grid": 32, "eval_points": 20000,
                             "metric_preset": "default", "dataset": "builtin"},
                "budget": None, "seeds": [0], "methods": ["test_sdf"], "dataset_options": {},
                "shapes": {s: shape_bytes_digest(dataset, s) for s in shapes},
                "sources": [{"commit": "abc1234", "cpu": "a test CPU", "date": "2026-12-07", "command": None,
                             "code": {"metrics": metric_code_digest(), "sampler": None, "methods": {}}}]}
    return write_reference(tmp_path / "refs" / "mine", manifest, rows), tmp_path / "cache"


def test_a_set_joins_a_runs_tables_beside_its_rows(crafted_set, tmp_path):
    folder, cache = crafted_set
    out = tmp_path / "b"
    assert main(run_args(out, cache, "--reference", str(folder))) == 0
    summary = (out / "summary.md").read_text()
    assert "| test\\_sdf (ref)" in summary and "| test\\_occ " in summary  # Markdown-escaped
    assert ("reference set mine (test\\_sdf on 2 shapes), not recomputed: 2 rows computed at commit abc1234 on a test "
            "CPU; over the 2 of this run's 2 shapes it has.") in summary
    stats = pd.read_csv(out / "statistics.csv")
    ref_cd = stats[(stats["method"] == "test_sdf (ref)") & (stats["metric"] == "cd")].iloc[0]
    assert ref_cd["pairs"] == 2 and ref_cd["mean"] == pytest.approx(15.0)  # x1e3, as stored
    assert "test_sdf (ref)" in (out / "report.html").read_text()
    assert set(pd.read_csv(out / "timing.csv")["method"]) == {"test_occ"}  # another machine's seconds: not timed
    assert set(pd.read_csv(out / "results.csv")["method"]) == {"test_occ"}  # results.csv: the run's own rows
    assert main(["report", str(out), str(out), "--reference", str(folder)]) == EXIT_REFUSED  # one run only


def test_a_score_run_is_joined_whatever_grid_and_mode_made_its_meshes():
    from runner.references import run_protocol

    assert run_protocol({"task": "score", "grid": 64, "mode": "neural", "metric_preset": "default",
                         "dataset": "sals-abc50"}, {"eval_points": 10**6}) == \
        {"eval_points": 10**6, "metric_preset": "default", "dataset": "sals-abc50"}


@pytest.mark.slow
def test_a_set_made_from_a_run_joins_another_runs_tables(made_set, tmp_path):
    folder, cache = made_set
    ref = read_reference(folder)
    made = pd.read_csv(tmp_path / "a" / "results.csv")
    assert list(ref.rows.columns) == ROW_COLUMNS and len(ref.rows) == 2
    np.testing.assert_allclose(ref.rows.sort_values("shape")["cd"], made.sort_values("shape")["cd"], rtol=1e-8)
    m = ref.manifest
    assert m["protocol"] == {"task": "encode", "mode": "oracle", "input": "mesh", "grid": 32, "eval_points": 20000,
                             "metric_preset": "default", "dataset": "builtin"}
    assert set(m["shapes"]) == set(made["shape"]) and all(d.startswith("generated:") for d in m["shapes"].values())
    (source,) = m["sources"]
    assert source["commit"] == head_commit()[:7] and set(source["code"]) == {"metrics", "sampler", "methods"}

    out = tmp_path / "b"
    assert main(run_args(out, cache, "--reference", str(folder))) == 0
    summary = (out / "summary.md").read_text()
    assert "| test\\_sdf (ref)" in summary and "| test\\_occ " in summary  # Markdown-escaped
    assert f"reference set mine (test\\_sdf on 2 shapes), not recomputed: 2 rows computed at commit {source['commit']}" \
        in summary
    stats = pd.read_csv(out / "statistics.csv")
    ref_cd = stats[(stats["method"] == "test_sdf (ref)") & (stats["metric"] == "cd")].iloc[0]
    assert ref_cd["pairs"] == 2 and ref_cd["mean"] == pytest.approx(made["cd"].mean() * 1000, rel=1e-6)
    assert "test_sdf (ref)" in (out / "report.html").read_text()
    assert "test_sdf" not in set(pd.read_csv(out / "timing.csv")["method"].str.replace(" (ref)", "", regex=False))
    assert "test_sdf" not in set(pd.read_csv(out / "results.csv")["method"])  # results.csv: the run's own rows

    # report joins it again, or another set; several runs refuse it
    assert main(["report", str(out), "--out", str(tmp_path / "again"), "--reference", str(folder)]) == 0
    assert "test\\_sdf (ref)" in (tmp_path / "again" / "summary.md").read_text()
    assert main(["report", str(out), str(tmp_path / "a"), "--reference", str(folder)]) == EXIT_REFUSED


def test_a_name_in_both_is_refused_unless_one_side_is_kept(crafted_set, tmp_path, capsys):
    folder, cache = crafted_set
    args = run_args(tmp_path / "c", cache, "--reference", str(folder), methods=("test_sdf", "test_occ"))
    assert main(args) == EXIT_REFUSED
    assert capsys.readouterr().err.strip() == (
        f"run_benchmark.py: error: --reference mine: row(s) test_sdf are both in this run and in the reference; "
        "say which to keep: --reference-keep run or --reference-keep reference")
    assert not (tmp_path / "c").exists()
    assert main(args + ["--reference-keep", "reference"]) == 0
    methods = set(pd.read_csv(tmp_path / "c" / "statistics.csv")["method"])
    assert {"test_sdf (ref)", "test_occ"} <= methods and "test_sdf" not in methods


@pytest.mark.parametrize("change, message", [
    ({"eval_points": 30000}, "eval_points differs: 30000 in the reference, 20000 in this run"),
    ({"grid": 64}, "grid differs: 64 in the reference, 32 in this run"),
    ({"metric_preset": "ndc"}, "metric_preset differs: 'ndc' in the reference, 'default' in this run"),
    ({"mode": "neural"}, "mode differs: 'neural' in the reference, 'oracle' in this run"),
    ({"dataset": "abc"}, "dataset differs: 'abc' in the reference, 'builtin' in this run"),
])
def test_another_protocol_is_refused_naming_the_setting_and_both_values(crafted_set, tmp_path, capsys, change, message):
    folder, cache = crafted_set
    ref = read_reference(folder)
    write_reference(folder, {**ref.manifest, "protocol": {**ref.protocol, **change}}, ref.rows)
    assert main(run_args(tmp_path / "d", cache, "--reference", str(folder))) == EXIT_REFUSED
    assert capsys.readouterr().err.strip() == f"run_benchmark.py: error: --reference mine: {message}"
    assert not (tmp_path / "d").exists()


def test_a_stale_metric_digest_is_refused_with_the_command_that_remakes_it(crafted_set, tmp_path, capsys):
    folder, cache = crafted_set
    ref = read_reference(folder)
    (source,) = ref.manifest["sources"]
    stale = {**source, "code": {**source["code"], "metrics": "0123456789abcdef"}}
    write_reference(folder, {**ref.manifest, "sources": [stale]}, ref.rows)
    assert main(run_args(tmp_path / "e", cache, "--reference", str(folder))) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "reference set mine is stale: 2 of its 2 rows (test_sdf) were scored by metric code 0123456789abcdef" in err
    assert err.endswith("re-make them: python run_benchmark.py --dataset builtin --methods test_sdf --mode oracle "
                        "--grid 32 --eval-points 20000 --metric-preset default --seed 0 --out runs/ref-mine && "
                        "python run_benchmark.py references make runs/ref-mine --name mine --replace")
    assert main(["references", "--into", str(folder.parent)]) == 0
    assert "| stale" in capsys.readouterr().out


def test_other_bytes_of_a_shared_shape_are_refused(crafted_set, tmp_path, capsys):
    folder, cache = crafted_set
    ref = read_reference(folder)
    shape = sorted(ref.manifest["shapes"])[0]
    write_reference(folder, {**ref.manifest, "shapes": {**ref.manifest["shapes"], shape: "generated:0000"}}, ref.rows)
    assert main(run_args(tmp_path / "f", cache, "--reference", str(folder))) == EXIT_REFUSED
    assert f"--reference mine: shape {shape} differs: its bytes are generated:" in capsys.readouterr().err


@pytest.mark.slow
def test_making_a_set_refuses_a_taken_name_and_what_is_not_a_run(made_set, tmp_path, capsys):
    folder, _ = made_set
    assert main(["references", "make", str(tmp_path / "a"), "--name", "mine", "--into", str(folder.parent)]) \
        == EXIT_REFUSED
    assert "a set named mine exists" in capsys.readouterr().err
    assert main(["references", "make", str(tmp_path / "nope"), "--name", "x", "--into", str(folder.parent)]) \
        == EXIT_REFUSED
    assert "not a finished salsbench run directory" in capsys.readouterr().err
    assert main(["--reference", "no-such-set", "--limit", "1"]) == EXIT_REFUSED
    assert "--reference no-such-set: no such reference set; known: abc-unseen93-encode" in capsys.readouterr().err


def test_the_shipped_sets_are_readable_and_say_their_protocol():
    names = reference_names()
    assert {"paper-abc50-encode", "paper-abc50-oracle", "paper-abc50-reconstruct", "paper-abc50-reconstruct-scan",
            "paper-nonmanifold50-encode", "paper-nonmanifold50-oracle", "abc-unseen93-encode"} <= set(names)
    for name in names:
        ref = find_reference(name)
        assert set(ref.rows["shape"]) == set(ref.manifest["shapes"]) and len(ref.rows) > 0
        assert (ref.rows["status"] == "ok").all()
        for source in ref.manifest["sources"]:
            assert source["cpu"] and len(source["code"]["metrics"]) == 16


# -- the shipped sets on the SALS paper's parts -----------------------------------------------------------

needs_parts = pytest.mark.skipif(not (SHARED_DATA / "abc-ppsurf").is_dir(),
                                 reason="../shared/data/abc-ppsurf is absent: the SALS paper's parts")
TWO = ["00010218_4769314c71814669ba5d3512_trimesh_013", "00993706_f8bc5c196ab9685d0182bbed_trimesh_001"]


@pytest.mark.slow
@needs_parts
def test_a_plugin_on_two_paper_parts_beside_every_reference_row(tmp_path):
    out = tmp_path / "run"
    assert main(["--task", "reconstruct", "--plugin", str(REPO / "examples" / "convex_hull.py"), "--methods",
                 "convex-hull", "--dataset", "sals-abc50", "--shapes", *TWO, "--reference", "paper-abc50-reconstruct",
                 "--gallery", "0", "--quiet", "--out", str(out), "--cache-dir", str(tmp_path / "cache"), "--executor", "local"]) == 0
    labels = {m + " (ref)" for m in find_reference("paper-abc50-reconstruct").rows["method"]}
    assert len(labels) == 7
    summary, html = (out / "summary.md").read_text(), (out / "report.html").read_text()
    stats = pd.read_csv(out / "statistics.csv")
    for label in labels:
        assert f"| {label} " in summary and label in html
        assert (stats.loc[stats["method"] == label, "pairs"] == 2).all()
    assert "over the 2 of this run's 2 shapes it has" in summary


@pytest.mark.slow
@needs_parts
def test_meshes_made_elsewhere_scored_beside_the_oracle_set(tmp_path):
    ref = find_reference("paper-abc50-oracle")
    shapes = sorted(ref.manifest["shapes"])[:2]  # two: a mean and a paired statistic over shapes
    preds = tmp_path / "preds"
    preds.mkdir()
    for s in shapes:  # the GT itself as "my" prediction: a mesh of another frame, scored in the original one
        (preds / f"{s}.stl").write_bytes((SHARED_DATA / "abc-ppsurf" / f"{s}.stl").read_bytes())
    out = tmp_path / "score"
    assert main(["score", "--pred-dir", str(preds), "--name", "mine", "--dataset", "sals-abc50", "--shapes", *shapes,
                 "--reference", "paper-abc50-oracle", "--gallery", "0", "--quiet", "--out", str(out), "--executor", "local"]) == 0
    stats = pd.read_csv(out / "statistics.csv")
    stats = stats[~stats["method"].str.startswith("floor")]  # the GT against a resample of itself
    assert set(stats["method"]) == {"mine"} | {m + " (ref)" for m in ref.rows["method"]} and stats["method"].nunique() == 12
    cd = stats[stats["metric"] == "cd"].set_index("method")["mean"]
    assert cd["mine"] < cd.drop("mine").min()  # the GT beats every reconstruction


@pytest.mark.slow
@needs_parts
def test_one_shipped_oracle_row_is_recomputed_to_its_stored_digits(tmp_path):
    """Drift in the metrics (or the exact fields, or E-DC) shows here: a shipped row re-made now."""
    ref = find_reference("paper-abc50-oracle")
    shape = "00017633_28ef8351018b4be18377fa7b_trimesh_005"
    out = tmp_path / "run"
    assert main(["--mode", "oracle", "--methods", "sals", "--dataset", "sals-abc50", "--shapes", shape,
                 "--gallery", "0", "--quiet", "--out", str(out), "--cache-dir", str(tmp_path / "cache"),
                 "--executor", "local"]) == 0
    now = pd.read_csv(out / "results.csv").iloc[0]
    stored = ref.rows[(ref.rows["shape"] == shape) & (ref.rows["method"] == "sals")].iloc[0]
    for metric in ("cd", "nc", "f1_005", "f1_01", "ecd", "ef1", "n_faces"):
        assert now[metric] == pytest.approx(stored[metric], rel=1e-7), metric
    assert json.loads((out / "config.json").read_text())["resolved"]["eval_points"] == ref.protocol["eval_points"]
