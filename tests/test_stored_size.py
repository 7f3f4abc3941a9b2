"""datasets.stored_size: the counts a file's header (or a bounded-memory line count) gives before the
file is read, checked against what the loaders read from the same files."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import datasets.stored_size as stored_size
from datasets.io import read_mesh_file
from datasets.pointclouds import read_point_cloud
from datasets.stored_size import count_occurrences, stored_count


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(2)  # 162 vertices, 320 faces


@pytest.mark.parametrize("name,kwargs", [("m.ply", {"encoding": "binary"}), ("m.ply", {"encoding": "ascii"}),
                                         ("m.off", {}), ("m.obj", {}), ("m.stl", {}),
                                         ("m.stl", {"file_type": "stl_ascii"})])
def test_the_stored_face_count_is_the_count_the_loader_reads(sphere, tmp_path, name, kwargs):
    path = tmp_path / name
    data = trimesh.exchange.export.export_mesh(sphere, None, file_type=kwargs.pop("file_type", path.suffix[1:]), **kwargs)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    assert stored_count(path, "faces") == len(read_mesh_file(path)[1]) == 320
    if path.suffix != ".stl":  # an STL stores 3 corners per triangle, welded by the loader: no vertex count
        assert stored_count(path, "points") == len(read_mesh_file(path)[0]) == 162


def test_a_header_is_believed_without_reading_the_body(tmp_path):
    path = tmp_path / "liar.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     b"property float z\nelement face 30000000\nproperty list uchar int vertex_indices\nend_header\n")
    assert stored_count(path, "faces") == 30_000_000 and stored_count(path, "points") == 3
    off = tmp_path / "liar.off"
    off.write_text("OFF\n# a comment\n4 70000000 0\n0 0 0\n")
    assert stored_count(off, "faces") == 70_000_000 and stored_count(off, "points") == 4
    stl = tmp_path / "liar.stl"
    stl.write_bytes(bytes(80) + (2).to_bytes(4, "little") + bytes(100))  # 84 + 50 x 2 bytes: binary, 2 triangles
    assert stored_count(stl, "faces") == 2


def test_obj_lines_are_counted_across_chunk_boundaries(tmp_path, monkeypatch):
    text = "# f 1 2 3 (a comment)\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1 2 3\nf\t1 2 3\n  f 1 2 3\nf 1 2 3 1\n"
    path = tmp_path / "m.obj"
    path.write_text(text * 50)
    for chunk in (1, 2, 3, 7, 1 << 24):  # every offset of a 2-byte pattern against the boundary
        monkeypatch.setattr(stored_size, "CHUNK_BYTES", chunk)
        assert stored_count(path, "faces") == 3 * 50  # an indented face line is not counted (its loader still is)
        assert stored_count(path, "points") == 3 * 50
        assert count_occurrences(path, (b"vt",)) == 50


def test_cloud_files_give_their_point_counts(tmp_path):
    points = np.random.default_rng(0).random((250, 3))
    np.save(tmp_path / "c.npy", points)
    np.savetxt(tmp_path / "c.xyz", points)
    (tmp_path / "d.xyz").write_text("0 0 0\n1 1 1")  # no newline at the end
    trimesh.PointCloud(points).export(tmp_path / "c.ply")
    for name in ("c.npy", "c.xyz", "c.ply"):
        assert stored_count(tmp_path / name, "points") == len(read_point_cloud(tmp_path / name)) == 250
    assert stored_count(tmp_path / "d.xyz", "points") == 2


def test_unknown_or_unreadable_headers_give_none(tmp_path):
    (tmp_path / "a.ply").write_bytes(b"not a ply at all")
    (tmp_path / "b.off").write_text("OFF\nthree four\n")
    (tmp_path / "c.npy").write_bytes(b"\x93NUMPY garbage")
    (tmp_path / "d.glb").write_bytes(b"glTF")
    for name in ("a.ply", "b.off", "c.npy", "d.glb"):
        assert stored_count(tmp_path / name, "faces") is None
    with pytest.raises(ValueError, match="what must be 'faces' or 'points'"):
        stored_count(tmp_path / "a.ply", "edges")


def test_an_npz_cloud_gives_the_rows_of_its_points_array(tmp_path):
    np.savez(tmp_path / "s.npz", points=np.zeros((321, 3)), sensor_position=np.ones((321, 3)))
    np.savez(tmp_path / "t.npz", other=np.zeros((5, 3)))
    assert stored_count(tmp_path / "s.npz", "points") == 321
    assert stored_count(tmp_path / "t.npz", "points") is None
