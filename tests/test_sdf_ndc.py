"""``sdf-ndc``: the sdf field extracted by NDC. Oracle mode on a turned box (NDC keeps the sharp
edges marching cubes cuts off), the fit it shares with ``sdf``, and a machine without the weights."""

import pytest

from foundation.metrics import evaluate
from methods.extractors import ndc
from methods.base import METHODS, available_methods, get_method
from tasks.cache import fit_code_digest
from runner.config import ConfigError, RunConfig
from runner.plan import resolve
from tests.test_methods import N_POINTS, _oracle, edge_coverage, generic_box


def _need_weights():
    try:
        ndc.load_weights()
    except ndc.WeightsError as exc:
        pytest.skip(str(exc))


def test_oracle_turned_box_keeps_its_twelve_sharp_edges(tmp_path):
    """The exact SDF of a box in general position at N = 64: NDC's vertices lie on its edges."""
    _need_weights()
    V, F, corners, edges = generic_box()
    ex = _oracle("sdf-ndc", V, F, 64, tmp_path)
    mc = _oracle("sdf", V, F, 64, tmp_path)
    ndc_scores = evaluate(V, F, ex.vertices, ex.faces, n_points=N_POINTS, seed=0)
    mc_scores = evaluate(V, F, mc.vertices, mc.faces, n_points=N_POINTS, seed=0)
    assert ndc_scores["cd"] < 0.02 and ex.info["ndc_cells"] == len(ex.vertices)
    cover, on_edges = edge_coverage(ex.vertices, ex.faces, corners, edges)
    # every edge found along (nearly) its whole length, few false edges (NDC's learned vertices miss
    # an edge's end more often at coarser grids)
    assert cover.min() >= 0.9 and on_edges >= 0.9, (cover, on_edges)
    assert ndc_scores["ecd"] < 0.5 * mc_scores["ecd"] and ndc_scores["ef1"] > mc_scores["ef1"] + 0.3


def test_shares_the_sdf_fit():
    sdf, sdf_ndc = get_method("sdf"), get_method("sdf-ndc")
    assert sdf_ndc.fit_name == "sdf" and sdf.fit_name == "sdf"
    assert fit_code_digest(sdf_ndc) == fit_code_digest(sdf) and sdf_ndc.fit_params() == sdf.fit_params()
    # every method fitted under another's name is that method's field: same targets, loss and fit params
    for name in METHODS.names():
        cls = METHODS.get(name)
        if cls.fit_of:
            owner = METHODS.get(cls.fit_of)
            assert issubclass(cls, owner) and not cls.fit_of == name
            for hook in ("training_targets", "loss", "network_inputs", "fit_params"):
                assert getattr(cls, hook) is getattr(owner, hook), (name, hook)
            assert cls.input_kind == owner.input_kind and cls.output_dim == owner.output_dim


def test_without_the_weights_it_is_left_out_of_the_default_list_and_refused_by_name(tmp_path, monkeypatch):
    monkeypatch.setenv(ndc.WEIGHTS_ENV, str(tmp_path / "absent.pth"))
    assert "sdf-ndc" not in available_methods() and "sdf" in available_methods()
    assert "sdf-ndc" not in resolve(RunConfig(limit=1)).methods
    with pytest.raises(ConfigError, match=r"method 'sdf-ndc' cannot run here: NDC weights not found at .*absent.pth"):
        resolve(RunConfig(methods=("sdf", "sdf-ndc"), limit=1))
