"""The error decomposition of fitted fields (methods.base.FieldMethod.hybrid_grid, component_errors and
--decompose end to end): hand-worked hybrids, and every exact component reproducing the oracle."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from methods.base import METHODS, median_angle_deg, signed_hybrid, wrong_side_points
from methods.fields.sals import SALSMethod


def test_each_method_lists_single_components_their_complements_and_all():
    assert METHODS.get("sals").decompositions() == [
        ("flags",), ("s",), ("normals",), ("s", "normals"), ("flags", "normals"), ("flags", "s"),
        ("flags", "s", "normals")]
    assert METHODS.get("udf").decompositions() == [("values",), ("gradients",), ("values", "gradients")]
    assert METHODS.get("sdf").decompositions() == [("sign",), ("magnitude",), ("sign", "magnitude")]


def test_signed_hybrid_takes_the_side_from_one_field_and_the_distance_from_the_other():
    fitted = np.array([0.3, -0.2, 0.05], dtype=np.float32)
    exact = np.array([-0.1, -0.4, 0.2], dtype=np.float32)
    np.testing.assert_array_equal(signed_hybrid(exact, fitted, 0.0), np.float32([-0.3, -0.2, 0.05]))
    np.testing.assert_array_equal(signed_hybrid(fitted, exact, 0.0), np.float32([0.1, -0.4, 0.2]))
    np.testing.assert_array_equal(signed_hybrid(exact, exact, 0.0), exact)  # one field for both: itself
    # occupancy around level 0.5: exact 0/1 stays 0/1
    np.testing.assert_array_equal(signed_hybrid(np.float32([0, 1]), np.float32([0, 1]), 0.5), np.float32([0, 1]))
    assert wrong_side_points(fitted, exact, 0.0) == 1


def test_median_angle_is_unoriented_for_planes_and_oriented_for_gradients():
    a = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=float)
    b = np.array([[-1, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 0]], dtype=float)  # last row: no direction
    assert median_angle_deg(a, b) == pytest.approx(0.0)  # angles 0, 0, 45
    assert median_angle_deg(a, b, oriented=True) == pytest.approx(45.0)  # 180, 0, 45
    assert np.isnan(median_angle_deg(np.zeros((2, 3)), np.ones((2, 3))))


class _ConstantSegments:
    """A stand-in network: every segment gets o high and s ~ 0.25, whose gradient w.r.t. either endpoint is along +x."""

    def __call__(self, x):
        import torch

        s_logit = float(np.log(0.25 / 0.75))
        return torch.stack([torch.full_like(x[:, 0], 5.0), s_logit + 1e-3 * (x[:, 0] + x[:, 3])], dim=1)

    def parameters(self):
        import torch

        return iter([torch.zeros(1)])


def test_sals_hybrid_mixes_flags_s_and_normals_edge_by_edge():
    method = SALSMethod()
    fitted = {"edge_ids": np.array([2, 5, 9]), "s": np.float32([0.9, 0.6, 0.1]),
              "normals": np.float32([[0, 0, 1], [0, 1, 0], [1, 0, 0]])}
    exact = {"edge_ids": np.array([5, 7]), "s": np.float32([0.5, 0.3]), "normals": np.float32([[1, 0, 0], [0, 0, 1]])}
    model = _ConstantSegments()
    # fitted flags, exact s: edge 5 takes the exact s; 2 and 9 (false hits) keep the network's
    hybrid = method.hybrid_grid(fitted, exact, ("s",), model, 16)
    np.testing.assert_array_equal(hybrid["edge_ids"], [2, 5, 9])
    np.testing.assert_array_equal(hybrid["s"], np.float32([0.9, 0.5, 0.1]))
    np.testing.assert_array_equal(hybrid["normals"], fitted["normals"])
    # exact flags, fitted s and normals: edge 7 (missed by the network) is evaluated by it
    hybrid = method.hybrid_grid(fitted, exact, ("flags",), model, 16)
    np.testing.assert_array_equal(hybrid["edge_ids"], [5, 7])
    assert hybrid["s"][0] == np.float32(0.6) and hybrid["s"][1] == pytest.approx(0.25, abs=1e-3)
    np.testing.assert_allclose(np.abs(hybrid["normals"][1]), [1, 0, 0], atol=1e-6)
    # every component exact: the exact field itself
    hybrid = method.hybrid_grid(fitted, exact, ("flags", "s", "normals"), model, 16)
    for key in exact:
        np.testing.assert_array_equal(hybrid[key], exact[key])
    errors = method.component_errors(fitted, exact, 16)
    assert (errors["hit_edges"], errors["false_hit_edges"], errors["missed_edges"]) == (1, 2, 1)
    assert errors["s_error_h"] == pytest.approx(0.1) and errors["normal_error_deg"] == pytest.approx(90.0)


@pytest.mark.slow
def test_every_exact_component_reproduces_the_oracle_result_exactly(tmp_path):
    """A decomposed neural run and an oracle run of one built-in shape: each method's row with every
    component exact has the oracle job's metrics and face count, bit for bit."""
    from runner.cli import main

    from methods.base import available_methods

    # every method with components (sdf-ndc extracts the sdf fit; it needs NDC's weights)
    methods = tuple(m for m in ("bof", "sdf", "sdf-ndc", "udf", "sals") if m in available_methods())
    common = ["--methods", *methods, "--limit", "1", "--grid", "32", "--eval-points", "20000", "--executor", "local",
              "--quiet", "--cache-dir", str(tmp_path / "cache")]
    assert main(["--budget", "tiny-grid", "--decompose", "--out", str(tmp_path / "neural"), *common]) == 0
    assert main(["--mode", "oracle", "--out", str(tmp_path / "oracle"), *common]) == 0
    components = pd.read_csv(tmp_path / "neural" / "components.csv")
    oracle = pd.read_csv(tmp_path / "oracle" / "results.csv").set_index("method")
    metrics = ["cd", "nc", "f1_005", "ecd", "ef1", "n_faces"]
    for method in methods:
        rows = components[components["method"] == method]
        assert list(rows["exact"]) == ["+".join(p) for p in METHODS.get(method).decompositions()]
        every = rows.iloc[-1]
        for m in metrics:
            assert every[m] == oracle.loc[method, m] or (np.isnan(every[m]) and np.isnan(oracle.loc[method, m])), (method, m)
    jobs = pd.read_csv(tmp_path / "neural" / "results.csv").set_index("method")
    assert jobs.loc["sals", "hit_edges"] + jobs.loc["sals", "missed_edges"] > 0
    summary = (tmp_path / "neural" / "summary.md").read_text()
    assert "## Error decomposition" in summary and "exact flags, s, normals" in summary
    assert "Error decomposition" in (tmp_path / "neural" / "report.html").read_text()


