"""methods.core.training_record and the seen_in_training column: a result row says whether its shape
was in the training set of the weights its method used, and the summary gives the means on the
shapes no method's weights saw."""

from __future__ import annotations

import pandas as pd
import pytest
import trimesh

from methods.base import registered_method
from methods.core.training_record import TrainingRecord, abc_ids
from runner.cli import main
from tests.fake_methods import PLUGIN, FakeSDF


def test_abc_ids_and_matching_by_id_range_or_content_hash():
    assert abc_ids("00000006_0") == [6] and abc_ids("00007974_5") == [7974] and abc_ids("bracket") == []
    assert abc_ids("00000003_ab+00010218_cd") == [3, 10218] and abc_ids("123456789_x") == []
    ndc = TrainingRecord("NDC", abc_ranges=((2, 7903),))
    assert ndc.saw("00000003_1ffb", "h") and ndc.saw("00007903", "h") and not ndc.saw("00007974_5", "h")
    assert not ndc.saw("00000001_1ffb", "h") and ndc.saw("00010218_x+00000005_y", "h")  # a soup: either part
    ours = TrainingRecord("ours", content_hashes=frozenset({"abc"}))
    assert ours.saw("anything", "abc") and not ours.saw("anything", "def")
    assert TrainingRecord("unrecorded", content_hashes=None).saw("x", "abc") is None


def test_the_published_ndc_weights_declare_their_abc_range():
    from methods.base import METHODS

    record = METHODS.get("sdf-ndc")().training_record()
    assert record.abc_ranges == ((2, 7903),) and record.saw("00000009_9b3d", "h")
    assert METHODS.get("sdf")().training_record() is None


class FakeSeen(FakeSDF):
    name = "test_seen"
    description = "test-only: the exact SDF, 'weights' trained on ABC object 00000003"

    def training_record(self):
        return TrainingRecord("test-only weights: ABC 00000003", abc_ranges=((3, 3),))


@pytest.mark.slow
def test_rows_say_which_shapes_were_seen_and_the_summary_gives_the_unseen_means(fakes, tmp_path):
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    trimesh.creation.box().export(meshes / "00000003_box.obj")
    trimesh.creation.icosphere(2).export(meshes / "00000010_ball.obj")
    trimesh.creation.cylinder(0.5, 1.0).export(meshes / "00000011_can.obj")
    out = tmp_path / "run"
    with registered_method(FakeSeen, order=9):
        code = main(["--methods", "test_seen", "test_sdf", "--mode", "oracle", "--dataset", "meshes", "--data-dir",
                     str(meshes), "--grid", "24", "--eval-points", "5000", "--out", str(out), "--quiet",
                     "--gallery", "0", "--cache-dir", str(tmp_path / "c"), "--plugin", PLUGIN, "--executor", "local"])
    assert code == 0
    df = pd.read_csv(out / "results.csv")
    seen = df.set_index(["method", "shape"])["seen_in_training"]
    assert seen["test_seen", "00000003_box"] == 1 and seen["test_seen", "00000010_ball"] == 0
    assert seen["test_sdf"].isna().all()  # no trained weights: no claim either way
    text = (out / "summary.md").read_text().replace("\\_", "_")  # markdown escapes the underscores
    assert "test_seen: its weights were trained on 1 of the 3 shapes (00000003_box), marked §" in text
    assert "Mean over the 2 shapes no method's weights were trained on" in text
    assert "Shapes: 00000010_ball, 00000011_can" in text


def test_a_learned_networks_record_holds_its_training_shapes():
    from datasets import get_dataset
    from methods.base import get_method
    from tasks.trained_networks import network_training_record

    method = get_method("sals-knn")
    budget = method.budget("tiny", {})
    record = network_training_record(method, budget, ())
    assert len(record.content_hashes) == budget.training_shapes
    test_shape = get_dataset("builtin").load(get_dataset("builtin").names()[0])
    assert record.saw(test_shape.name, test_shape.content_hash) is False  # the built-in test parts are not training parts
