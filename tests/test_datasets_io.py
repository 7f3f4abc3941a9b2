"""datasets/io.py: reading, validation and the canonical frame."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest
import trimesh

from tests.conftest import SHARED_DATA, shared_meshes
from datasets.formats import parse_off
from datasets.io import (
    MeshError,
    Normalization,
    classify_topology,
    load_shape,
    normalize_shape,
    read_mesh_arrays,
    read_mesh_file,
    save_mesh,
)

SHARED = shared_meshes()
NO_SHARED = pytest.param(None, marks=pytest.mark.skip(reason=f"{SHARED_DATA} is absent: real-mesh tests need ../shared/data"))


def _ids(paths):
    return [p.relative_to(SHARED_DATA).as_posix() for p in paths]


def file_vertex_count(path) -> int | None:
    """Vertex count as the file states it (OBJ: 'v' lines; PLY: the header), None for STL."""
    if path.suffix == ".obj":
        return sum(1 for line in path.read_text().splitlines() if line.startswith("v "))
    if path.suffix == ".ply":
        header = path.read_bytes()[:4096]
        return int(re.search(rb"element vertex (\d+)", header).group(1))
    return None


def provenance_stl_counts() -> dict[str, tuple[int, int]]:
    """file name -> (V_merged, F) from the abc/ table of the data folder's PROVENANCE.md (SHARED_DATA)."""
    rows = [line.split("|") for line in (SHARED_DATA / "PROVENANCE.md").read_text().splitlines() if line.startswith("|")]
    header = [c.strip() for c in rows[0]]
    col_v, col_f = header.index("V_merged"), header.index("F")
    return {r[1].split()[0]: (int(r[col_v]), int(r[col_f])) for r in rows if r[1].strip().endswith(".stl") or ".stl " in r[1]}


# -- every real mesh ------------------------------------------------------------------------------


@pytest.mark.parametrize("path", SHARED or [NO_SHARED], ids=_ids(SHARED) or None)
def test_shared_mesh_loads_into_canonical_frame(path):
    shape = load_shape(path)
    v = shape.vertices
    assert v.dtype == np.float64 and shape.faces.dtype == np.int64 and shape.faces.shape[1] == 3
    assert np.abs(v).max() <= 0.995 + 1e-9
    used = v[np.unique(shape.faces)]
    assert np.ptp(used, axis=0).max() == pytest.approx(1.99, abs=1e-12)
    assert np.allclose((used.max(0) + used.min(0)) / 2, 0.0, atol=1e-12)
    # the transform maps back to the file's own coordinates
    raw_vertices, raw_faces = read_mesh_arrays(path)
    scale = np.abs(raw_vertices).max()
    np.testing.assert_allclose(shape.transform.invert(v), raw_vertices, rtol=0, atol=1e-12 * scale)
    np.testing.assert_array_equal(shape.faces, raw_faces)
    # no silent merging: the vertex count is the file's
    stated = file_vertex_count(path)
    if stated is not None:
        assert len(v) == stated


@pytest.mark.skipif(not (SHARED_DATA / "PROVENANCE.md").is_file(), reason=f"{SHARED_DATA} is absent")
def test_stl_is_welded_exactly_to_provenance_counts():
    counts = provenance_stl_counts()
    assert len(counts) == 7
    for name, (v_merged, n_faces) in counts.items():
        vertices, faces = read_mesh_arrays(SHARED_DATA / "abc" / name)
        assert (len(vertices), len(faces)) == (v_merged, n_faces), name


# -- bad inputs: one MeshError line naming the file -------------------------------------------------


def _write(path, content):
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    return path


PLY_HEAD = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
PLY_FACE = "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
ASCII_STL = (b"solid caf\xe9\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
             b"endloop\nendfacet\nendsolid caf\xe9\n")  # the solid's name in Latin-1: not UTF-8

