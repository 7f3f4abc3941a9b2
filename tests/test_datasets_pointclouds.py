"""The ``pointclouds`` dataset (datasets/pointclouds.py): cloud files with their GT beside them, in
the GT's canonical frame, or alone (reconstructed, not scored); bad clouds refused with one line; a
reconstruct run on the files."""

from __future__ import annotations

import io
import json
import sqlite3
import warnings

import numpy as np
import pandas as pd
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays, scalar_dtypes

from runner.cli import EXIT_REFUSED, main
from datasets import MeshError, get_dataset
from datasets.io import NO_GT
from datasets.pointclouds import read_point_cloud, read_scan, write_point_cloud
from tests.conftest import FAST_EXAMPLES
from tests.loader_fuzz import COUNTS, FLOATS, loads_or_refuses, mutated, truncations


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


@pytest.mark.parametrize("extension", [".ply", ".npz"])
def test_a_scan_with_its_sensors_reads_back_bit_for_bit_and_moves_with_the_gt(folder, extension):
    path, points = folder
    sensors = points + np.random.default_rng(1).normal(size=points.shape)
    write_point_cloud(path / f"scan{extension}", points, sensors)
    (path / "scan.gt.ply").write_bytes((path / "box.gt.ply").read_bytes())
    got_points, got_sensors = read_scan(path / f"scan{extension}")
    assert np.array_equal(got_points, points) and np.array_equal(got_sensors, sensors)
    shape = get_dataset("pointclouds", data_dir=path).load("scan")
    assert np.array_equal(shape.sensors, shape.transform.apply(sensors))  # the GT's canonical frame, as the points
    assert shape.content_hash != get_dataset("pointclouds", data_dir=path).load("box").content_hash
    assert get_dataset("pointclouds", data_dir=path).load("box").sensors is None  # a file without sensors


def test_sensors_must_match_the_points_and_only_ply_and_npz_hold_them(tmp_path):
    points = np.random.default_rng(0).random((150, 3))
    np.savez(tmp_path / "short.npz", points=points, sensor_position=points[:10])
    with pytest.raises(MeshError, match=r"short.npz: \(10, 3\) sensor positions for 150 points"):
        read_scan(tmp_path / "short.npz")
    np.savez(tmp_path / "none.npz", xyz=points)
    with pytest.raises(MeshError, match=r"none.npz: has no array 'points' \(arrays: xyz\)"):
        read_scan(tmp_path / "none.npz")
    with pytest.raises(ValueError, match="a .xyz file holds no sensor positions; write .ply or .npz"):
        write_point_cloud(tmp_path / "c.xyz", points, points)
    write_point_cloud(tmp_path / "c.xyz", points)
    assert np.array_equal(read_point_cloud(tmp_path / "c.xyz"), points)  # %.17g: exact


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
                 str(tmp_path / "c"), "--executor", "local"]) == 0
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


@pytest.mark.slow
def test_a_reconstruct_run_uses_the_files_points(folder, tmp_path, capsys):
    path, _ = folder
    out = tmp_path / "run"
    args = ["--dataset", "pointclouds", "--data-dir", str(path), "--methods", "poisson", "--grid", "32",
            "--eval-points", "5000", "--out", str(out), "--quiet", "--cache-dir", str(tmp_path / "c"),
            "--executor", "local"]
    assert main(["--task", "reconstruct", *args]) == 0
    (info,) = sqlite3.connect(out / "results.db").execute("SELECT info FROM jobs").fetchone()
    assert json.loads(info)["input_points"] == 3000
    capsys.readouterr()
    encode = [a for a in args if a not in ("--methods", "poisson")]
    assert main(encode + ["--out", str(tmp_path / "r2")]) == EXIT_REFUSED  # the encode task: refused
    assert "holds point clouds: use --task reconstruct" in capsys.readouterr().err


