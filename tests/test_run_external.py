"""The score task (``run_benchmark.py score``, :mod:`tasks.score`, :func:`tasks.rows.predictions_row`):
meshes made elsewhere scored as a row of their own, registered nowhere.

Shapes (a ``meshes`` dataset in a non-canonical frame): a sphere of radius 3 centred at (-5, 2, 0)
(icosphere, 5 subdivisions) and a 2 x 1 x 0.5 box centred at (10, 0, 0). The canonical scale of the
sphere is 1.99 / 6 (radius 0.995), so a prediction shifted by 0.6 along x in the file's frame is
shifted by d = 0.199 canonical units; its Chamfer distance is :func:`shifted_sphere_cd` (d / 2 to
first order in d / r).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import trimesh

from methods.base import METHODS
from tasks.rows import row_kind
from runner.cli import EXIT_FAILED_TASKS, EXIT_REFUSED, main
from tasks.score import external_seconds, prediction_file, unmatched_predictions

SHIFT = 0.6


def shifted_sphere_cd(r: float, d: float) -> float:
    """The Chamfer distance between a sphere of radius r and its copy shifted by d: the mean, over the
    sphere's points p = c + d x + r n (n uniform, so n_x = t uniform on [-1, 1]), of their distance
    | |r n + d x| - r | = |f(t) - r| to the other, f(t) = sqrt(r^2 + d^2 + 2 r d t); both directions
    alike. With F(t) = f(t)^3 / (3 r d) - r t (an antiderivative of f - r) and f(t0) = r at
    t0 = -d / (2 r): 1/2 [F(1) + F(-1) - 2 F(t0)]."""
    def F(t):
        return (r * r + d * d + 2 * r * d * t) ** 1.5 / (3 * r * d) - r * t

    return 0.5 * (F(1.0) + F(-1.0) - 2 * F(-d / (2 * r)))


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    root = tmp_path_factory.mktemp("gt")
    sphere = trimesh.creation.icosphere(5, radius=3.0)
    sphere.apply_translation((-5.0, 2.0, 0.0))
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box.apply_translation((10.0, 0.0, 0.0))
    meshes = {"sphere": sphere, "box": box}
    for name, mesh in meshes.items():
        mesh.export(root / f"{name}.off")
    return root, meshes


def _score(tmp_path, data_dir, pred_dir, name="mine", *extra):
    out = tmp_path / f"run-{name}-{len(list(tmp_path.iterdir()))}"
    code = main(["score", "--pred-dir", str(pred_dir), "--name", name, "--dataset", "meshes", "--data-dir",
                 str(data_dir), "--eval-points", "20000", "--out", str(out), "--quiet", "--gallery", "0",
                 "--executor", "local", *extra])
    assert name not in METHODS  # a score run's row is registered nowhere
    return code, out


@pytest.mark.slow
def test_the_gt_itself_scores_at_the_floor_and_a_shifted_sphere_the_analytic_shift(shapes, tmp_path):
    """The GT given back scores exactly its floor row (the same metric samples: F1 -> 1 and CD -> 0
    as the points grow; at 20k points the floor's CD is ~0.01)."""
    data_dir, meshes = shapes
    same, shifted = tmp_path / "same", tmp_path / "shifted"
    same.mkdir(), shifted.mkdir()
    for name, mesh in meshes.items():
        mesh.export(same / f"{name}.off")
        mesh.copy().apply_translation((SHIFT, 0.0, 0.0)).export(shifted / f"{name}.off")
    code, out = _score(tmp_path, data_dir, same)
    assert code == 0
    jobs = pd.read_csv(out / "results.csv").set_index("shape")
    floor = pd.read_csv(out / "floor.csv").set_index("shape").loc[jobs.index]
    metrics = ["cd", "nc", "f1_005", "f1_01", "ecd", "ef1"]
    assert np.array_equal(jobs[metrics].to_numpy(), floor[metrics].to_numpy(), equal_nan=True)  # the floor, exactly
    code, out = _score(tmp_path, data_dir, shifted, "mine", "--eval-points", "200000")
    jobs = pd.read_csv(out / "results.csv").set_index("shape")
    assert shifted_sphere_cd(1.0, 1e-6) == pytest.approx(0.5e-6, rel=1e-3)  # d / 2 for a small shift
    assert jobs.loc["sphere", "cd"] == pytest.approx(shifted_sphere_cd(0.995, SHIFT * 1.99 / 6.0), rel=0.03)


@pytest.mark.slow
def test_canonical_predictions_score_as_the_same_meshes_in_the_original_frame(shapes, tmp_path):
    from datasets import get_dataset

    data_dir, meshes = shapes
    original, canonical = tmp_path / "original", tmp_path / "canonical"
    original.mkdir(), canonical.mkdir()
    dataset = get_dataset("meshes", data_dir=data_dir)
    for name, mesh in meshes.items():
        noisy = mesh.copy()
        noisy.vertices += np.random.default_rng(0).normal(scale=0.01, size=noisy.vertices.shape)
        noisy.export(original / f"{name}.ply", encoding="ascii")
        shape = dataset.load(name)
        trimesh.Trimesh(shape.transform.apply(noisy.vertices), noisy.faces, process=False).export(
            canonical / f"{name}.ply", encoding="ascii")
    _, out_a = _score(tmp_path, data_dir, original)
    _, out_b = _score(tmp_path, data_dir, canonical, "mine", "--pred-frame", "canonical")
    a, b = (pd.read_csv(o / "results.csv").set_index("shape") for o in (out_a, out_b))
    assert np.allclose(a.loc[:, ["cd", "nc", "f1_005", "ecd"]], b.loc[a.index, ["cd", "nc", "f1_005", "ecd"]],
                       rtol=1e-4, equal_nan=True)  # float32 PLY coordinates in both frames
    assert "mine: meshes made outside this run" in (out_b / "summary.md").read_text()


def test_a_missing_prediction_fails_its_job_and_extra_ones_are_listed_and_ignored(shapes, tmp_path, capsys):
    data_dir, meshes = shapes
    preds = tmp_path / "preds"
    (preds / "sphere").mkdir(parents=True)
    meshes["sphere"].export(preds / "sphere" / "mine.obj")  # the nested layout
    meshes["box"].export(preds / "stray.obj")
    (preds / "seconds.csv").write_text("shape,seconds\nsphere,12.5\n")
    code, out = _score(tmp_path, data_dir, preds)
    assert code == EXIT_FAILED_TASKS
    jobs = pd.read_csv(out / "results.csv").set_index("shape")
    assert jobs.loc["sphere", "status"] == "ok" and jobs.loc["box", "status"] == "failed"
    assert jobs.loc["box", "error"].startswith(f"loading: FileNotFoundError: no prediction for shape 'box' in {preds}")
    assert "1 prediction(s) match no shape of the dataset, ignored: stray.obj" in capsys.readouterr().err
    assert jobs.loc["sphere", "external_s"] == 12.5


def test_the_matching_rule_and_the_refusals(tmp_path, capsys):
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    (tmp_path / "a.ply").write_text("ply\n")
    with pytest.raises(ValueError, match="several predictions for shape 'a'"):
        prediction_file(tmp_path, "a", "m")
    with pytest.raises(FileNotFoundError, match=r"looked for b.<ext> and b/m.<ext>"):
        prediction_file(tmp_path, "b", "m")
    assert unmatched_predictions(tmp_path, ["b"], "m") == ["a.obj", "a.ply"]
    (tmp_path / "seconds.csv").write_text("shape,seconds\na,-1\n")
    with pytest.raises(ValueError, match="line 2: seconds '-1' is not a number >= 0"):
        external_seconds(tmp_path)
    assert main(["score", "--name", "x"]) == EXIT_REFUSED
    assert "score needs --pred-dir DIR" in capsys.readouterr().err
    assert main(["score", "--name", "sals", "--pred-dir", str(tmp_path)]) == EXIT_REFUSED
    assert "'sals' is a built-in method" in capsys.readouterr().err
