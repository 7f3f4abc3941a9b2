"""The ``pointclouds`` dataset (datasets/pointclouds.py): cloud files with their GT beside them, in
the GT's canonical frame; bad clouds refused with one line; a reconstruct run on the files."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
import trimesh

from benchmark.run.cli import EXIT_REFUSED, main
from datasets import MeshError, get_dataset
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


def test_a_mesh_ply_is_not_a_cloud_and_a_cloud_without_gt_is_refused(tmp_path):
    trimesh.creation.box().export(tmp_path / "mesh.ply")
    with pytest.raises(MeshError, match="a mesh with faces, not a point cloud"):
        read_point_cloud(tmp_path / "mesh.ply")
    np.save(tmp_path / "alone.npy", np.random.default_rng(0).normal(size=(500, 3)))
    with pytest.raises(MeshError, match="no GT mesh beside it"):
        get_dataset("pointclouds", data_dir=tmp_path).load("alone")


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
