"""``udf-dcudf``: the udf field extracted by DCUDF. Oracle mode on a turned box (one closed sheet,
against the udf method's MeshUDF) and the fit it shares with ``udf``; the steps on a sphere are in
``tests/test_dcudf.py``."""

import numpy as np

from foundation.fields import ExactFields
from foundation.metrics import evaluate
from methods.base import get_method
from tasks.cache import fit_code_digest
from tests.test_methods import N_POINTS, _oracle, generic_box


def test_oracle_turned_box_is_closed_and_as_close_as_meshudf(tmp_path, torch_threads):
    """At 40^3 with r = 0.03 (the authors' r, 0.064 here, makes the inner and outer sheets of so small
    a box differ by more than the cut's 15 %) and 40 iterations: the cut keeps the outer sheet, a
    closed mesh with a CD close to MeshUDF's, whose mesh has boundary edges; the box's edges come
    out rounded (the measured values: docs/PERFORMANCE.md, section 7)."""
    V, F, _, _ = generic_box()
    ex = _oracle("udf-dcudf", V, F, 40, tmp_path, r=0.03, iterations=40)
    mu = _oracle("udf", V, F, 40, tmp_path)
    scores = evaluate(V, F, ex.vertices, ex.faces, n_points=N_POINTS, seed=0)
    mc = evaluate(V, F, mu.vertices, mu.faces, n_points=N_POINTS, seed=0)
    info = ex.info
    assert info["cut"] == 1 and info["iterations"] == 40 and info["faces"] == len(ex.faces)
    assert 0.5 < info["faces"] / info["cover_faces"] < 0.6  # the outer of two sheets
    assert scores["watertight"] and not mc["watertight"]
    assert scores["cd"] < 0.01 and scores["cd"] < 1.2 * mc["cd"]
    assert np.median(ExactFields(V, F).udf(ex.vertices)) < 0.004  # the value measured: as above


def test_shares_the_udf_fit():
    udf, dcudf = get_method("udf"), get_method("udf-dcudf")
    assert dcudf.fit_name == "udf" and dcudf.fit_params() == udf.fit_params()
    assert fit_code_digest(dcudf) == fit_code_digest(udf)
