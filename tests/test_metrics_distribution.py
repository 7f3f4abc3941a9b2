"""The distance distribution (foundation.metrics.distances.distance_distribution) and the precision
and recall of every F1 threshold, on cases worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from foundation import metrics as M
from tests.test_metrics import square

KEYS = ("dist_median", "dist_p90", "dist_p99", "hausdorff")


def big_square(z: float = 0.0):
    """[-1, 1]^2 at height z (area 4), two triangles."""
    v = np.array([[-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_the_pooled_quantiles_and_the_maximum_on_ten_distances():
    """d(g -> P) = 0, 1, 2, 3, 4 and d(p -> G) = 5, ..., 9 pool into 0..9 (10 values). numpy's linear
    quantile q sits at position q * 9: median 4.5, p90 8.1, p99 8.91; the largest, 9."""
    got = M.distance_distribution(np.arange(5.0), np.arange(5.0, 10.0))
    assert got == pytest.approx({"dist_median": 4.5, "dist_p90": 8.1, "dist_p99": 8.91, "hausdorff": 9.0}, abs=1e-12)
    assert all(math.isnan(v) for v in M.distance_distribution(np.zeros(0), np.zeros(0)).values())


@pytest.mark.parametrize("preset", ["default", "ndc"])
def test_surface_metrics_report_the_distribution_of_the_chamfer_distances_unsquared(preset):
    """GT samples (0,0,0), (1,0,0); prediction samples (0,0,0.1), (1,0,0.002): nearest distances
    0.1 and 0.002 each way (the hand example of tests/test_metrics.py), pooled 0.002, 0.002, 0.1,
    0.1: median 0.051, p90 and p99 0.1 (positions 2.7 and 2.97, both between the two 0.1s), max 0.1;
    the same under ndc, whose CD squares them."""
    g = np.array([[0, 0, 0], [1, 0, 0]], dtype=float)
    p = np.array([[0, 0, 0.1], [1, 0, 0.002]])
    n = np.array([[0, 0, 1], [0, 0, 1]], dtype=float)
    got = M.surface_metrics(g, n, p, n, preset)
    assert {k: got[k] for k in KEYS} == pytest.approx(
        {"dist_median": 0.051, "dist_p90": 0.1, "dist_p99": 0.1, "hausdorff": 0.1}, abs=1e-12)


def test_a_square_and_its_copy_offset_by_001_along_its_normal():
    """GT [-1, 1]^2 at z = 0 and the prediction at z = 0.01, n = 100,000 samples each. Every sample's
    nearest neighbour on the other sheet is sqrt(0.01^2 + r^2), r its in-plane distance to the
    nearest sample of the other set: for uniform samples of density lam = n / 4 = 25,000 per unit
    area, P(r > x) = exp(-lam pi x^2), so the q-quantile is sqrt(0.01^2 + ln(1 / (1 - q)) / (lam pi)):
    median 0.010432, p90 0.011372, p99 0.012595 (about 0.01, over it by the sampling: no distance is
    below 0.01). Measured within 0.1% (median), 0.1% (p90), 0.3% (p99: the border, where neighbours
    are half as dense, adds a little); tolerances twice that. The Hausdorff distance is the largest
    in-plane gap of 100,000 samples: measured 0.016-0.018 over seeds 0-3, asserted in (p99, 0.025).
    CD is the mean of the same pooled distances (equal counts): between the median and p90."""
    gv, gf = big_square()
    pv, pf = big_square(0.01)
    r = M.evaluate(gv, gf, pv, pf, n_points=100_000, seed=0)
    lam = 100_000 / 4
    expect = {q: math.sqrt(0.01**2 + math.log(1 / (1 - q)) / (lam * math.pi)) for q in (0.5, 0.9, 0.99)}
    assert r["dist_median"] == pytest.approx(expect[0.5], rel=0.002)
    assert r["dist_p90"] == pytest.approx(expect[0.9], rel=0.002)
    assert r["dist_p99"] == pytest.approx(expect[0.99], rel=0.006)
    assert r["dist_p99"] < r["hausdorff"] < 0.025
    assert r["dist_median"] < r["cd"] < r["dist_p90"]


def test_identical_meshes_have_a_small_hausdorff_distance_from_sampling_alone():
    """The floor of the same square: two independent sample sets of one sheet, distances purely
    in-plane: median sqrt(ln 2 / (lam pi)) = 0.00297 (within 1%), Hausdorff the largest gap,
    below 0.025 (1.25% of the side)."""
    gv, gf = big_square()
    r = M.floor(gv, gf, n_points=100_000, seed=0)
    assert r["dist_median"] == pytest.approx(math.sqrt(math.log(2) / (25_000 * math.pi)), rel=0.01)
    assert 0.0 < r["hausdorff"] < 0.025


def test_an_empty_prediction_has_nan_distances():
    gv, gf = square()
    r = M.evaluate(gv, gf, np.zeros((0, 3)), np.zeros((0, 3)), n_points=500)
    assert r["empty_prediction"] and all(math.isnan(r[k]) for k in KEYS)


@pytest.mark.parametrize("preset, thresholds", [("default", ("005", "01")), ("ndc", ("003",))])
def test_precision_and_recall_are_reported_for_every_f1_threshold(preset, thresholds):
    """The unit square against its copy 0.004 above: every distance is at least 0.004 (0.0028 in
    ndc's frame, where the square's diagonal is 1) and, at n = 20,000 (in-plane gaps ~ 0.004), some
    are below each threshold. For each threshold of the preset: f1, precision and recall, with
    F1 = 2PR / (P + R), all in (0, 1]; an empty prediction gets 0 for all three."""
    gv, gf = square()
    pv, pf = square(0.004)
    r = M.evaluate(gv, gf, pv, pf, preset=preset, n_points=20_000)
    for t in thresholds:
        p, rec, f1 = r[f"precision_{t}"], r[f"recall_{t}"], r[f"f1_{t}"]
        assert 0.0 < p <= 1.0 and 0.0 < rec <= 1.0 and f1 == pytest.approx(2 * p * rec / (p + rec))
    empty = M.evaluate(gv, gf, np.zeros((0, 3)), np.zeros((0, 3)), preset=preset, n_points=500)
    assert all(empty[f"{k}_{t}"] == 0.0 for t in thresholds for k in ("precision", "recall", "f1"))