# -- property-based: any cloud file gives points or one MeshError line (issue 41, item 2) ------------
# tests/loader_fuzz.py: the contract each call is held to and the strategies; the example counts are
# the Hypothesis profile's (tests/conftest.py).

CLOUD = np.random.default_rng(0).random((120, 3))


def cloud_files(points) -> dict[str, tuple[str, bytes]]:
    """format -> (extension, the bytes of that file) of one cloud, in every format the loader reads."""
    npy = io.BytesIO()
    np.save(npy, points)
    xyz = "# a cloud\n" + "".join(" ".join(map(repr, map(float, p))) + " 0 0 1\n" for p in points)  # + normals
    cloud = trimesh.PointCloud(np.asarray(points, dtype=np.float64))
    sensors = np.asarray(points, dtype=np.float64) * 3.0
    return {"xyz": (".xyz", xyz.encode()), "npy": (".npy", npy.getvalue()),
            "ply_ascii": (".ply", cloud.export(file_type="ply", encoding="ascii")),
            "ply_binary": (".ply", cloud.export(file_type="ply")),
            "ply_scan": (".ply", _written(".ply", points, sensors)), "npz_scan": (".npz", _written(".npz", points, sensors))}


def _written(extension: str, points, sensors) -> bytes:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"cloud{extension}"
        write_point_cloud(path, points, sensors)
        return path.read_bytes()


VALID_CLOUDS = cloud_files(CLOUD)
CLOUD_COUNTS = [(b"element vertex 120", b"element vertex %d"), (b"(120, 3)", b"(%d, 3)"), (b"(120, 3)", b"(120, %d)")]
CLOUD_NUMBERS = [b"0.6369616873214543", b"0.2697867137638703", b"0 0 1", b"0.0"]


def _assert_cloud_shape(shape):
    """A cloud loaded without a GT: finite float64 points in the canonical box, no faces."""
    p = shape.points
    assert p.dtype == np.float64 and p.ndim == 2 and p.shape[1] == 3 and len(p) >= 100 and np.isfinite(p).all()
    assert np.abs(p).max() <= 0.995 + 1e-9 and not shape.has_gt


def _cloud_as(folder, extension: str, data: bytes, **kw):
    """The fuzzed file as the only cloud of a pointclouds dataset, loaded (read_point_cloud, then the
    canonical frame of its own points)."""
    path = folder / f"fuzzed{extension}"
    for old in folder.iterdir():
        old.unlink()
    path.write_bytes(data)
    shape = loads_or_refuses(lambda p: get_dataset("pointclouds", data_dir=folder).load(p.stem), path, MeshError, **kw)
    if shape is not None:
        _assert_cloud_shape(shape)
    return shape


@pytest.fixture(scope="module")
def cloud_dir(tmp_path_factory):
    read_point_cloud(_write_bytes(tmp_path_factory.mktemp("warm") / "c.ply", VALID_CLOUDS["ply_binary"][1]))
    return tmp_path_factory.mktemp("clouds")


def _write_bytes(path, data):
    path.write_bytes(data)
    return path


