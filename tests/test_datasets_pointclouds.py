"""The ``pointclouds`` dataset (datasets/pointclouds.py): cloud files with their GT beside them, in
the GT's canonical frame, or alone (reconstructed, not scored); bad clouds refused with one line; a
reconstruct run on the files."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pandas as pd
import pytest
import trimesh

from runner.cli import EXIT_REFUSED, main
from datasets import MeshError, get_dataset
from datasets.io import NO_GT
from datasets.pointclouds import read_point_cloud


@pytest.fixture
def folder(tmp_path):
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box.apply_translation((10.0, 0.0, 0.0))  # a source frame far from the canonical one
    box.export(tmp_path / "box.gt.ply")
    points = trimesh.sample.sample_surface(box, 3000, seed=0)[0]
    np.savetxt(tmp_path / "box.xyz", np.hstack([points, np.ones((len(points), 3))]))  # + ignored normals
    return tmp_path, points


def test_a_cloud_loads_in_the_canonical_frame_of_its_gt(folder):
    path, points = folder
    np.save(path / "copy.npy", points)
    (path / "copy.gt.ply").write_bytes((path / "box.gt.ply").read_bytes())
    trimesh.PointCloud(points).export(path / "third.ply")
    (path / "third.gt.ply").write_bytes((path / "box.gt.ply").read_bytes())
    ds = get_dataset("pointclouds", data_dir=path)
    assert ds.names() == ["box", "copy", "third"]  # GT files are not clouds
    shapes = [ds.load(n) for n in ds.names()]
    for s in shapes:
        assert s.points.shape == (3000, 3) and s.kind == "closed"
        assert np.allclose(s.points.min(axis=0), s.vertices.min(axis=0), atol=0.02)  # box corners at -0.995 ...
        assert np.allclose(s.vertices.min(axis=0), [-0.995, -0.4975, -0.24875])
    assert np.allclose(shapes[0].points, shapes[1].points)
    assert np.allclose(np.sort(shapes[0].points, axis=0), np.sort(shapes[2].points, axis=0), atol=1e-6)


@pytest.mark.parametrize("name, content, message", [
    ("empty.xyz", "", "points; a cloud needs at least 100"),
    ("two.xyz", "0 0 0\n1 1 1\n", "2 points; a cloud needs at least 100"),
    ("nan.npy", None, "points with NaN/inf coordinates"),
    ("text.xyz", "a b c\n" * 200, "cannot read the point cloud"),
    ("flat.npy", np.zeros((200, 2)), "expected (P, 3) points"),
])
def test_bad_clouds_are_one_line_naming_the_file(tmp_path, name, content, message):
    path = tmp_path / name
    if name.endswith(".npy"):
        data = np.full((200, 3), np.nan) if content is None else content
        np.save(path, data)
    else:
        path.write_text(content)
    with pytest.raises(MeshError) as err:
        read_point_cloud(path)
    assert message in str(err.value) and str(path) in str(err.value) and "\n" not in str(err.value)


def test_a_mesh_ply_is_not_a_cloud_and_a_cloud_alone_has_no_gt_and_its_own_frame(tmp_path):
    trimesh.creation.box().export(tmp_path / "mesh.ply")
    with pytest.raises(MeshError, match="a mesh with faces, not a point cloud"):
        read_point_cloud(tmp_path / "mesh.ply")
    points = np.random.default_rng(0).uniform([5.0, -1.0, 0.0], [9.0, 1.0, 1.0], size=(500, 3))
    np.save(tmp_path / "alone.npy", points)
    shape = get_dataset("pointclouds", data_dir=tmp_path).load("alone")
    assert not shape.has_gt and shape.kind == NO_GT and shape.vertices.shape == (0, 3)
    # the canonical frame of the points themselves: bbox centred, largest side (x, 4 long) 1.99
    lo, hi = shape.points.min(axis=0), shape.points.max(axis=0)
    assert np.allclose((lo + hi) / 2, 0, atol=1e-12) and (hi - lo).max() == pytest.approx(1.99)
    assert np.allclose(shape.transform.invert(shape.points), points)
    np.save(tmp_path / "point.npy", np.ones((200, 3)))
    with pytest.raises(MeshError, match="bounding box has zero size"):
        get_dataset("pointclouds", data_dir=tmp_path).load("point")


@pytest.mark.slow
def test_clouds_without_a_gt_are_reconstructed_and_listed_apart_from_the_scored(folder, tmp_path):
    """A scan alone is reconstructed like any cloud (mesh written, validity counted) and kept out of
    every metric: the mean table is over the cloud with a GT, the floor has no row for the scan."""
    path, points = folder
    np.save(path / "scan.npy", points[:, [2, 0, 1]] * 3.0)  # another frame, no GT beside it
    out = tmp_path / "run"
    assert main(["--task", "reconstruct", "--dataset", "pointclouds", "--data-dir", str(path), "--methods", "poisson",
                 "--grid", "32", "--eval-points", "5000", "--out", str(out), "--quiet", "--cache-dir",
                 str(tmp_path / "c")]) == 0
    jobs = pd.read_csv(out / "results.csv").set_index("shape")
    assert (jobs["status"] == "ok").all() and jobs.loc["scan", "n_faces"] > 0
    assert jobs.loc["scan", "scored"] == 0 and np.isnan(jobs.loc["scan", "cd"]) and np.isnan(jobs.loc["scan", "ef1"])
    assert jobs.loc["box", "scored"] == 1 and jobs.loc["box", "cd"] < 0.05
    assert (out / "meshes" / "scan" / "poisson.ply").is_file() and not (out / "meshes" / "scan" / "gt.ply").exists()
    stats = pd.read_csv(out / "statistics.csv").set_index(["method", "metric"])
    assert stats.loc[("poisson", "cd"), "shapes"] == 1
    assert stats.loc[("poisson", "cd"), "mean"] == pytest.approx(jobs.loc["box", "cd"] * 1e3, rel=1e-5)
    summary = (out / "summary.md").read_text()
    assert "Reconstructed without a GT (not scored)" in summary and "| scan" in summary
    assert "not scored (no GT)" in (out / "report.html").read_text()


def test_a_reconstruct_run_uses_the_files_points(folder, tmp_path, capsys):
    path, _ = folder
    out = tmp_path / "run"
    args = ["--dataset", "pointclouds", "--data-dir", str(path), "--methods", "poisson", "--grid", "32",
            "--eval-points", "5000", "--out", str(out), "--quiet", "--cache-dir", str(tmp_path / "c")]
    assert main(["--task", "reconstruct", *args]) == 0
    (info,) = sqlite3.connect(out / "results.db").execute("SELECT info FROM jobs").fetchone()
    assert json.loads(info)["input_points"] == 3000
    capsys.readouterr()
    encode = [a for a in args if a not in ("--methods", "poisson")]
    assert main(encode + ["--out", str(tmp_path / "r2")]) == EXIT_REFUSED  # the encode task: refused
    assert "holds point clouds: use --task reconstruct" in capsys.readouterr().err
