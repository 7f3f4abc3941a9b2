"""``udf-dualmesh``: the udf field extracted by DualMesh-UDF. Oracle mode on a turned box (the dual
vertices land on its edges and corners) and the fit it shares with ``udf``."""

import numpy as np

from foundation.fields import ExactFields
from foundation.metrics import evaluate
from methods.base import get_method
from tasks.cache import fit_code_digest
from tests.test_methods import N_POINTS, _oracle, edge_coverage, generic_box


def test_oracle_turned_box_keeps_its_twelve_sharp_edges_and_eight_corners(tmp_path):
    V, F, corners, edges = generic_box()
    ex = _oracle("udf-dualmesh", V, F, 40, tmp_path)
    scores = evaluate(V, F, ex.vertices, ex.faces, n_points=N_POINTS, seed=0)
    mc = evaluate(V, F, *(lambda e: (e.vertices, e.faces))(_oracle("udf", V, F, 40, tmp_path)), n_points=N_POINTS, seed=0)
    assert scores["cd"] < 0.02
    assert np.abs(ExactFields(V, F).udf(ex.vertices)).max() < 1e-3  # every vertex on the surface
    cover, on_edges = edge_coverage(ex.vertices, ex.faces, corners, edges)
    assert cover.min() == 1.0 and on_edges > 0.95, (cover, on_edges)
    assert np.linalg.norm(ex.vertices[:, None] - corners[None], axis=2).min(axis=0).max() < 1e-3  # corners
    assert ex.info["corner_vertices"] >= 8 and ex.info["edge_vertices"] > 0
    assert scores["ecd"] < 0.5 * mc["ecd"] and scores["ef1"] > mc["ef1"] + 0.2  # MeshUDF cuts the edges


def test_shares_the_udf_fit():
    udf, dualmesh = get_method("udf"), get_method("udf-dualmesh")
    assert dualmesh.fit_name == "udf" and dualmesh.fit_params() == udf.fit_params()
    assert fit_code_digest(dualmesh) == fit_code_digest(udf)
