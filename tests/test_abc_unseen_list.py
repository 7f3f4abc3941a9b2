"""lists/abc-unseen.txt (ABC parts outside NDC's training range), its manifest lists/abc-unseen.csv and
scripts/fetch_abc_unseen.py. The meshes live outside the repository, in ../shared/data/abc-ppsurf (all
104 parts of the source, the 93 of the list among them); the checks that need them skip, with a reason,
when that folder is absent."""

from __future__ import annotations

import hashlib
import re
import warnings

import pytest

from datasets import get_dataset
from datasets.abc import read_list_file
from tests.scripts import load_script
from tests.conftest import REPO, SHARED_DATA

LIST = REPO / "lists" / "abc-unseen.txt"
UNSEEN_DIR = SHARED_DATA / "abc-ppsurf"
OUR_ABC_DIR = SHARED_DATA / "abc"
NDC_TRAINING_IDS = range(2, 7903 + 1)  # ABC objects 00000002-00007903 (docs/PROTOCOL.md, sdf-ndc)
MIN_ENTRIES = 30
MAX_FACES = 50_000
ABC_STEM = re.compile(r"^(\d{8})_[0-9a-f]{8,}_trimesh_\d{3}$")


fetch_script = load_script("fetch_abc_unseen")
ENTRIES = read_list_file(LIST)
ROWS, ROW_PROBLEMS = fetch_script.manifest_rows()


def test_list_parses_with_the_project_reader_and_is_long_enough():
    assert len(ENTRIES) >= MIN_ENTRIES
    assert all(ABC_STEM.match(e) for e in ENTRIES), [e for e in ENTRIES if not ABC_STEM.match(e)]
    assert ENTRIES == sorted(ENTRIES)
    assert LIST.read_text().startswith("#")  # the header states the rule and the source


def test_no_id_in_ndc_training_range():
    assert [e for e in ENTRIES if int(e[:8]) in NDC_TRAINING_IDS] == []


def test_ids_are_unique():
    ids = [e[:8] for e in ENTRIES]
    assert len(ids) == len(set(ids))


def test_no_id_among_our_abc_parts():
    if not OUR_ABC_DIR.is_dir():
        pytest.skip(f"{OUR_ABC_DIR} is absent: the ids of our ABC parts are read from it")
    ours = {p.name[:8] for p in OUR_ABC_DIR.iterdir() if re.match(r"\d{8}", p.name)}
    assert ours, f"no ABC ids found in {OUR_ABC_DIR}"
    assert sorted(e for e in ENTRIES if e[:8] in ours) == []


def test_manifest_agrees_with_list():
    assert ROW_PROBLEMS == []
    assert [r["file"].rsplit(".", 1)[0] for r in ROWS] == ENTRIES
    for row in ROWS:
        assert row["abc_id"] == row["file"][:8]
        assert re.fullmatch(r"[0-9a-f]{64}", row["sha256"])
        assert row["source_path"] == "datasets/abc_modeling/00_base_meshes/" + row["file"]
        assert int(row["faces"]) <= MAX_FACES
        assert row["closed"] in ("yes", "no")
    assert len({r["sha256"] for r in ROWS}) == len(ROWS)  # byte-identical files count once


def test_check_reports_each_problem_on_one_line(tmp_path, capsys):
    assert fetch_script.main(["--check", str(tmp_path)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == len(ROWS) and all(line.endswith(": missing (pinned by abc-unseen.csv)") for line in err)


def test_fetch_copies_and_verifies(tmp_path):
    repo, out = tmp_path / "repo", tmp_path / "out"
    (repo / "src").mkdir(parents=True)
    (repo / "src" / "a.stl").write_bytes(b"solid a")
    (repo / "src" / "b.stl").write_bytes(b"solid b")
    rows = [{"file": "a.stl", "source_path": "src/a.stl", "sha256": hashlib.sha256(b"solid a").hexdigest()},
            {"file": "b.stl", "source_path": "src/b.stl", "sha256": "0" * 64},
            {"file": "c.stl", "source_path": "src/c.stl", "sha256": "0" * 64}]
    problems = fetch_script.fetch(repo, out, rows)
    assert (out / "a.stl").read_bytes() == b"solid a"
    assert not (out / "b.stl").exists()  # a source with the wrong SHA-256 is not copied
    assert [p.split(": ", 1)[1].split(" ", 1)[0] for p in problems] == ["SHA-256", "missing"]


def test_missing_clone_prints_the_commands(tmp_path, capsys):
    assert fetch_script.main(["--repo", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert f"git clone {fetch_script.SOURCE_URL}" in err and fetch_script.COMMIT in err


@pytest.mark.skipif(not UNSEEN_DIR.is_dir(), reason=f"{UNSEEN_DIR} is absent: make it with "
                    "scripts/fetch_abc_unseen.py --repo <ppsurf_modeling clone>")
def test_shared_copies_match_their_sha256(capsys, monkeypatch):
    assert [p for row in ROWS if (p := fetch_script.check_file(UNSEEN_DIR / row["file"], row))] == []
    monkeypatch.setenv("SALSBENCH_SHARED_DATA", str(SHARED_DATA))
    assert fetch_script.main(["--check"]) == 0  # the shared folder is the default source
    assert capsys.readouterr().out.strip() == f"{len(ROWS)} files ok in {UNSEEN_DIR}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a list entry without its file would warn
        dataset = get_dataset("abc", data_dir=UNSEEN_DIR, list_file=LIST, strict=True)
    assert dataset.names() == ENTRIES


SCALING_LIST = REPO / "lists" / "abc-22-unseen-12.txt"


def test_the_scaling_list_is_twelve_of_our_abc_parts_outside_ndc_training_range():
    entries = read_list_file(SCALING_LIST)
    assert len(entries) == 12 and entries == sorted(entries)
    assert [e for e in entries if int(e[:8]) in NDC_TRAINING_IDS] == []
    if not OUR_ABC_DIR.is_dir():
        pytest.skip(f"{OUR_ABC_DIR} is absent: the list's files are read from it")
    stems = {p.name.rsplit(".", 1)[0] for p in OUR_ABC_DIR.iterdir()}
    assert [e for e in entries if e not in stems] == []
    unseen = sorted(s for s in stems if re.match(r"\d{8}", s) and int(s[:8]) not in NDC_TRAINING_IDS)
    assert entries == unseen[:12]  # the header's rule: the first 12 by id of the unseen ones