#: file name -> (content, the whole message after "<path>: ")
BAD_INPUTS = {
    "missing.obj": (None, "file not found"),
    "empty.obj": ("", "file is empty"),
    "garbage.obj": (bytes(range(256)) * 8, "holds binary data, not a text OBJ file"),
    "nan.obj": ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "1 vertices have NaN or infinite coordinates"),
    "degenerate.obj": ("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 1 2 4\nf 2 2 3\n",
                       "total surface area is zero relative to its size (0 x the largest bounding-box side "
                       "squared, below 1e-12; degenerate mesh)"),
    # a sliver: area 0.5e-14 on a box of side 1, a line up to rounding
    "sliver.obj": ("v 0 0 0\nv 1 0 0\nv 0.5 1e-14 0\nf 1 2 3\n",
                   "total surface area is zero relative to its size (5e-15 x the largest bounding-box side "
                   "squared, below 1e-12; degenerate mesh)"),
    "points.ply": (PLY_HEAD + "end_header\n0 0 0\n1 0 0\n0 1 0\n",
                   "3 vertices but no faces (a point cloud?); a triangle mesh is needed"),
    "points.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "3 vertices but no faces (a point cloud?); a triangle mesh is needed"),
    "text.obj": ("hello world\n", "no vertices found (not an OBJ mesh?)"),
    "badindex.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "face indices out of range [0, 3)"),
    "hugeindex.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1e20\n",
                      "face index 1e+20 is out of range (no mesh has that many vertices)"),
    "hugeindex.off": ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1e20\n",
                      "face index 1e+20 is out of range (no mesh has that many vertices)"),
    "zeroindex.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "face index 0 (OBJ indices start at 1)"),
    "text.off": ("hello\n", "no OFF header (first line starts with 'hello')"),
    "short.off": ("OFF\n3 1 0\n0 0 0\n1 0 0\n", "file ends early: header promises 3 vertices and 1 faces, found 2 data lines"),
    "mesh.xyz": ("0 0 0\n", "unsupported extension '.xyz' (use one of .obj, .ply, .stl, .off, .glb, .gltf)"),
    # STL: bytes 80-83 of bytes(range(256)) are 0x50 0x51 0x52 0x53, a little-endian count of 1,397,903,696
    "garbage.stl": (bytes(range(256)) * 8, "not an STL file: binary header claims 1,397,903,696 triangles "
                    "(69,895,184,884 bytes) but the file holds 2,048 bytes, and it does not start with 'solid' (ASCII STL)"),
    "short.stl": (b"abc", "not an STL file: 3 bytes, shorter than a binary STL header (84 bytes), "
                  "and it does not start with 'solid' (ASCII STL)"),
    # bytes 80-83 of "solid " + bytes(range(256)) are 0x4a..0x4d: 1,296,845,642 triangles
    "binary_solid.stl": (b"solid " + bytes(range(256)), "not an STL file: starts with 'solid' but holds binary data, "
                         "and its binary header claims 1,296,845,642 triangles (64,842,282,184 bytes) but the file holds 262 bytes"),
    # PLY headers
    "garbage.ply": (bytes(range(256)) * 8, "not a PLY file (its first line is not 'ply')"),
    "no_y.ply": (PLY_HEAD.replace("property float y\n", "") + PLY_FACE, "PLY vertex element lacks property 'y'"),
    "no_vertex.ply": ("ply\nformat ascii 1.0\n" + PLY_FACE, "PLY header has no 'element vertex' line"),
    "no_end.ply": (PLY_HEAD, "PLY header has no 'end_header' line"),
    "no_format.ply": (PLY_HEAD.replace("format ascii 1.0\n", "") + PLY_FACE, "PLY header has no 'format' line"),
    "bad_format.ply": (PLY_HEAD.replace("ascii", "text") + PLY_FACE,
                       "PLY format 'text' is not one of ascii, binary_little_endian, binary_big_endian (with a version)"),
    "bad_type.ply": (PLY_HEAD.replace("float y", "flaot y") + PLY_FACE,
                     "PLY header line 5 is not a property of a declared element: 'property flaot y'"),
    "truncated.ply": (PLY_HEAD.replace("ascii", "binary_little_endian") + PLY_FACE.split("end_header")[0] + "end_header\n",
                      "PLY data does not match its header (PLY is unexpected length!)"),
}


@pytest.mark.filterwarnings("error")  # no warning may leak before the error line
@pytest.mark.parametrize("file_name", sorted(BAD_INPUTS))
def test_bad_input_gives_one_line_mesh_error(tmp_path, file_name):
    content, expected = BAD_INPUTS[file_name]
    path = tmp_path / file_name
    if content is not None:
        _write(path, content)
    with pytest.raises(MeshError) as info:
        read_mesh_arrays(path)
    assert str(info.value) == f"{path}: {expected}"


