"""tasks.rows: a method's row carries its class's facts; the score task's rows are folders of
predictions under a name of the user's, registered nowhere, their parameters typed and checked."""

from __future__ import annotations

import pytest

from foundation.params import ParamError
from methods.base import METHODS, available_methods
from tasks.rows import method_row, predictions_row, row_kind


def test_a_method_row_states_its_class():
    for name in available_methods(None):
        cls, row = METHODS.get(name), method_row(name)
        assert (row.task, row.module, row.learned, row.budget_family, row.fit_name, row.components) == (
            cls.task, cls.__module__, cls.learned, cls.budget_family, cls.fit_name, tuple(cls.components))
        assert row.budget_fields == cls.budget_fields() and row.checked_params({}) == cls().params
    sdf_ndc = row_kind("encode", "sdf-ndc")
    assert sdf_ndc.fit_name == "sdf" and sdf_ndc.budget_family == "encode"
    assert row_kind("reconstruct", "poisson").budget_family is None
    with pytest.raises(ValueError, match="no-such-method"):
        row_kind("encode", "no-such-method")


def test_a_score_row_is_a_folder_of_predictions_under_any_new_name(tmp_path):
    row = row_kind("score", "mine", {"pred_dir": str(tmp_path), "pred_frame": "canonical"})
    assert (row.task, row.module, row.budget_family, row.learned) == ("score", "tasks.score", None, False)
    assert row.note == f"mine: meshes made outside this run from {tmp_path} (canonical frame), scored as given."
    assert "mine" not in METHODS
    assert row.checked_params({"pred_dir": str(tmp_path)}) == {"pred_dir": str(tmp_path), "pred_frame": "original"}
    with pytest.raises(ValueError, match=r"mine.pred_dir .*missing: not a folder of predicted meshes"):
        row.checked_params({"pred_dir": str(tmp_path / "missing")})
    with pytest.raises(ParamError, match="pred_frame"):
        row.checked_params({"pred_dir": str(tmp_path), "pred_frame": "sideways"})
    with pytest.raises(ParamError, match="has no parameter"):
        row.checked_params({"pred_dir": str(tmp_path), "o_threshold": 0.1})
    with pytest.raises(ValueError, match="'sals' is a built-in method"):
        predictions_row("sals")