CLOUD_MAGIC = st.sampled_from([b"", b"PK\x03\x04", b"\x93NUMPY\x01\x00", b"\x93NUMPY\x02\x00", b"ply\nformat ascii 1.0\n", b"0 0 0\n",
                               b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n"])


@given(extension=st.sampled_from([".xyz", ".npy", ".ply", ".npz"]),
       data=st.tuples(CLOUD_MAGIC, st.binary(max_size=600)).map(b"".join))
def test_any_bytes_give_a_cloud_or_one_mesh_error_line(cloud_dir, extension, data):
    """Random bytes, alone or after the start of a header, under every cloud extension."""
    _cloud_as(cloud_dir, extension, data)


@pytest.mark.parametrize("fmt", sorted(VALID_CLOUDS))
@given(data=st.data())
def test_a_damaged_cloud_file_gives_a_cloud_or_one_mesh_error_line(cloud_dir, fmt, data):
    """A valid file truncated, with bytes flipped, inserted or deleted, a count or a number changed."""
    _cloud_as(cloud_dir, VALID_CLOUDS[fmt][0], data.draw(mutated(VALID_CLOUDS[fmt][1], CLOUD_COUNTS, CLOUD_NUMBERS)))


@pytest.mark.parametrize("fmt", ["npy", "ply_ascii", "ply_binary"])
@given(data=st.data())
def test_a_truncated_cloud_file_is_refused_or_read_whole(cloud_dir, fmt, data):
    """.npy and .ply state their point count: a cut file is refused, or the cut held no points."""
    shape = _cloud_as(cloud_dir, VALID_CLOUDS[fmt][0], data.draw(truncations(VALID_CLOUDS[fmt][1])))
    assert shape is None or len(shape.points) == len(CLOUD)


def _usable(points) -> bool:
    """Whether a (P, >= 3) array is a cloud the loader must accept: finite, a bounding box of some
    size that float64 can normalise."""
    with np.errstate(all="ignore"):
        points = np.asarray(points[:, :3], dtype=np.float64)
        side = np.ptp(points, axis=0)
    return bool(np.isfinite(points).all() and np.isfinite(side).all() and side.max() > 0)


def _npy_claiming(count: int) -> bytes:
    """CLOUD as a .npy whose header claims ``count`` points (the data stays 120 points)."""
    header = io.BytesIO()
    np.lib.format.write_array_header_2_0(header, {"descr": "<f8", "fortran_order": False, "shape": (count, 3)})
    valid = VALID_CLOUDS["npy"][1]
    return header.getvalue() + valid[valid.index(b"\n") + 1:]


@pytest.mark.parametrize("fmt", ["npy", "ply_binary", "ply_ascii"])
@given(count=COUNTS)
def test_a_claimed_point_count_the_file_does_not_hold_is_refused_before_allocating(cloud_dir, fmt, count):
    """A .ply or .npy header claiming up to 10^20 points is checked against the file's size before
    anything is allocated (traced peak under 64 MiB); only the true count loads."""
    extension, valid = VALID_CLOUDS[fmt]
    data = _npy_claiming(count) if fmt == "npy" else valid.replace(b"element vertex 120", b"element vertex %d" % count)
    shape = _cloud_as(cloud_dir, extension, data, trace_memory=True)
    assert (shape is not None) == (count == len(CLOUD))


@given(fmt=st.sampled_from(sorted(VALID_CLOUDS)),
       bad=st.lists(st.tuples(st.integers(0, 119), st.integers(0, 2), FLOATS), max_size=4))
def test_nan_inf_and_extreme_coordinates_give_a_cloud_or_one_mesh_error_line(cloud_dir, fmt, bad):
    """Up to 4 coordinates made NaN, inf, 1e308, denormal, -0.0 (any float64): the cloud loads exactly
    when its values are finite and its box has a size float64 can normalise."""
    points = CLOUD.copy()
    for row, column, value in bad:
        points[row, column] = value
    with np.errstate(all="ignore"), warnings.catch_warnings():  # trimesh's export of 1e308 to float32 warns
        warnings.simplefilter("ignore")
        extension, data = cloud_files(points)[fmt]
        stored = points.astype(np.float32) if fmt.startswith("ply") else points  # what the file holds
    shape = _cloud_as(cloud_dir, extension, data)
    assert (shape is not None) == _usable(stored)


NPY_DTYPES = st.one_of(scalar_dtypes(), st.sampled_from([np.dtype("U3"), np.dtype("S3"),
                                                          np.dtype([("x", "f4"), ("y", "f4"), ("z", "f4")])]))


@given(array=arrays(dtype=NPY_DTYPES, shape=st.one_of(st.tuples(st.integers(99, 101), st.integers(2, 4)),
                                                      array_shapes(min_dims=0, max_dims=3))))
def test_a_npy_of_any_dtype_and_shape_gives_a_cloud_or_one_mesh_error_line(cloud_dir, array):
    """A .npy of any dtype (bool, complex, datetime, strings, structured, float16, ...) and shape:
    points only from an integer or float (P >= 100, >= 3) array of usable values."""
    npy = io.BytesIO()
    np.save(npy, array)
    shape = _cloud_as(cloud_dir, ".npy", npy.getvalue())
    usable = (array.dtype.kind in "iuf" and array.ndim == 2 and array.shape[0] >= 100 and array.shape[1] >= 3
              and _usable(array))
    assert (shape is not None) == usable


@given(comment=st.text(st.characters(categories=["L", "N", "P", "S", "Zs"]), max_size=20),
       encoding=st.sampled_from(["utf-8", "latin-1", "cp1252", "utf-16"]))
def test_a_xyz_comment_in_any_encoding_loads_the_same_points_or_one_line(cloud_dir, comment, encoding):
    """A comment in UTF-8, Latin-1 or cp1252 loads the same points; UTF-16 is refused in one line."""
    text = VALID_CLOUDS["xyz"][1].decode().replace("# a cloud", f"# {comment}", 1)
    shape = _cloud_as(cloud_dir, ".xyz", text.encode(encoding, errors="replace"))
    if encoding != "utf-16":
        assert shape is not None and np.allclose(shape.transform.invert(shape.points), CLOUD, rtol=0, atol=1e-15)


GT_BOX = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
GT_FILES = {ext: (lambda data: data if isinstance(data, bytes) else data.encode())(GT_BOX.export(file_type=ext[1:]))
            for ext in (".ply", ".obj", ".stl", ".off", ".glb")}
GT_COUNTS = [(b"element vertex 8", b"element vertex %d"), (b"element face 12", b"element face %d"),
             (b"8 12 0", b"%d 12 0"), (b'"count":8', b'"count":%d')]


@pytest.mark.slow
@settings(max_examples=20 * FAST_EXAMPLES)
@given(cloud=st.sampled_from(sorted(VALID_CLOUDS)), gt=st.sampled_from(sorted(GT_FILES)), data=st.data())
def test_a_damaged_cloud_with_a_damaged_gt_mesh_gives_a_shape_or_one_line_at_length(cloud_dir, cloud, gt, data):
    """The slow lane's longer run over both loaders at once: a cloud and its GT mesh, either or both
    damaged (any format of each), loaded by the pointclouds dataset: a scored shape in the GT's
    canonical frame, or one MeshError line naming the cloud or the GT file."""
    folder = cloud_dir
    for old in folder.iterdir():
        old.unlink()
    extension, valid = VALID_CLOUDS[cloud]
    damage_cloud, damage_gt = data.draw(st.sampled_from([(True, False), (False, True), (True, True)]))
    cloud_bytes = data.draw(mutated(valid, CLOUD_COUNTS, CLOUD_NUMBERS)) if damage_cloud else valid
    gt_bytes = data.draw(mutated(GT_FILES[gt], GT_COUNTS, [b"1.0", b"0.5"])) if damage_gt else GT_FILES[gt]
    (folder / f"pair{extension}").write_bytes(cloud_bytes)
    gt_path = _write_bytes(folder / f"pair.gt{gt}", gt_bytes)

    def load(cloud_path):
        try:
            return get_dataset("pointclouds", data_dir=folder).load("pair")
        except MeshError as exc:
            assert str(cloud_path) in str(exc) or str(gt_path) in str(exc), f"names neither file: {exc}"
            raise

    shape = loads_or_refuses(load, folder / f"pair{extension}", MeshError, names_file=False)
    if shape is not None:
        assert shape.has_gt and np.isfinite(shape.points).all() and np.isfinite(shape.vertices).all()
        assert shape.faces.min() >= 0 and shape.faces.max() < len(shape.vertices)
