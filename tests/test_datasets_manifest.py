"""datasets/manifest.py (SHA-256 manifests) and the checked ABC datasets: the ``manifest`` option of
``abc`` / ``abc-nonmanifold`` and the SALS paper's named test sets ``sals-abc50`` and
``sals-nonmanifold50`` (committed lists and manifest in lists/). The checks on the real parts read
../shared/data/abc-ppsurf and skip, with a reason, where it is absent."""

from __future__ import annotations

import csv
import hashlib
import re
import warnings

import numpy as np
import pytest

from datasets import DatasetError, DatasetNotFoundError, MissingShapesWarning, get_dataset, save_mesh
from datasets.abc import (SALS_ABC_LIST, SALS_ABC_MANIFEST, SALS_NONMANIFOLD_LIST, default_ppsurf_dir,
                          read_list_file)
from datasets.manifest import check_file, file_sha256, read_manifest, verify_manifest
from tests.conftest import REPO, SHARED_DATA

PPSURF_DIR = SHARED_DATA / "abc-ppsurf"
needs_ppsurf = pytest.mark.skipif(not PPSURF_DIR.is_dir(), reason=f"{PPSURF_DIR} is absent: the SALS paper's parts "
                                  "are read from it (the 104 raw ABC parts of cg-tuwien/ppsurf_modeling)")
STEM = re.compile(r"^\d{8}_[0-9a-f]{8,}_trimesh_\d{3}$")


def tetra(size=1.0):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * size
    return vertices, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def write_manifest(folder, names, path):
    """A manifest of ``folder``'s files ``names`` as they are now (sha256sum's format)."""
    path.write_text("".join(f"{hashlib.sha256((folder / n).read_bytes()).hexdigest()}  {n}\n" for n in names))
    return path


def flip_one_byte(path, offset=-1):
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


@pytest.fixture
def parts(tmp_path):
    """Three ABC-named parts, a list of them and a manifest pinning them as written."""
    folder = tmp_path / "parts"
    names = [f"0000000{i}_{'ab' * 12}_trimesh_00{i}" for i in (1, 2, 3)]
    for i, name in enumerate(names, start=1):
        save_mesh(folder / f"{name}.ply", *tetra(float(i)))
    (tmp_path / "list.txt").write_text("\n".join(names) + "\n")
    manifest = write_manifest(folder, [f"{n}.ply" for n in names], tmp_path / "parts.sha256")
    return folder, names, tmp_path / "list.txt", manifest


# -- the manifest format and the one file check --------------------------------------------------


def test_file_sha256_is_hashlib_of_the_bytes(tmp_path):
    path = tmp_path / "x.bin"
    path.write_bytes(bytes(range(256)) * 5000)  # over one read chunk
    assert file_sha256(path) == hashlib.sha256(path.read_bytes()).hexdigest()


def test_read_manifest_reads_sha256sum_lines_and_refuses_a_bad_line_naming_it(tmp_path):
    digest = "ab" * 32
    path = tmp_path / "m.sha256"
    path.write_text(f"# pinned parts\n\n{digest}  a.stl\n{digest.upper()} *sub/b c.stl\n")
    assert read_manifest(path) == {"a.stl": digest, "sub/b c.stl": digest}  # binary-mode '*', spaces in names
    path.write_text(f"{digest}  a.stl\n{digest[:-1]}  b.stl\n")
    with pytest.raises(DatasetError, match=r"m\.sha256: line 2 is not") as info:
        read_manifest(path)
    assert "\n" not in str(info.value)
    path.write_text(f"{digest}  a.stl\n{digest}  a.stl\n")
    with pytest.raises(DatasetError, match="line 2 pins a.stl a second time"):
        read_manifest(path)
    with pytest.raises(DatasetNotFoundError, match="absent.sha256"):
        read_manifest(tmp_path / "absent.sha256")


def test_one_altered_byte_is_named_and_a_missing_file_is_one_line(parts):
    folder, names, _, manifest = parts
    assert verify_manifest(folder, manifest) == []
    flip_one_byte(folder / f"{names[1]}.ply")
    (folder / f"{names[2]}.ply").unlink()
    problems = verify_manifest(folder, manifest)
    assert len(problems) == 2 and all("\n" not in p for p in problems)
    assert problems[0].startswith(f"{folder / names[1]}.ply: SHA-256 ") and "differs from the pinned" in problems[0]
    assert problems[1] == f"{folder / names[2]}.ply: missing (pinned by parts.sha256)"
    assert check_file(folder / f"{names[0]}.ply", None, "parts.sha256").endswith(": not pinned by parts.sha256")