def test_stl_reading_does_not_depend_on_trimeshs_optional_encoding_detector(tmp_path, monkeypatch):
    """trimesh guesses non-UTF-8 text with charset_normalizer, an optional dependency; without it a
    Latin-1 ASCII STL still loads (decoded here, never "unreadable (No module named
    'charset_normalizer')")."""
    monkeypatch.setitem(sys.modules, "charset_normalizer", None)  # import fails, as where it is absent
    vertices, faces = read_mesh_arrays(_write(tmp_path / "latin1.stl", ASCII_STL))
    np.testing.assert_array_equal(vertices, [[0, 0, 0], [0, 1, 0], [1, 0, 0]])  # welded: sorted unique
    np.testing.assert_array_equal(vertices[faces], [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]])
    with pytest.raises(MeshError, match="not an STL file: binary header claims"):
        read_mesh_arrays(_write(tmp_path / "garbage.stl", bytes(range(256)) * 8))


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("exponent", [-1000, 1000])
def test_a_mesh_at_2_to_the_1000_or_its_inverse_loads_like_the_same_mesh_at_1(tmp_path, exponent):
    """Degeneracy is judged in the canonical frame: a tetrahedron scaled by 2^-1000 (~1e-301) is not
    refused as "total surface area is zero", one at 2^1000 (~1e301) does not warn "overflow". Scaling
    by a power of two is exact, so both load to exactly the unit tetrahedron's canonical arrays."""
    tet = np.array([[0, 0, 0], [4, 0, 0], [0, 2, 0], [0, 0, 1]], dtype=float)
    text = "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    def obj(vertices):  # repr: the exact float64 values
        return "".join("v " + " ".join(repr(float(x)) for x in p) + "\n" for p in vertices) + text

    unit = load_shape(_write(tmp_path / "unit.obj", obj(tet)))
    shape = load_shape(_write(tmp_path / "scaled.obj", obj(tet * 2.0**exponent)))
    np.testing.assert_array_equal(shape.vertices, unit.vertices)
    np.testing.assert_array_equal(shape.faces, unit.faces)


@pytest.mark.filterwarnings("error")
def test_a_box_beyond_float64_is_one_line_not_an_overflow_warning(tmp_path):
    path = _write(tmp_path / "huge.obj", "v -1e308 0 0\nv 1e308 0 0\nv 0 1e308 0\nf 1 2 3\n")
    with pytest.raises(MeshError) as info:
        load_shape(path)
    assert str(info.value) == f"{path}: bounding box (largest side inf) cannot be normalised in float64"


