"""The reconstruct task through the command line: the input point cloud, a classic baseline end to
end, and the options that belong to one task refused in the other."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from runner.cli import EXIT_REFUSED, main
from foundation.corruptions import input_point_cloud
from datasets import get_dataset


@pytest.fixture(scope="module")
def shape():
    ds = get_dataset("builtin")
    return ds.load(ds.names()[0])


def test_the_input_cloud_is_seeded_on_the_surface_and_noised_as_asked(shape):
    from foundation.fields import ExactFields

    (a, sensors), (b, _) = input_point_cloud(shape, 5000, 0.0, seed=0), input_point_cloud(shape, 5000, 0.0, seed=0)
    assert a.shape == (5000, 3) and np.array_equal(a, b) and sensors is None  # uniform samples carry no sensors
    assert not np.array_equal(a, input_point_cloud(shape, 5000, 0.0, seed=1)[0])
    fields = ExactFields(shape.vertices, shape.faces)
    assert fields.udf(a).max() < 1e-6  # on the GT surface
    noisy, _ = input_point_cloud(shape, 5000, 0.01, seed=0)
    assert np.std(noisy - a) == pytest.approx(0.01, rel=0.05)  # the clean cloud plus N(0, sigma^2) per axis


def test_a_scan_input_is_on_the_surface_with_a_sensor_per_point_and_the_same_for_every_method(shape):
    from foundation.corruptions import input_cloud
    from foundation.fields import ExactFields
    from foundation.seeding import job_streams

    points, sensors = input_point_cloud(shape, 5000, 0.0, seed=0, corruption="scan")
    assert points.shape == sensors.shape == (5000, 3)
    assert ExactFields(shape.vertices, shape.faces).udf(points).max() < 1e-9
    assert np.allclose(np.linalg.norm(sensors, axis=1), 3.0, rtol=1e-2)  # 10 sensors 3 units from the centre
    again = input_cloud(shape.vertices, shape.faces, 5000, "scan", job_streams(shape.content_hash, 0).sampler_rng())
    assert np.array_equal(points, again.points)  # the job's sampler stream: what any method of the job gets


@pytest.mark.slow
def test_a_scan_run_gives_poisson_its_sensors_and_says_so(tmp_path):
    out = tmp_path / "run"
    code = main(["--task", "reconstruct", "--methods", "poisson", "--limit", "1", "--grid", "32", "--pc-points",
                 "5000", "--eval-points", "5000", "--out", str(out), "--quiet", "--cache-dir", str(tmp_path / "c"),
                 "--pc-corruption", "scan", "--executor", "local"])
    assert code == 0
    df = pd.read_csv(out / "results.csv")
    assert list(df.used_sensors) == [1] and df.loc[0, "cd"] < 0.05
    assert "Given each input point's sensor position (a scan): poisson;" in (out / "summary.md").read_text()


@pytest.mark.slow
def test_poisson_runs_as_a_reconstruct_task_end_to_end(tmp_path):
    out = tmp_path / "run"
    code = main(["--task", "reconstruct", "--methods", "poisson", "--limit", "1", "--grid", "32", "--pc-points",
                 "5000", "--eval-points", "5000", "--out", str(out), "--quiet", "--cache-dir", str(tmp_path / "c"),
                 "--executor", "local"])
    assert code == 0
    df = pd.read_csv(out / "results.csv")
    assert list(df.method) == ["poisson"] and (df.status == "ok").all()
    assert df.loc[0, "n_faces"] > 0 and df.loc[0, "cd"] < 0.05 and df.loc[0, "reconstruct_s"] > 0
    assert "sample_s" in df.columns and "fit_s" in df.columns and np.isnan(df.loc[0, "fit_s"])


@pytest.mark.parametrize("args, message", [
    (["--task", "reconstruct", "--methods", "sals"], "method 'sals' belongs to the encode task"),
    (["--methods", "poisson"], "method 'poisson' belongs to the reconstruct task"),
    (["--pc-points", "1000"], "--pc-points applies to --task reconstruct, not to --task encode"),
    (["--pc-corruption", "scan"], "--pc-corruption applies to --task reconstruct"),
    (["--train-dir", "/x"], "--train-dir applies to --task reconstruct"),
    (["--task", "reconstruct", "--decompose"], "--decompose applies to --task encode"),
    (["--task", "reconstruct", "--pc-corruption", "noise-4"], "--pc-corruption='noise-4'"),
    (["--task", "reconstruct", "--pc-corruption", "scan", "--pc-noise", "0.01"], "for a scan use --pc-corruption"),
    (["--task", "reconstruct", "--pc-points", "10"], "--pc-points='10': expected int in [100, inf)"),
    (["--task", "reconstruct", "--mode", "oracle"], "--mode oracle applies to --task encode, not to --task reconstruct"),
    (["--task", "score", "--methods", "m", "--sweep", "grid=32,64"], "--sweep applies to --task encode or --task reconstruct"),
    (["--task", "reconstruct", "--methods", "udf-knn", "--train-dir", "/nonexistent"], "--train-dir /nonexistent"),
    (["--task", "reconstruct", "--methods", "udf-knn", "--no-cache"], "keep their trained networks in the cache"),
])
def test_options_of_the_other_task_are_refused_with_one_line(tmp_path, capsys, args, message):
    assert main([*args, "--out", str(tmp_path / "r")]) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


@pytest.mark.slow
def test_a_learned_method_trains_once_and_later_jobs_and_runs_load_its_network(tmp_path):
    import json

    from methods.pointcloud.knn.training import KNN_BUDGETS, KNNBudget

    budget = KNNBudget("test-knn", k=8, encoder_width=16, encoder_depth=1, head_width=16, head_depth=1, steps=20,
                       shapes_per_batch=2, samples_per_item=256, points_per_item=2000, training_shapes=2,
                       pool_samples=4000, pool_points=4000, log_every=10)
    args = ["--task", "reconstruct", "--methods", "udf-knn", "poisson", "--budget", "test-knn", "--limit", "2",
            "--grid", "24", "--pc-points", "3000", "--eval-points", "5000", "--train-dir", str(tmp_path / "extra"),
            "--cache-dir", str(tmp_path / "cache"), "--quiet",
            "--executor", "local"]  # the test's knn budget is registered in this process only
    (tmp_path / "extra").mkdir()
    import trimesh

    trimesh.creation.box(extents=(1.0, 0.6, 0.4)).export(tmp_path / "extra" / "box.ply")
    with KNN_BUDGETS.registered("test-knn", budget):
        assert main([*args, "--out", str(tmp_path / "a")]) == 0
        assert main([*args, "--out", str(tmp_path / "b")]) == 0
    a, b = pd.read_csv(tmp_path / "a" / "results.csv"), pd.read_csv(tmp_path / "b" / "results.csv")
    learned = a[a.method == "udf-knn"]
    assert (a.status == "ok").all() and len(learned) == 2
    info = [json.loads(r) for r in pd.read_sql_query(
        "SELECT info FROM jobs WHERE method = 'udf-knn' ORDER BY rowid",
        __import__("sqlite3").connect(tmp_path / "a" / "results.db"))["info"]]
    assert [i["trained"] for i in info] == [1, 0] and info[0]["network_key"] == info[1]["network_key"]
    assert (b[b.method == "udf-knn"]["cache"] == "network").all()  # the second run trains nothing
    assert np.allclose(learned["cd"].to_numpy(), b[b.method == "udf-knn"]["cd"].to_numpy())
    assert a[a.method == "poisson"]["budget"].isna().all()  # the classic baseline trains nothing
    record = json.loads((tmp_path / "a" / "config.json").read_text())
    assert record["config"]["budget"] == "test-knn" and record["resolved"]["budget"] == {"knn": {
        "training_shapes": 2, "pool_samples": 4000, "pool_points": 4000, "k": 8, "encoder_width": 16, "encoder_depth": 1,
        "head_width": 16, "head_depth": 1, "steps": 20, "shapes_per_batch": 2, "samples_per_item": 256,
        "points_per_item": 2000, "lr": 1e-3, "weight_decay": 0.01, "log_every": 10}}
    assert record["resolved"]["train_dirs"] == [
        str((tmp_path / "extra").resolve())]


def test_the_knn_recipe_sweeps_k_over_the_learned_method_only(tmp_path):
    from runner.cli import build_parser, configure
    from runner.plan import resolve
    from runner.plan import build_tasks

    args = build_parser().parse_args(["--recipe", "knn", "--methods", "sals-knn", "poisson", "--limit", "1",
                                      "--out", str(tmp_path / "r")])
    plan = resolve(configure(args, tmp_path / "r"))
    _, jobs = build_tasks(plan)
    learned = [j for j in jobs if j.method == "sals-knn"]
    classic = [j for j in jobs if j.method == "poisson"]
    assert len(learned) == 9 and {j.budget_params["k"] for j in learned} == {10, 20, 50}
    assert len(classic) == 3 and all(j.budget is None and not j.budget_params for j in classic)  # one per density
    assert {j.pc_points for j in classic} == {10_000, 40_000, 100_000}


def test_a_run_directory_refuses_another_training_set(tmp_path, capsys):
    import json

    import trimesh

    from runner.cli import _plan, build_parser

    extra = tmp_path / "extra"
    extra.mkdir()
    trimesh.creation.box(extents=(1.0, 0.6, 0.4)).export(extra / "box.ply")
    out = tmp_path / "run"
    args = build_parser().parse_args(["--task", "reconstruct", "--methods", "sals-knn", "--limit", "1",
                                      "--train-dir", str(extra), "--out", str(out)])
    plan = _plan(args, out)
    assert plan.record()["training_set"] == {str(extra.resolve()): plan.training_set[str(extra.resolve())]}
    out.mkdir()
    (out / "config.json").write_text(json.dumps({"config": plan.config.to_dict(), "resolved": plan.record()}))
    assert _plan(args, out).training_set == plan.training_set  # the same files: the same run
    trimesh.creation.box(extents=(1.0, 0.6, 0.5)).export(extra / "box.ply")  # the folder now holds other meshes
    assert main(["--task", "reconstruct", "--methods", "sals-knn", "--limit", "1", "--train-dir", str(extra),
                 "--out", str(out), "--quiet"]) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "trained on another training set (training_set" in err, err


def test_exported_clouds_are_the_run_inputs_and_read_back_as_a_pointclouds_dataset(tmp_path, shape):
    out = tmp_path / "clouds"
    code = main(["export-inputs", "--task", "reconstruct", "--limit", "1", "--pc-points", "3000", "--seed", "0", "--quiet",
                 "--sweep", "pc_corruption=uniform,outliers-2", "--cloud-format", "npz", "--out", str(out)])
    assert code == 0
    assert sorted(p.name for p in out.iterdir()) == ["outliers-2-s0", "uniform-s0"]
    for corruption in ("uniform", "outliers-2"):
        folder = out / f"{corruption}-s0"
        assert sorted(p.name for p in folder.iterdir()) == [f"{shape.name}.gt.off", f"{shape.name}.npz"]
        loaded = get_dataset("pointclouds", data_dir=folder).load(shape.name)
        points, sensors = input_point_cloud(shape, 3000, 0.0, seed=0, corruption=corruption)
        assert np.allclose(loaded.points, points, rtol=0, atol=1e-12)  # the run's cloud, through the source frame
        assert np.allclose(loaded.vertices, shape.vertices, rtol=0, atol=1e-12)
        assert (loaded.sensors is None) == (sensors is None)
        if sensors is not None:
            assert np.allclose(loaded.sensors, sensors, rtol=0, atol=1e-12)


def test_export_inputs_needs_an_output_folder(tmp_path, capsys):
    assert main(["export-inputs", "--task", "reconstruct"]) == EXIT_REFUSED
    assert "export-inputs writes its files under --out DIR" in capsys.readouterr().err
    assert main(["export-inputs", "--cloud-format", "obj", "--out", str(tmp_path)]) == EXIT_REFUSED
    assert "--cloud-format must be one of ply, npz, got 'obj'" in capsys.readouterr().err


def test_encode_inputs_are_the_canonical_gt_and_the_shared_samplers_draw(tmp_path, shape):
    from foundation.sampler import sample_training_data
    from foundation.seeding import job_streams
    from datasets.io import read_mesh_file
    from methods.base import get_method

    out = tmp_path / "inputs"
    assert main(["export-inputs", "--methods", "sals", "--budget", "tiny", "--limit", "1", "--quiet",
                 "--out", str(out)]) == 0
    folder = out / "encode-s0"
    vertices, faces = read_mesh_file(folder / f"{shape.name}.gt.off")
    assert np.array_equal(vertices, shape.vertices) and np.array_equal(faces, shape.faces)  # canonical, exact
    budget = get_method("sals").budget("tiny", {})
    expected = sample_training_data(shape.vertices, shape.faces, budget.num_samples,
                                    job_streams(shape.content_hash, 0).sampler_rng())
    with np.load(folder / f"{shape.name}.samples.npz") as got:
        assert np.array_equal(got["segments"], expected.segments) and np.array_equal(got["group"], expected.group)


@pytest.mark.slow
def test_the_robustness_recipe_runs_every_corruption_and_writes_its_tables(tmp_path):
    """The shipped recipe with Poisson on one built-in shape: 17 inputs, every job ok, robustness.md
    with a section per kind, Poisson given sensors on every scan input."""
    out = tmp_path / "run"
    code = main(["--recipe", "robustness", "--methods", "poisson", "--limit", "1", "--grid", "32",
                 "--pc-points", "5000", "--eval-points", "5000", "--out", str(out), "--quiet", "--gallery", "0",
                 "--cache-dir", str(tmp_path / "c"), "--executor", "local"])
    assert code == 0
    df = pd.read_csv(out / "results.csv")
    assert len(df) == 17 and (df.status == "ok").all()
    assert (df["used_sensors"] == (df["sweep.pc_corruption"] != "uniform").astype(int)).all()
    text = (out / "robustness.md").read_text()
    assert all(f"## {kind}" in text for kind in ("noise", "outliers", "missing", "density", "misalign"))
    assert "Mean CD grows at every step scan -\\> 1 -\\> 2 -\\> 3" in text