# -- the manifest option of the ABC datasets -----------------------------------------------------


def test_abc_with_a_manifest_leaves_out_an_altered_file_with_one_line_and_loads_the_rest(parts):
    folder, names, list_file, manifest = parts
    flip_one_byte(folder / f"{names[0]}.ply")
    with pytest.warns(MissingShapesWarning) as caught:
        ds = get_dataset("abc", data_dir=folder, list_file=list_file, manifest=manifest)
    assert len(caught) == 1
    (line,) = [str(w.message) for w in caught]
    assert f"{names[0]}.ply: SHA-256" in line and "left out: 1 shape(s)" in line and "\n" not in line
    assert ds.names() == names[1:] and ds.missing == [names[0]]
    assert [len(ds.load(n).faces) for n in ds.names()] == [4, 4]
    assert ds.describe()["options"]["manifest"] == str(manifest)
    with pytest.raises(DatasetError, match=f"{names[0]}.ply: SHA-256"):
        get_dataset("abc", data_dir=folder, list_file=list_file, manifest=manifest, strict=True)


def test_abc_with_a_manifest_a_missing_file_is_one_line_and_an_unpinned_one_is_left_out(parts):
    folder, names, list_file, manifest = parts
    (folder / f"{names[2]}.ply").unlink()
    save_mesh(folder / f"{names[2]}.obj", *tetra())  # same stem, a file the manifest does not pin
    with pytest.warns(MissingShapesWarning) as caught:
        ds = get_dataset("abc", data_dir=folder, list_file=list_file, manifest=manifest)
    assert [str(w.message).split("; ")[0].split(": ", 1)[1] for w in caught] == \
        [f"{folder / names[2]}.obj: not pinned by parts.sha256"]
    assert ds.names() == names[:2]
    (folder / f"{names[2]}.obj").unlink()
    with pytest.warns(MissingShapesWarning) as caught:  # no file at all: the list's one missing line
        ds = get_dataset("abc", data_dir=folder, list_file=list_file, manifest=manifest)
    assert len(caught) == 1 and f"1 of 3 lines of {list_file} do not name a mesh" in str(caught[0].message)
    assert ds.names() == names[:2] and ds.missing == [names[2]]


def test_nonmanifold_with_a_manifest_names_the_bad_part_once_and_keeps_the_other_pairs(parts, tmp_path):
    folder, names, _, manifest = parts
    pairs = tmp_path / "pairs.txt"
    pairs.write_text(f"{names[0]}+{names[1]}\n{names[0]}+{names[2]}\n{names[1]}+{names[2]}\n")
    flip_one_byte(folder / f"{names[0]}.ply")
    with pytest.warns(MissingShapesWarning) as caught:
        ds = get_dataset("abc-nonmanifold", data_dir=folder, list_file=pairs, manifest=manifest)
    assert len(caught) == 1 and f"{names[0]}.ply: SHA-256" in str(caught[0].message)
    assert "left out: 2 shape(s)" in str(caught[0].message)
    assert ds.names() == [f"{names[1]}+{names[2]}"]
    assert len(ds.load(ds.names()[0]).faces) == 8


# -- the SALS paper's named test sets -------------------------------------------------------------


def test_committed_sals_lists_and_manifest_agree():
    stems = read_list_file(SALS_ABC_LIST)
    assert len(stems) == 50 == len(set(stems)) and all(STEM.match(s) for s in stems)
    pairs = read_list_file(SALS_NONMANIFOLD_LIST)
    assert len(pairs) == 50 and all(line.count("+") == 1 for line in pairs)
    assert {p for line in pairs for p in line.split("+")} <= set(stems)  # 41 of the 50 parts
    assert list(read_manifest(SALS_ABC_MANIFEST)) == [f"{s}.stl" for s in stems]  # list order, one pin each


