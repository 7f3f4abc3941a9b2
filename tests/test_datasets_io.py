"""datasets/io.py: reading, validation and the canonical frame."""

from __future__ import annotations

import re
import sys
import warnings

import numpy as np
import pytest
import trimesh

from hypothesis import given
from hypothesis import strategies as st

from tests.conftest import SHARED_DATA, shared_meshes
from tests.loader_fuzz import COUNTS, FLOATS, loads_or_refuses, mutated, truncations
from datasets.formats import parse_off
from datasets.io import (
    MESH_EXTENSIONS,
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
                      "PLY data does not match its header (it declares 3 vertex, 1 face: at least 37 bytes of "
                      "binary data; the file holds 0)"),
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


# -- property-based: any bytes give a mesh or one MeshError line (issue 41, item 2) ------------------
# tests/loader_fuzz.py: the contract each call is held to and the strategies; the example counts are
# the Hypothesis profile's (tests/conftest.py).

TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def mesh_files(vertices, faces) -> dict[str, tuple[str, bytes]]:
    """format -> (extension, the bytes of that file) of one mesh, in every format the loaders read."""
    mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
    rows = [" ".join(map(repr, map(float, v))) for v in vertices]  # repr: the exact float64 values
    off = (f"OFF\n{len(vertices)} {len(faces)} 0\n" + "".join(r + "\n" for r in rows)
           + "".join("3 " + " ".join(map(str, f)) + "\n" for f in faces))
    obj = "".join(f"v {r}\n" for r in rows) + "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in faces)
    return {"obj": (".obj", obj.encode()), "off": (".off", off.encode()),
            "ply_ascii": (".ply", mesh.export(file_type="ply", encoding="ascii")),
            "ply_binary": (".ply", mesh.export(file_type="ply")),
            "stl_binary": (".stl", mesh.export(file_type="stl")),
            "stl_ascii": (".stl", mesh.export(file_type="stl_ascii").encode()),
            "glb": (".glb", mesh.export(file_type="glb"))}


VALID_MESHES = mesh_files(TETRA_V, TETRA_F)
#: The header numbers of each format that a count mutation replaces, and the coordinates a number
#: mutation replaces.
MESH_COUNTS = [(b"4 4 0", b"%d 4 0"), (b"4 4 0", b"4 %d 0"), (b"element vertex 4", b"element vertex %d"),
               (b"element face 4", b"element face %d"), (b'"count":4', b'"count":%d'), (b'"count":12', b'"count":%d')]
MESH_NUMBERS = [b"1.0", b"1.00000000", b"0.0", b"0.00000000", b"1.0000000e+00", b"0.0000000e+00"]
#: Formats whose header states how much data follows: a truncated file is refused or loads whole.
COUNTED = ["off", "ply_ascii", "ply_binary", "stl_binary", "stl_ascii", "glb"]


def _assert_canonical(shape):
    """A loaded shape is usable: finite float64 vertices, those of its faces in the canonical box
    (a vertex no face uses may lie outside), at least one int64 triangle indexing them."""
    v, f = shape.vertices, shape.faces
    assert v.dtype == np.float64 and v.ndim == 2 and v.shape[1] == 3 and np.isfinite(v).all()
    assert f.dtype == np.int64 and f.ndim == 2 and f.shape[1] == 3 and len(f) > 0
    assert f.min() >= 0 and f.max() < len(v)
    assert np.abs(v[np.unique(f)]).max() <= 0.995 + 1e-9


def _load_as(folder, extension: str, data: bytes):
    path = folder / f"fuzzed{extension}"
    path.write_bytes(data)
    shape = loads_or_refuses(load_shape, path, MeshError)
    if shape is not None:
        _assert_canonical(shape)
    return shape


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    load_shape(_write(tmp_path_factory.mktemp("warm") / "t.glb", VALID_MESHES["glb"][1]))  # imports before timing
    return tmp_path_factory.mktemp("fuzz")


MAGIC = st.sampled_from([b"", b"ply\nformat ascii 1.0\n", b"ply\nformat binary_little_endian 1.0\n", b"OFF\n",
                         b"v ", b"solid x\n", b"glTF\x02\x00\x00\x00", b"\x00" * 80])


@given(extension=st.sampled_from(MESH_EXTENSIONS), data=st.tuples(MAGIC, st.binary(max_size=600)).map(b"".join))
def test_any_bytes_give_a_mesh_or_one_mesh_error_line(fuzz_dir, extension, data):
    """Random bytes, alone or after the start of a header, under every mesh extension."""
    _load_as(fuzz_dir, extension, data)


@pytest.mark.parametrize("fmt", sorted(VALID_MESHES))
@given(data=st.data())
def test_a_damaged_mesh_file_gives_a_mesh_or_one_mesh_error_line(fuzz_dir, fmt, data):
    """A valid file truncated, with bytes flipped, inserted or deleted, a count or a number changed."""
    _load_as(fuzz_dir, VALID_MESHES[fmt][0], data.draw(mutated(VALID_MESHES[fmt][1], MESH_COUNTS, MESH_NUMBERS)))