def test_read_mesh_file_checks_the_file_not_the_content(tmp_path):
    """A prediction is data: read_mesh_file returns what the file holds (NaN, out-of-range indices,
    no faces, nothing); read_mesh_arrays refuses the same content."""
    cases = {
        "nan.obj": ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", (3, 1)),
        "badindex.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", (3, 1)),
        "points.off": ("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", (3, 0)),
        "points.ply": (PLY_HEAD + "end_header\n0 0 0\n1 0 0\n0 1 0\n", (3, 0)),
    }
    for name, (content, (n_vertices, n_faces)) in cases.items():
        vertices, faces = read_mesh_file(_write(tmp_path / name, content))
        assert vertices.shape == (n_vertices, 3) and faces.shape == (n_faces, 3), name
        with pytest.raises(MeshError):
            read_mesh_arrays(tmp_path / name)
    # an empty mesh as trimesh writes it (PLY with 0 vertices and 0 faces)
    save_mesh(tmp_path / "empty.ply", np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    vertices, faces = read_mesh_file(tmp_path / "empty.ply")
    assert vertices.shape == (0, 3) and faces.shape == (0, 3)
    # the file itself is still checked
    with pytest.raises(MeshError, match="PLY vertex element lacks property 'y'"):
        read_mesh_file(_write(tmp_path / "no_y.ply", PLY_HEAD.replace("property float y\n", "") + PLY_FACE))


def test_directory_is_not_a_mesh(tmp_path):
    (tmp_path / "folder.obj").mkdir()
    with pytest.raises(MeshError, match="is a directory"):
        load_shape(tmp_path / "folder.obj")


# -- OBJ / OFF parsing, hand-checked -------------------------------------------------------------


def test_quad_obj_is_fan_triangulated(tmp_path):
    path = _write(tmp_path / "quad.obj", "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\nf 1 2 3 4\n")
    vertices, faces = read_mesh_arrays(path)
    np.testing.assert_array_equal(faces, [[0, 1, 2], [0, 2, 3]])
    assert len(vertices) == 4
    shape = load_shape(path)
    np.testing.assert_allclose(shape.vertices[2], [0.995, 0.4975, 0.0])  # centre (1, .5, 0), scale 1.99/2


def test_obj_groups_share_vertices_and_indices_resolve(tmp_path):
    text = """# two objects, two materials, texture/normal indices and a negative index
o a
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vn 0 0 1
usemtl m1
f 1/1/1 2/1/1 3/1/1
o b
v 0 0 1   # trailing comment
v 1 0 1
usemtl m2
f 1//1 3//1 4//1
f -2 -1 3
"""
    vertices, faces = read_mesh_arrays(_write(tmp_path / "groups.obj", text))
    assert len(vertices) == 6  # trimesh would split the groups into 12 vertices
    np.testing.assert_array_equal(faces, [[0, 1, 2], [0, 2, 3], [4, 5, 2]])
    np.testing.assert_array_equal(vertices[4], [0, 0, 1])


OFF_VARIANTS = {
    "plain": "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n",
    "counts on header line": "OFF 4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
    "counts glued (ModelNet)": "OFF4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
    "lower case, comments, CRLF, tabs": "off\r\n# made by hand\r\n4 1 0\r\n0 0 0 # origin\r\n1\t0 0\r\n\r\n1 1 0\r\n0 1 0\r\n4 0 1 2 3",
    "COFF colours": "COFF\n4 2 0\n0 0 0 255 0 0 255\n1 0 0 255 0 0 255\n1 1 0 0 0 0 255\n0 1 0 0 0 0 255\n3 0 1 2 9 9 9\n3 0 2 3 9 9 9\n",
    "NOFF normals": "NOFF\n4 1 0\n0 0 0 0 0 1\n1 0 0 0 0 1\n1 1 0 0 0 1\n0 1 0 0 0 1\n4 0 1 2 3\n",
    "counts spread": "OFF\n4\n1\n0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
}


@pytest.mark.parametrize("variant", sorted(OFF_VARIANTS))
def test_off_quirks(variant):
    vertices, faces = parse_off(OFF_VARIANTS[variant])
    np.testing.assert_array_equal(vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(faces, [[0, 1, 2], [0, 2, 3]])


def test_gltf_scene_becomes_one_mesh_with_node_transforms(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(extents=(2, 2, 2)), node_name="a")
    scene.add_geometry(trimesh.creation.box(extents=(2, 2, 2)), node_name="b",
                       transform=trimesh.transformations.translation_matrix([10, 0, 0]))
    path = tmp_path / "scene.glb"
    scene.export(path)
    vertices, faces = read_mesh_arrays(path)
    assert (len(vertices), len(faces)) == (16, 24)
    np.testing.assert_allclose(vertices.min(0), [-1, -1, -1])
    np.testing.assert_allclose(vertices.max(0), [11, 1, 1])


# -- frame, topology, round trip --------------------------------------------------------------------


def test_normalize_shape_hand_worked():
    vertices = np.array([[0, 0, 0], [4, 0, 0], [0, 2, 0], [0, 0, 1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    shape = normalize_shape("tet", vertices, faces)
    assert shape.transform.centre == (2.0, 1.0, 0.5) and shape.transform.scale == pytest.approx(1.99 / 4)
    np.testing.assert_allclose(shape.vertices[1], [0.995, -0.4975, -0.24875])
    composed = shape.transform.then(Normalization((0.5, 0.0, 0.0), 2.0))
    np.testing.assert_allclose(composed.apply(vertices), (shape.vertices - [0.5, 0, 0]) * 2.0)
    assert classify_topology(faces) == "closed"
    assert classify_topology(faces[:3]) == "open"
    assert classify_topology(np.vstack([faces, [[0, 1, 2]]])) == "nonmanifold"  # edge 0-1 in three faces


def test_save_and_load_round_trip(tmp_path):
    box = trimesh.creation.box(extents=(1, 2, 3))
    path = tmp_path / "sub" / "box.ply"
    save_mesh(path, box.vertices, box.faces)
    vertices, faces = read_mesh_arrays(path)
    np.testing.assert_allclose(vertices, box.vertices)
    np.testing.assert_array_equal(faces, box.faces)
