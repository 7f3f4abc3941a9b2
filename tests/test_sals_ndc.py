"""``sals-ndc``: the sals field with learned intersection flags. It shares the sals fit; on the
exact field of a turned box a network that passes o through flags exactly the crossing edges and
the mesh is sals's oracle mesh; its decomposition takes the exact field's components, not its own
flags; without weights it is unavailable in one line."""

import numpy as np
import pytest

from foundation.field_cache import FieldCache
from foundation.fields import ExactFields
from methods.base import available_methods, get_method
from methods.extractors import learned_flags
from tasks.cache import fit_code_digest
from tests.test_learned_flags import _threshold_network
from tests.test_methods import generic_box


def _with_weights(tmp_path, monkeypatch, network, names=("train1_builtin_000_bracket",)):
    path = tmp_path / "flags.pt"
    learned_flags.save_weights(path, network, {"training_names": list(names), "training_hashes": ["h0"],
                                               "training_set": "test"})
    monkeypatch.setenv(learned_flags.WEIGHTS_ENV, str(path))
    return path


def test_shares_the_sals_fit():
    sals, sals_ndc = get_method("sals"), get_method("sals-ndc")
    assert sals_ndc.fit_name == "sals" and sals_ndc.fit_params() == sals.fit_params()
    assert fit_code_digest(sals_ndc) == fit_code_digest(sals)
    assert "o_threshold" not in sals_ndc.params and sals_ndc.params["o_low"] == learned_flags.DEFAULT_O_LOW


def test_with_a_network_passing_o_through_the_oracle_mesh_is_sals_oracle_mesh(tmp_path, monkeypatch):
    """Exact o is 1 on the crossing edges: the threshold network keeps all of them and nothing else,
    so E-DC gets sals's oracle input and makes the same mesh; the decomposition's exact field is
    that field too."""
    _with_weights(tmp_path, monkeypatch, _threshold_network())
    V, F, _, _ = generic_box()
    fields, cache, N = ExactFields(V, F), FieldCache(None), 40
    method = get_method("sals-ndc")
    grid, facts = method.oracle_grid(fields, N, cache)
    exact, _ = get_method("sals").oracle_grid(fields, N, cache)
    np.testing.assert_array_equal(grid["edge_ids"], exact["edge_ids"])
    assert facts["flagged_edges"] == facts["candidate_edges"] == len(exact["edge_ids"]) > 1000
    ours, theirs = method.extract(grid, N), get_method("sals").extract(exact, N)
    np.testing.assert_array_equal(ours.vertices, theirs.vertices)
    np.testing.assert_array_equal(ours.faces, theirs.faces)
    np.testing.assert_array_equal(method.exact_grid(fields, N, cache)["edge_ids"], exact["edge_ids"])
    assert method.training_record().saw("any", "h0") and not method.training_record().saw("any", "h1")


def test_a_network_that_flags_nothing_gives_an_empty_mesh_and_the_decomposition_keeps_the_exact_field(
        tmp_path, monkeypatch):
    network = _threshold_network()
    with __import__("torch").no_grad():
        network.conv_out.bias[:] = -2.0  # logit o - 2 < 0 for every o in [0, 1]
    _with_weights(tmp_path, monkeypatch, network)
    V, F, _, _ = generic_box()
    method = get_method("sals-ndc")
    grid, facts = method.oracle_grid(ExactFields(V, F), 24, FieldCache(None))
    assert len(grid["edge_ids"]) == 0 and facts["candidate_edges"] > 0
    assert len(method.extract(grid, 24).faces) == 0
    assert len(method.exact_grid(ExactFields(V, F), 24, FieldCache(None))["edge_ids"]) == facts["candidate_edges"]


def test_without_the_weights_it_is_unavailable_with_one_clear_line(tmp_path, monkeypatch):
    monkeypatch.setenv(learned_flags.WEIGHTS_ENV, str(tmp_path / "absent.pt"))
    line = get_method("sals-ndc").unavailable()
    assert line.startswith(f"sals-ndc weights not found at {tmp_path / 'absent.pt'}") and "\n" not in line
    assert "sals-ndc" not in available_methods() and "sals" in available_methods()


def test_weights_trained_on_an_evaluation_shape_make_it_unavailable(tmp_path, monkeypatch):
    _with_weights(tmp_path, monkeypatch, _threshold_network(), names=("00012345_abcdef",))
    line = get_method("sals-ndc").unavailable()
    assert "trained on evaluation shape(s) 00012345_abcdef: refused" in line and "\n" not in line
