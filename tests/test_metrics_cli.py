"""The command line ``python -m foundation.metrics GT PRED`` (foundation/metrics/__main__.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from foundation.metrics.__main__ import main
from tests.conftest import REPO


def run_cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "foundation.metrics", *map(str, args)], cwd=REPO, capture_output=True, text=True, timeout=120
    )


def test_cli_json_on_two_tiny_meshes(tmp_path, capsys):
    """GT cube side 20, prediction cube side 22 (offset 1 per face). The GT's canonical transform
    scales by 1.99 / 20, so the offset becomes 0.0995; with --no-normalize it stays 1. The sampled
    gt -> pred mean exceeds the offset by ~E[s^2] / (2 offset) ~ 2% at 20k points: 5% tolerance."""
    trimesh.creation.box(extents=(20, 20, 20)).export(tmp_path / "gt.obj")
    trimesh.creation.box(extents=(22, 22, 22)).export(tmp_path / "pred.ply")
    out = run_cli(tmp_path / "gt.obj", tmp_path / "pred.ply", "--points", 20000, "--json", "--seed", 3)
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert r["cd_gt_to_pred"] == pytest.approx(0.0995, rel=0.05)
    assert r["n_faces"] == 12 and r["watertight"] is True and r["seed"] == 3 and r["normalized"] is True
    # the other options, in-process (same entry point, no interpreter start-up)
    assert main([str(tmp_path / "gt.obj"), str(tmp_path / "pred.ply"), "--points", "20000", "--json", "--no-normalize"]) == 0
    assert json.loads(capsys.readouterr().out)["cd_gt_to_pred"] == pytest.approx(1.0, rel=0.05)
    assert main([str(tmp_path / "gt.obj"), str(tmp_path / "pred.ply"), "--points", "5000", "--preset", "ndc"]) == 0
    table = capsys.readouterr().out
    assert "CD (x100000)" in table and "F1@0.003" in table and "watertight yes" in table


def test_cli_bad_path_exits_2_with_one_line(tmp_path, capsys):
    trimesh.creation.box().export(tmp_path / "gt.obj")
    out = run_cli(tmp_path / "gt.obj", tmp_path / "missing.obj")
    assert out.returncode == 2 and out.stdout == ""
    assert len(out.stderr.strip().splitlines()) == 1 and "missing.obj" in out.stderr and "not found" in out.stderr
    (tmp_path / "junk.obj").write_text("this is not a mesh\n")
    assert main([str(tmp_path / "junk.obj"), str(tmp_path / "gt.obj")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "junk.obj" in err


def obj_text(vertices, faces="f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n") -> str:
    """An OBJ with exactly these float64 vertices (repr round-trips); default faces: a tetrahedron."""
    return "".join("v " + " ".join(repr(float(x)) for x in p) + "\n" for p in vertices) + faces


TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TETRA = obj_text(TET)

#: prediction files that are readable but degenerate: scored (NaN + flags), exit 0
DEGENERATE_PREDICTIONS = {
    "nan.obj": ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", 1),  # (content, dropped faces)
    "zero_area.obj": ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", 0),
    "bad_index.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", 1),
    "points.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", 0),
}


def strict_json(text: str) -> dict:
    """json.loads that refuses the non-standard NaN/Infinity tokens."""
    def refuse(token):
        raise ValueError(f"non-standard JSON token {token}")
    return json.loads(text, parse_constant=refuse)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", sorted(DEGENERATE_PREDICTIONS))
def test_a_degenerate_prediction_is_scored_with_its_flags_exit_0(tmp_path, capsys, name):
    """The prediction is data: scored, never exit 2 ("total surface area is zero", "NaN ...")."""
    content, dropped = DEGENERATE_PREDICTIONS[name]
    (tmp_path / "gt.obj").write_text(TETRA)
    (tmp_path / name).write_text(content)
    args = [str(tmp_path / "gt.obj"), str(tmp_path / name), "--points", "2000"]
    assert main(args + ["--json"]) == 0
    r = strict_json(capsys.readouterr().out)
    assert r["empty_prediction"] is True and r["cd"] is None and r["f1_005"] == 0.0 and r["dropped_faces"] == dropped
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "prediction is EMPTY or degenerate (no usable face, or its faces lie on a line or a point)" in table
    assert ("prediction faces dropped" in table) == bool(dropped)


def test_an_empty_mesh_file_as_trimesh_writes_it_is_an_empty_prediction(tmp_path, capsys):
    (tmp_path / "gt.obj").write_text(TETRA)
    trimesh.Trimesh().export(tmp_path / "empty.ply")  # 'element vertex 0', 'element face 0'
    assert main([str(tmp_path / "gt.obj"), str(tmp_path / "empty.ply"), "--points", "2000", "--json"]) == 0
    r = strict_json(capsys.readouterr().out)
    assert r["empty_prediction"] is True and r["n_vertices"] == 0 and r["n_faces"] == 0


@pytest.mark.parametrize("case", ["GT on a line", "unreadable GT file", "unreadable prediction file", "--points 0", "--seed -1"])
def test_a_broken_gt_a_broken_file_or_a_bad_flag_exits_2_with_one_line(tmp_path, capsys, case):
    (tmp_path / "gt.obj").write_text(TETRA)
    (tmp_path / "line.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    (tmp_path / "pred.stl").write_bytes(b"abc")
    gt, pred, flags, expected = {
        "GT on a line": ("line.obj", "gt.obj", [], "line.obj: total surface area is zero relative to its size"),
        "unreadable GT file": ("pred.stl", "gt.obj", [], "pred.stl: not an STL file: 3 bytes"),
        "unreadable prediction file": ("gt.obj", "pred.stl", [], "pred.stl: not an STL file: 3 bytes"),
        "--points 0": ("gt.obj", "gt.obj", ["--points", "0"], "error: --points must be >= 1, got 0"),
        "--seed -1": ("gt.obj", "gt.obj", ["--seed", "-1"],
                      "error: seed must be a non-negative int or a numpy.random.SeedSequence, got -1"),
    }[case]
    assert main([str(tmp_path / gt), str(tmp_path / pred), *flags]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1 and expected in captured.err


@pytest.mark.filterwarnings("error")
def test_a_pair_at_2_to_the_minus_1000_scores_exactly_like_the_pair_at_1(tmp_path, capsys):
    """The GT's canonical transform of a 2^-1000-scale pair is the unit pair's, scaled exactly: same
    numbers bit for bit, never exit 2 with "total surface area is zero"."""
    results = []
    for scale in (1.0, 2.0**-1000):
        (tmp_path / "gt.obj").write_text(obj_text(TET * scale))
        (tmp_path / "pred.obj").write_text(obj_text((TET * 1.02 + 0.01) * scale))
        assert main([str(tmp_path / "gt.obj"), str(tmp_path / "pred.obj"), "--points", "5000", "--json"]) == 0
        results.append({k: v for k, v in strict_json(capsys.readouterr().out).items() if k != "seconds"})
    assert results[0] == results[1] and results[0]["empty_prediction"] is False


def test_the_scene_preset_reads_the_files_in_metres(tmp_path):
    """A 1 m square and its copy 3 cm above, as files in metres: CD 3 cm (x100 in the table), with or
    without the canonical mapping."""
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    trimesh.Trimesh(V, F, process=False).export(tmp_path / "gt.ply")
    trimesh.Trimesh(V + [0, 0, 0.03], F, process=False).export(tmp_path / "pred.ply")
    for extra in ((), ("--no-normalize",)):
        out = run_cli(str(tmp_path / "gt.ply"), str(tmp_path / "pred.ply"), "--preset", "scene", "--points", "200000",
                      "--json", *extra)
        assert out.returncode == 0, out.stderr
        assert json.loads(out.stdout)["cd"] == pytest.approx(0.03, rel=2e-3)