def test_the_manifest_agrees_with_the_abc_unseen_pins_of_the_same_files():
    with open(REPO / "lists" / "abc-unseen.csv", newline="") as f:
        unseen = {row["file"]: row["sha256"] for row in csv.DictReader(f)}
    pins = read_manifest(SALS_ABC_MANIFEST)
    shared = sorted(set(pins) & set(unseen))
    assert len(shared) == 45  # the other 5 parts are the ids of ../shared/data/abc (docs/ABC-UNSEEN.md)
    assert [n for n in shared if pins[n] != unseen[n]] == []


def test_the_named_sets_take_no_list_or_manifest_and_name_an_absent_folder(tmp_path, monkeypatch):
    with pytest.raises(DatasetError, match="has no option 'list_file'"):
        get_dataset("sals-abc50", list_file=SALS_ABC_LIST)
    monkeypatch.setenv("SALSBENCH_SHARED_DATA", str(tmp_path / "nowhere"))
    assert default_ppsurf_dir() == tmp_path / "nowhere" / "abc-ppsurf"
    for name in ("sals-abc50", "sals-nonmanifold50"):
        with pytest.raises(DatasetNotFoundError, match="nowhere/abc-ppsurf does not exist"):
            get_dataset(name)


@needs_ppsurf
def test_the_committed_manifest_matches_the_shared_parts():
    assert verify_manifest(PPSURF_DIR, SALS_ABC_MANIFEST) == []


@needs_ppsurf
def test_the_shared_lists_are_the_committed_ones():
    shared_lists = SHARED_DATA / "lists"
    if not shared_lists.is_dir():
        pytest.skip(f"{shared_lists} is absent")
    assert read_list_file(shared_lists / "sals_abc_list.txt") == read_list_file(SALS_ABC_LIST)
    assert read_list_file(shared_lists / "sals_non_manifold_abc_list.txt") == read_list_file(SALS_NONMANIFOLD_LIST)


@needs_ppsurf
def test_sals_sets_run_all_fifty_from_the_shared_folder():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a missing or altered part would warn
        parts, pairs = get_dataset("sals-abc50"), get_dataset("sals-nonmanifold50")
    assert parts.names() == read_list_file(SALS_ABC_LIST) and parts.missing == []
    assert pairs.names() == read_list_file(SALS_NONMANIFOLD_LIST) and pairs.missing == []
    assert parts.describe()["options"]["data_dir"] == str(PPSURF_DIR)
    shape = parts.load(parts.names()[0])
    assert np.isclose(np.ptp(shape.vertices, axis=0).max(), 1.99)  # the canonical frame


@needs_ppsurf
def test_sals_abc50_with_an_altered_and_a_missing_part_runs_the_other_48(tmp_path):
    stems = read_list_file(SALS_ABC_LIST)
    for stem in stems[2:]:
        (tmp_path / f"{stem}.stl").symlink_to(PPSURF_DIR / f"{stem}.stl")
    altered = tmp_path / f"{stems[0]}.stl"
    altered.write_bytes((PPSURF_DIR / f"{stems[0]}.stl").read_bytes())
    flip_one_byte(altered, offset=100)  # one byte of the STL header's first triangle
    with pytest.warns(MissingShapesWarning) as caught:
        ds = get_dataset("sals-abc50", data_dir=tmp_path)
    lines = sorted(str(w.message) for w in caught)
    assert len(lines) == 2 and all("\n" not in line for line in lines)
    assert f"{stems[0]}.stl: SHA-256" in lines[0]  # the altered file, named
    assert f"1 of 50 lines of {SALS_ABC_LIST}" in lines[1] and stems[1] in lines[1]  # the missing one, named
    assert ds.names() == stems[2:] and sorted(ds.missing) == sorted(stems[:2])


def test_shape_bytes_digest_is_the_files_sha256_or_the_generated_arrays_hash(tmp_path):
    from datasets.manifest import shape_bytes_digest

    V, F = tetra()
    save_mesh(tmp_path / "a.ply", V, F)
    folder = get_dataset("meshes", data_dir=tmp_path)
    assert shape_bytes_digest(folder, "a") == hashlib.sha256((tmp_path / "a.ply").read_bytes()).hexdigest()
    builtin = get_dataset("builtin")
    name = builtin.names()[0]
    assert shape_bytes_digest(builtin, name) == "generated:" + builtin.load(name).content_hash