@pytest.mark.parametrize("fmt", COUNTED)
@given(data=st.data())
def test_a_truncated_mesh_file_is_refused_or_read_whole(fuzz_dir, fmt, data):
    """A format that states its counts (or, ASCII STL, its end) never loads part of a cut file:
    the cut is refused, or it only removed what held no data (the last digits of a number aside)."""
    extension, valid = VALID_MESHES[fmt]
    path = fuzz_dir / f"cut{extension}"
    path.write_bytes(data.draw(truncations(valid)))
    arrays = loads_or_refuses(read_mesh_file, path, MeshError)
    if arrays is not None:
        assert arrays[0].shape == TETRA_V.shape and arrays[1].shape == TETRA_F.shape


@pytest.mark.parametrize("fmt, old, new", [
    ("ply_ascii", b"element vertex 4", b"element vertex %d"), ("ply_ascii", b"element face 4", b"element face %d"),
    ("ply_binary", b"element vertex 4", b"element vertex %d"), ("ply_binary", b"element face 4", b"element face %d"),
    ("off", b"4 4 0", b"%d 4 0"), ("off", b"4 4 0", b"4 %d 0"), ("glb", b'"count":4', b'"count":%d'),
    ("stl_binary", b"\x04\x00\x00\x00", None)])
@given(count=COUNTS)
def test_a_header_count_the_data_does_not_hold_is_refused_before_allocating(fuzz_dir, fmt, old, new, count):
    """A count in a header (up to 10^20) is checked against the data before arrays are allocated
    (the load's traced peak stays under 64 MiB): more than the file holds is refused, the true
    count loads, fewer may load fewer elements where a format allows data beyond them (OFF, glTF)."""
    extension, valid = VALID_MESHES[fmt]
    if new is None:  # binary STL: the little-endian triangle count at bytes 80-83
        count %= 2**32
        data = valid[:80] + count.to_bytes(4, "little") + valid[84:]
    else:
        data = valid.replace(old, new % count, 1)
    path = fuzz_dir / f"counted{extension}"
    path.write_bytes(data)
    arrays = loads_or_refuses(read_mesh_file, path, MeshError, trace_memory=True)
    if count > 4:
        assert arrays is None
    elif count == 4:
        assert arrays is not None and arrays[0].shape == (4, 3) and arrays[1].shape == (4, 3)


@given(fmt=st.sampled_from(sorted(VALID_MESHES)), coordinates=st.lists(FLOATS, min_size=12, max_size=12))
def test_nan_inf_and_extreme_coordinates_give_a_mesh_or_one_mesh_error_line(fuzz_dir, fmt, coordinates):
    """Any float64 coordinates (NaN, inf, 1e308, denormals, -0.0) in any format: a valid canonical
    shape, or one line (NaN/inf vertices, a box beyond float64, a degenerate mesh)."""
    vertices = np.array(coordinates).reshape(4, 3)
    with np.errstate(all="ignore"), warnings.catch_warnings():  # trimesh's export of inf and 1e308 warns
        warnings.simplefilter("ignore")
        if fmt in ("ply_ascii", "ply_binary", "stl_binary", "stl_ascii", "glb"):
            vertices = vertices.astype(np.float32)  # what those files store
        extension, data = mesh_files(vertices, TETRA_F)[fmt]
    shape = _load_as(fuzz_dir, extension, data)
    if shape is not None:
        assert np.isfinite(vertices).all()


#: Text a comment may hold: letters, digits, punctuation, symbols and spaces of any script.
COMMENTS = st.text(st.characters(categories=["L", "N", "P", "S", "Zs"]), max_size=20)


@given(fmt=st.sampled_from(["obj", "off", "ply_ascii"]), comment=COMMENTS,
       encoding=st.sampled_from(["utf-8", "latin-1", "cp1252", "utf-16", "utf-8-sig"]))
def test_a_comment_in_any_encoding_loads_the_same_mesh_or_one_line(fuzz_dir, fmt, comment, encoding):
    """A comment (OBJ/OFF '#', PLY 'comment') in any encoding: an ASCII-compatible one (UTF-8,
    Latin-1, cp1252) loads exactly the mesh without it; the others are refused in one line."""
    extension, valid = VALID_MESHES[fmt]
    text = valid.decode("ascii")
    if fmt == "obj":
        text = f"# {comment}\n" + text
    elif fmt == "off":
        text = text.replace("\n", f"  # {comment}\n", 1)
    else:
        text = text.replace("format ascii 1.0\n", f"format ascii 1.0\ncomment {comment}\n", 1)
    path = fuzz_dir / f"encoded{extension}"
    path.write_bytes(text.encode(encoding, errors="replace"))
    arrays = loads_or_refuses(read_mesh_file, path, MeshError)
    if encoding in ("utf-8", "latin-1", "cp1252"):
        assert arrays is not None
        path.write_bytes(valid)
        for got, want in zip(arrays, read_mesh_file(path)):
            np.testing.assert_array_equal(got, want)
