"""datasets/abc.py and the registry: folders of meshes, ABC lists, non-manifold pairs."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from datasets import (
    Dataset,
    DatasetError,
    DatasetNotFoundError,
    MeshError,
    MissingShapesWarning,
    available_datasets,
    get_dataset,
    load_shape,
    save_mesh,
)
from datasets.abc import compose_soup, match_list_entry, read_list_file
from datasets.registry import DATASETS, available_datasets
from tests.conftest import SHARED_DATA, requires_shared
from tests.loader_fuzz import loads_or_refuses

SALS_LIST = SHARED_DATA / "lists" / "sals_abc_list.txt"
SALS_NONMANIFOLD_LIST = SHARED_DATA / "lists" / "sals_non_manifold_abc_list.txt"
SALS_PRESENT = {
    "00993706_f8bc5c196ab9685d0182bbed_trimesh_001",
    "00010218_4769314c71814669ba5d3512_trimesh_013",
    "00019203_1bcd132f82c84761b4e9851d_trimesh_001",
    "00992294_c5390f6bb4e80a940dae7c15_trimesh_000",
    "00014489_f4297f01e3434034b7051ebb_trimesh_004",
}

HASH_A, HASH_B = "1ffb81a71e5b402e966b9341", "d4fe04f0f5f84b52bd4f10e4"


def tetra(size=1.0, shift=(0.0, 0.0, 0.0)):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * size + shift
    return vertices, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


@pytest.fixture
def abc_dir(tmp_path):
    """A small ABC-like folder: model folders (raw ABC layout), a stem without _trimesh_NNN, a bad file."""
    root = tmp_path / "abc"
    save_mesh(root / "00000001" / f"00000001_{HASH_A}_trimesh_000.ply", *tetra(1.0))
    save_mesh(root / "00000001" / f"00000001_{HASH_A}_trimesh_001.obj", *tetra(2.0))
    save_mesh(root / "00000002" / f"00000002_{HASH_B}.stl", *tetra(3.0))
    save_mesh(root / f"00000003_{HASH_B}_trimesh_004.off", *tetra(4.0))
    (root / ".hidden").mkdir()
    save_mesh(root / ".hidden" / "00000009_ffffffffffffffffffffffff.ply", *tetra())
    (root / f"00000004_{HASH_A}_trimesh_000.obj").write_bytes(b"\x00\x01garbage")
    return root


# -- list files and matching ---------------------------------------------------------------------


def test_read_list_file(tmp_path):
    path = tmp_path / "list.txt"
    path.write_text("# header comment\n\n  a_1  \nb_2 # trailing\na_1\n\t\n#c\nc_3")
    assert read_list_file(path) == ["a_1", "b_2", "c_3"]
    with pytest.raises(DatasetNotFoundError, match="list file"):
        read_list_file(tmp_path / "nope.txt")


def test_match_list_entry_rules():
    index = {stem: Path(stem + ".ply") for stem in sorted([
        f"00000001_{HASH_A}_trimesh_000", f"00000001_{HASH_A}_trimesh_001", f"00000002_{HASH_B}", "00000006_0"])}
    exact = f"00000001_{HASH_A}_trimesh_001"
    assert match_list_entry(exact, index).stem == exact
    # entry with a part number, file stored under the model name only
    assert match_list_entry(f"00000002_{HASH_B}_trimesh_007", index).stem == f"00000002_{HASH_B}"
    # prefix-only entries (id + hash, or the id alone): first part in sorted order
    assert match_list_entry(f"00000001_{HASH_A}", index).stem == f"00000001_{HASH_A}_trimesh_000"
    assert match_list_entry("00000001", index).stem == f"00000001_{HASH_A}_trimesh_000"
    # another part of the same model, or a stem without the hash, is not a match
    assert match_list_entry(f"00000001_{HASH_A}_trimesh_002", index) is None
    assert match_list_entry(f"00000006_{HASH_B}_trimesh_001", index) is None
    assert match_list_entry("00000007", index) is None


def test_abc_folder_without_list(abc_dir):
    ds = get_dataset("abc", data_dir=abc_dir)
    assert ds.names() == sorted([f"00000001_{HASH_A}_trimesh_000", f"00000001_{HASH_A}_trimesh_001",
                                 f"00000002_{HASH_B}", f"00000003_{HASH_B}_trimesh_004", f"00000004_{HASH_A}_trimesh_000"])
    assert len(get_dataset("abc", data_dir=abc_dir, recursive=False)) == 2
    # names() opened no file; the bad one fails alone, with its file named
    results = dict(ds.iter_safe())
    assert isinstance(results[f"00000004_{HASH_A}_trimesh_000"], MeshError)
    assert "binary data" in str(results[f"00000004_{HASH_A}_trimesh_000"])
    good = [s for s in results.values() if not isinstance(s, MeshError)]
    assert len(good) == 4 and all(s.kind == "closed" for s in good)
    with pytest.raises(MeshError):
        list(ds)  # plain iteration stops at the bad shape


def test_abc_list_filter_missing_and_strict(abc_dir, tmp_path):
    listing = tmp_path / "list.txt"
    listing.write_text(f"# test list\n00000003_{HASH_B}_trimesh_004\n00000002_{HASH_B}_trimesh_000\n"
                       f"00000001_{HASH_A}\n00000005_{HASH_A}_trimesh_000\n")
    with pytest.warns(MissingShapesWarning, match="1 of 4 lines"):
        ds = get_dataset("abc", data_dir=abc_dir, list_file=listing)
    assert ds.names() == [f"00000003_{HASH_B}_trimesh_004", f"00000002_{HASH_B}_trimesh_000", f"00000001_{HASH_A}"]
    assert ds.missing == [f"00000005_{HASH_A}_trimesh_000"]
    shape = ds.load(f"00000002_{HASH_B}_trimesh_000")  # the STL stored under the model name, welded
    assert shape.name == f"00000002_{HASH_B}_trimesh_000" and len(shape.vertices) == 4
    assert ds.load(f"00000001_{HASH_A}").source.endswith("_trimesh_000.ply")
    record = json.loads(json.dumps(ds.describe()))
    assert record["missing"] == ds.missing and record["count"] == 3
    assert record["files"][f"00000001_{HASH_A}"] == f"00000001/00000001_{HASH_A}_trimesh_000.ply"
    with pytest.raises(DatasetError, match="1 of 4 lines"):
        get_dataset("abc", data_dir=abc_dir, list_file=listing, strict=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert get_dataset("abc", data_dir=abc_dir, list_file=listing, limit=2).names() == ds.names()[:2]


@requires_shared("abc")
def test_sals_list_finds_the_five_present_meshes():
    with pytest.warns(MissingShapesWarning, match="45 of 50"):
        ds = get_dataset("abc", data_dir=SHARED_DATA / "abc", list_file=SALS_LIST)
    assert set(ds.names()) == SALS_PRESENT and len(ds.missing) == 45
    name = "00992294_c5390f6bb4e80a940dae7c15_trimesh_000"
    shape = ds.load(name)
    assert shape.name == name and shape.kind == "closed" and len(shape.faces) == 3464
    assert np.abs(shape.vertices).max() <= 0.995 + 1e-9


@requires_shared("abc")
def test_prefix_only_entry_matches_a_shared_file(tmp_path):
    listing = tmp_path / "prefix.txt"
    listing.write_text("00014489_f4297f01e3434034b7051ebb\n00000006_d4fe04f0f5f84b52bd4f10e4\n")
    ds = get_dataset("abc", data_dir=SHARED_DATA / "abc", list_file=listing)
    assert ds.describe()["files"] == {
        "00014489_f4297f01e3434034b7051ebb": "00014489_f4297f01e3434034b7051ebb_trimesh_004.ply",
        "00000006_d4fe04f0f5f84b52bd4f10e4": "00000006_d4fe04f0f5f84b52bd4f10e4_trimesh_001.stl",
    }


# -- non-manifold pairs --------------------------------------------------------------------------


@requires_shared("abc")
def test_sals_nonmanifold_pair_is_a_soup_of_both_parts():
    with pytest.warns(MissingShapesWarning, match="49 of 50"):
        ds = get_dataset("abc-nonmanifold", data_dir=SHARED_DATA / "abc", list_file=SALS_NONMANIFOLD_LIST)
    a, b = "00993706_f8bc5c196ab9685d0182bbed_trimesh_001", "00014489_f4297f01e3434034b7051ebb_trimesh_004"
    assert ds.names() == [f"{a}+{b}"]
    shape = ds.load(f"{a}+{b}")
    assert shape.name == f"{a}+{b}" and shape.kind == "nonmanifold"
    assert len(shape.faces) == 36196 + 7112 and len(shape.vertices) == 18098 + 3548
    assert np.abs(shape.vertices).max() <= 0.995 + 1e-9
    assert np.ptp(shape.vertices, axis=0).max() == pytest.approx(1.99, abs=1e-12)
    # the first block is part A in its own canonical frame, moved by the renormalisation
    part_a = load_shape(SHARED_DATA / "abc" / f"{a}.ply")
    np.testing.assert_allclose(shape.vertices[:18098], shape.transform.apply(part_a.vertices), atol=1e-12)
    assert [p["faces"] for p in shape.meta["parts"]] == [36196, 7112]


def test_compose_soup_hand_worked():
    from datasets.io import normalize_shape

    small = normalize_shape("a", *tetra(1.0))
    shifted = normalize_shape("b", *tetra(1.0, shift=(5.0, 0.0, 0.0)))
    soup = compose_soup("a+b", [small, shifted])
    # both parts fill [-0.995, 0.995]^3 in their frames: the union box is the same, nothing moves
    np.testing.assert_allclose(soup.vertices, np.vstack([small.vertices, shifted.vertices]), atol=1e-15)
    np.testing.assert_array_equal(soup.faces[4:], shifted.faces + 4)
    assert soup.kind == "nonmanifold" and len(soup.faces) == 8


def test_nonmanifold_without_list_pairs_consecutive_stems(abc_dir):
    ds = get_dataset("abc-nonmanifold", data_dir=abc_dir)
    assert ds.names() == [f"00000001_{HASH_A}_trimesh_000+00000001_{HASH_A}_trimesh_001",
                          f"00000002_{HASH_B}+00000003_{HASH_B}_trimesh_004"]  # the 5th stem is left out
    shape = ds.load(ds.names()[1])
    assert len(shape.faces) == 8 and shape.kind == "nonmanifold"


def test_nonmanifold_list_lines_must_be_pairs(abc_dir, tmp_path):
    listing = tmp_path / "pairs.txt"
    listing.write_text("a+b+c\n")
    with pytest.raises(DatasetError, match="not of the form A\\+B"):
        get_dataset("abc-nonmanifold", data_dir=abc_dir, list_file=listing)


# -- meshes folder and registry --------------------------------------------------------------------


def test_meshes_folder(tmp_path):
    save_mesh(tmp_path / "b.ply", *tetra())
    save_mesh(tmp_path / "a.obj", *tetra())
    save_mesh(tmp_path / "sub" / "a.stl", *tetra())
    vertices, faces = tetra()
    save_mesh(tmp_path / "open.ply", vertices, faces[:3])
    (tmp_path / "notes.txt").write_text("not a mesh")
    ds = get_dataset("meshes", data_dir=tmp_path)
    assert ds.names() == ["a.obj", "b", "open", "sub/a.stl"]
    assert [s.kind for s in ds] == ["closed", "closed", "open", "closed"]
    assert get_dataset("meshes", data_dir=tmp_path, recursive="false").names() == ["a", "b", "open"]
    assert get_dataset("meshes", data_dir=tmp_path, limit=2).names() == ["a.obj", "b"]
    picked = get_dataset("meshes", data_dir=tmp_path, limit=2, seed=3).names()
    assert picked == get_dataset("meshes", data_dir=tmp_path, limit=2, seed=3).names() and len(picked) == 2
    assert get_dataset("meshes", data_dir=tmp_path, kind="nonmanifold").load("b").kind == "nonmanifold"


def test_registry_errors(tmp_path):
    assert sorted(available_datasets()) == ["abc", "abc-nonmanifold", "builtin", "meshes", "pointclouds", "rooms",
                                            "sals-abc50", "sals-nonmanifold50", "street"]
    with pytest.raises(ValueError) as info:
        get_dataset("shapenet")
    assert str(info.value) == ("unknown dataset 'shapenet'; known datasets: builtin, meshes, abc, abc-nonmanifold, "
                               "sals-abc50, sals-nonmanifold50, pointclouds, rooms, street")
    with pytest.raises(DatasetError, match="has no option 'lst_file'"):
        get_dataset("abc", data_dir=tmp_path, lst_file="x")
    with pytest.raises(DatasetNotFoundError) as info:
        get_dataset("abc", data_dir=tmp_path / "absent")
    assert isinstance(info.value, FileNotFoundError) and isinstance(info.value, ValueError)
    assert "\n" not in str(info.value) and "absent" in str(info.value)
    with pytest.raises(DatasetError, match="needs the option data_dir"):
        get_dataset("meshes")
    with pytest.raises(DatasetError, match="no mesh files"):
        get_dataset("meshes", data_dir=tmp_path)
    with pytest.raises(DatasetNotFoundError, match="list file"):
        get_dataset("abc", data_dir=tmp_path, list_file=tmp_path / "absent.txt")


def test_register_a_custom_dataset():
    class OneTetra(Dataset):
        def names(self):
            return ["tet"]

        def load(self, name):
            from datasets.io import normalize_shape

            return normalize_shape(name, *tetra())

    with DATASETS.registered("test-one-tetra", OneTetra):
        OneTetra.name = "test-one-tetra"
        ds = get_dataset("test-one-tetra")
        assert ds.name == "test-one-tetra" and len(ds) == 1
        assert [s.name for s in ds] == ["tet"]
        assert ds.describe() == {"dataset": "test-one-tetra", "options": {}, "count": 1, "names": ["tet"]}
    assert "test-one-tetra" not in available_datasets()
    with pytest.raises(DatasetError, match="unknown dataset 'test-one-tetra'; known datasets: builtin"):
        get_dataset("test-one-tetra")


# -- property-based: any list file gives a dataset or one DatasetError line (issue 41, item 2) -------
# tests/loader_fuzz.py: the contract each call is held to; the example counts are the Hypothesis
# profile's (tests/conftest.py).

ABC_STEMS = [f"00000001_{HASH_A}_trimesh_000", f"00000001_{HASH_A}_trimesh_001", f"00000002_{HASH_B}",
             f"00000003_{HASH_B}_trimesh_004"]
#: One line of a list: a stem of the folder, a prefix of one, a pair, a comment, or any text.
LIST_LINES = st.one_of(
    st.sampled_from(ABC_STEMS + ["00000001", f"00000001_{HASH_A}", f"00000002_{HASH_B}_trimesh_009", "00000005"]),
    st.tuples(st.sampled_from(ABC_STEMS), st.sampled_from(ABC_STEMS)).map("+".join),
    st.text(max_size=30).map(lambda t: "# " + t), st.text(max_size=30))
LIST_TEXT = st.tuples(st.lists(LIST_LINES, max_size=8), st.sampled_from(["\n", "\r\n", "\r", "\n\n"])).map(
    lambda lines_and_end: lines_and_end[1].join(lines_and_end[0]))
LIST_BYTES = st.one_of(
    st.tuples(LIST_TEXT, st.sampled_from(["utf-8", "latin-1", "utf-16", "cp1252"])).map(
        lambda t: t[0].encode(t[1], errors="replace")),
    st.binary(max_size=300))


@pytest.fixture(scope="module")
def list_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("abc")
    for i, stem in enumerate(ABC_STEMS):
        save_mesh(root / f"{stem}.ply", *tetra(1.0 + i))
    return root, tmp_path_factory.mktemp("lists")


@given(data=LIST_BYTES)
def test_any_list_file_gives_its_stripped_entries(list_dir, data):
    """read_list_file reads any bytes: entries stripped, non-empty, without comments, line breaks or
    repeats, in file order."""
    path = list_dir[1] / "list.txt"
    path.write_bytes(data)
    entries = loads_or_refuses(read_list_file, path, DatasetError)
    assert entries is not None and len(set(entries)) == len(entries)
    for entry in entries:
        assert entry and entry == entry.strip() and "#" not in entry and len(entry.splitlines()) == 1


@pytest.mark.parametrize("name", ["abc", "abc-nonmanifold"])
@given(data=LIST_BYTES)
def test_any_list_file_gives_a_dataset_or_one_dataset_error_line(list_dir, name, data):
    """An ABC or non-manifold dataset over any list file: its shapes are entries of the list (each
    loads), its missing entries are one warning line; or one DatasetError line naming the list."""
    folder, lists = list_dir
    path = lists / "list.txt"
    path.write_bytes(data)

    def build(list_file):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always", MissingShapesWarning)
            dataset = get_dataset(name, data_dir=folder, list_file=list_file)
        assert all(issubclass(w.category, MissingShapesWarning) and len(str(w.message).splitlines()) == 1
                   for w in seen)
        return dataset

    dataset = loads_or_refuses(build, path, DatasetError)
    if dataset is not None:
        entries = read_list_file(path)
        assert dataset.names() and set(dataset.names()) <= set(entries)
        assert set(dataset.missing) == set(entries) - set(dataset.names())
        assert dataset.load(dataset.names()[0]).faces.shape[1] == 3