class _PlaneEdges:
    """A stand-in segment network for the plane z = Z0: o logit +5 on edges that cross it, +1 on the
    other z-edges within one spacing of it (false hits of a blurred o), -5 elsewhere."""

    def __init__(self, z0: float, h: float):
        self.z0, self.h = z0, h

    def __call__(self, x):
        import torch

        uz, vz = x[:, 2], x[:, 5]
        crosses = (uz - self.z0) * (vz - self.z0) < 0
        near = ((uz - self.z0).abs() < self.h) & ((vz - uz).abs() > 0)
        o = torch.where(crosses, 5.0, torch.where(near, 1.0, -5.0))
        return torch.stack([o, torch.zeros_like(o)], dim=1)

    def parameters(self):
        import torch

        return iter([torch.zeros(1)])


def test_the_calibrated_o_threshold_keeps_exactly_the_edges_that_cross_the_surface():
    from foundation.fields import ExactFields
    from foundation.grid import spacing
    from methods.fields.sals import calibrated_o_threshold

    N, z0 = 32, 0.1 + 1e-3  # the plane off the grid's planes
    V = np.array([[-1.5, -1.5, z0], [1.5, -1.5, z0], [1.5, 1.5, z0], [-1.5, 1.5, z0]])  # beyond the cube
    F = np.array([[0, 1, 2], [0, 2, 3]])
    model = _PlaneEdges(z0, spacing(N))
    threshold, facts = calibrated_o_threshold(model, ExactFields(V, F), N, np.random.default_rng(0), n=20_000)
    # hits at +5, false hits at +1: the best cut lies halfway, logit 3; F1 1 there, below 1 at 0.1
    assert threshold == pytest.approx(1 / (1 + np.exp(-3.0)))
    assert facts["o_calibration_f1"] == 1.0 and facts["o_calibration_f1_paper"] < 0.8
    assert 0 < facts["o_calibration_hits"] < facts["o_calibration_edges"]
