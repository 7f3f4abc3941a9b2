"""Tests of foundation.metrics on shapes whose answers can be worked out by hand:
presets, the distance formulas, evaluate/floor on degenerate input, seeds. Sharp-edge points,
validity and the command line have their own files (tests/test_metrics_*.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh
from scipy.integrate import dblquad

from foundation import metrics as M
from foundation.seeding import job_streams


def box(side: float):
    mesh = trimesh.creation.box(extents=(side, side, side))
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def square(z: float = 0.0):
    """The unit square [0, 1]^2 at height z, two triangles."""
    v = np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.9)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)


def metric_values(result: dict) -> dict:
    return {k: v for k, v in result.items() if k != "seconds"}


# ---------------------------------------------------------------- presets


def test_presets_are_data_with_the_spec_values():
    d, n = M.PRESETS["default"], M.PRESETS["ndc"]
    assert (d.n_points, d.frame, d.chamfer, d.f1_thresholds, d.edge_radius, d.ef1_threshold) == (
        1_000_000, "canonical", "l1_half_mean", (0.005, 0.01), 0.004, 0.005)
    assert d.f1_keys == ("f1_005", "f1_01") and d.report_scale["cd"] == 1e3 and d.report_scale["ecd"] == 1e2
    assert (n.n_points, n.frame, n.chamfer, n.f1_thresholds, n.empty_edge_fallback) == (
        100_000, "diag1", "squared_sum", (0.003,), 486)
    assert n.f1_keys == ("f1_003",) and n.report_scale["cd"] == 1e5 and n.report_scale["ecd"] == 100
    with pytest.raises(Exception):
        d.n_points = 5  # frozen
    assert list(M.PRESETS) == ["default", "ndc", "scene"] and "ndc" in M.PRESETS
    with pytest.raises(ValueError, match="^unknown metric preset 'nd'; known metric presets: default, ndc, scene$"):
        M.evaluate(*box(2.0), *box(2.0), preset="nd", n_points=10)


# ---------------------------------------------------------------- analytic distances


def test_parallel_squares_offset_delta_give_cd_delta():
    """GT: unit square at z = 0; prediction: the same square at z = delta.

    Every prediction sample is at height delta above the GT plane, so its distance to the nearest GT
    sample is sqrt(delta^2 + s^2) >= delta, s being the in-plane gap to that sample (and the same
    holds the other way). With n samples per unit area, E[s^2] ~ 1/(pi n), so
    CD = mean sqrt(delta^2 + s^2) is within delta * (1 + 1/(2 pi n delta^2)) = delta * 1.0003 of
    delta for n = 200k, delta = 0.05. All distances exceed 0.01, so F1@0.005 = F1@0.01 = 0 exactly;
    all normals are parallel, so NC = 1 exactly. The ndc preset's squared sum is >= 2 delta^2.
    """
    delta = 0.05
    gv, gf = square(0.0)
    pv, pf = square(delta)
    r = M.evaluate(gv, gf, pv, pf, n_points=200_000, seed=1)
    assert delta <= r["cd"] <= delta * 1.001
    assert delta <= r["cd_gt_to_pred"] <= delta * 1.001 and delta <= r["cd_pred_to_gt"] <= delta * 1.001
    assert r["f1_005"] == 0.0 and r["f1_01"] == 0.0
    assert r["nc"] == pytest.approx(1.0, abs=1e-12)
    # flat squares: no sharp-edge points at all -> ECD 0, EF1 1 by definition
    assert r["gt_edge_points"] == 0 and r["ecd"] == 0.0 and r["ef1"] == 1.0
    # same pair under the ndc preset (frame: GT bbox centred, diagonal sqrt(2) -> 1)
    q = M.evaluate(gv, gf, pv, pf, preset="ndc", n_points=50_000, seed=1)
    d1 = delta / math.sqrt(2)
    assert 2 * d1**2 <= q["cd"] <= 2 * d1**2 * 1.01


def test_cube_against_concentric_scaled_cube_matches_the_analytic_chamfer():
    """GT: cube of half-side a = 0.5; prediction: concentric cube of half-side A = a + delta, delta = 0.05.

    gt -> pred: a GT point (a, y, z) with |y|, |z| <= a is at distance A - a = delta from the face
    x = A, and at least A - |y| >= delta from any other face: the mean distance is exactly delta.
    pred -> gt: a point (A, y, z) of a prediction face is at distance
    sqrt(delta^2 + (|y| - a)_+^2 + (|z| - a)_+^2) from the GT cube. Averaging over the face (all six
    faces are alike, y, z uniform on [-A, A]) and splitting the square at |y| = a and |z| = a:
        mean = [delta a^2 + 2 a int_0^delta sqrt(delta^2 + s^2) ds + int int_[0,delta]^2 sqrt(delta^2+s^2+t^2)] / A^2
             = [delta a^2 + a delta^2 (sqrt 2 + asinh 1) + c delta^3] / A^2,
    c = int int_[0,1]^2 sqrt(1 + s^2 + t^2) ds dt = 1.28079 (numerical quadrature); = 0.0513375.
    CD = (0.05 + 0.0513375) / 2 = 0.0506687. Sampling adds ~E[s^2]/(2 delta) ~ 0.3% (see the squares
    test), so compare within 1%.
    """
    a, delta = 0.5, 0.05
    big_a = a + delta
    c = dblquad(lambda t, s: math.sqrt(1 + s * s + t * t), 0, 1, 0, 1)[0]
    pred_to_gt = (delta * a**2 + a * delta**2 * (math.sqrt(2) + math.asinh(1)) + c * delta**3) / big_a**2
    assert pred_to_gt == pytest.approx(0.0513375, rel=1e-5)
    gv, gf = box(2 * a)
    pv, pf = box(2 * big_a)
    r = M.evaluate(gv, gf, pv, pf, n_points=200_000, seed=0)
    assert r["cd_gt_to_pred"] == pytest.approx(delta, rel=0.01)
    assert r["cd_pred_to_gt"] == pytest.approx(pred_to_gt, rel=0.01)
    assert r["cd"] == pytest.approx(0.5 * (delta + pred_to_gt), rel=0.01)
    assert r["f1_005"] == 0.0 and r["f1_01"] == 0.0  # every distance >= delta = 0.05


def test_identical_meshes_score_the_floor_and_f1_rises_with_n():
    v, f = box(2.0)
    results = [M.floor(v, f, n_points=n, seed=0) for n in (10_000, 100_000, 300_000)]
    assert metric_values(results[-1]) == metric_values(M.evaluate(v, f, v, f, n_points=300_000, seed=0))
    cds = [r["cd"] for r in results]
    f1s = [r["f1_005"] for r in results]
    assert cds[0] > cds[1] > cds[2] > 0  # the floor shrinks like 1/sqrt(n)
    assert f1s[0] < f1s[1] < f1s[2] and results[-1]["f1_01"] > 0.95
    # ~0.5/sqrt(density) on area 24: cd ~ 0.5 * sqrt(24 / n) within a factor 2
    assert 0.25 * math.sqrt(24 / 300_000) < cds[2] < 1.0 * math.sqrt(24 / 300_000)
    assert results[-1]["nc"] > 0.99


# ---------------------------------------------------------------- the ndc preset, by hand


def test_ndc_formulas_on_a_hand_worked_example():
    """GT samples g1 = (0,0,0), g2 = (1,0,0); prediction samples p1 = (0,0,0.1), p2 = (1,0,0.002).
    Nearest distances: g1 -> p1 0.1, g2 -> p2 0.002, and the same back.
    ndc: CD = mean d^2 + mean d^2 = 2 * (0.01 + 0.000004) / 2 = 0.010004; F1@0.003: P = R = 1/2 -> 0.5.
    default: CD = (0.051 + 0.051) / 2 = 0.051; F1@0.005 = 0.5, F1@0.01 = 0.5.
    NC: normals g1 (0,0,1), g2 (0,0,1); p1 (0,0,-1) (flipped: |dot| = 1), p2 (0,0.6,0.8) (|dot| = 0.8):
    NC = ((1 + 0.8) / 2 + (1 + 0.8) / 2) / 2 = 0.9."""
    g = np.array([[0, 0, 0], [1, 0, 0]], dtype=float)
    p = np.array([[0, 0, 0.1], [1, 0, 0.002]])
    ng = np.array([[0, 0, 1], [0, 0, 1]], dtype=float)
    npred = np.array([[0, 0, -1], [0, 0.6, 0.8]])
    ndc = M.surface_metrics(g, ng, p, npred, "ndc")
    assert ndc["cd"] == pytest.approx(0.010004, abs=1e-12)
    assert ndc["f1_003"] == pytest.approx(0.5) and ndc["nc"] == pytest.approx(0.9)
    default = M.surface_metrics(g, ng, p, npred, "default")
    assert default["cd"] == pytest.approx(0.051, abs=1e-12)
    assert default["f1_005"] == pytest.approx(0.5) and default["f1_01"] == pytest.approx(0.5)


def test_ndc_edge_metrics_and_the_486_origin_points():
    """GT edge points e1 = (0.3, 0.4, 0), e2 = (0, 0, 1); prediction edge points: none.
    ndc replaces them by 486 copies of the origin: gt -> pred d^2 = |e|^2 = 0.25, 1 (mean 0.625);
    pred -> gt: each origin copy is 0.5 from e1 (d^2 = 0.25, mean 0.25). ECD = 0.875. No distance is
    below 0.005, so EF1 = 0. The default preset gives ECD = NaN with the flag and EF1 = 0.
    With prediction edge points (0.3, 0.4, 0.004) and (0, 0, 1): d = 0.004, 0 both ways:
    ndc ECD = 2 * (0.000016 + 0) / 2 = 0.000016 and EF1@0.005 = 1; default ECD (in a frame with
    D = 1) = (0.002 + 0.002) / 2 = 0.002, EF1 = 1."""
    gt_e = np.array([[0.3, 0.4, 0.0], [0.0, 0.0, 1.0]])
    none = np.zeros((0, 3))
    ndc = M.edge_metrics(gt_e, none, "ndc")
    assert ndc["ecd"] == pytest.approx(0.875) and ndc["ef1"] == 0.0 and ndc["ecd_flag"] is True
    default = M.edge_metrics(gt_e, none, "default", gt_diagonal=1.0)
    assert math.isnan(default["ecd"]) and default["ef1"] == 0.0 and default["ecd_flag"] is True
    pred_e = np.array([[0.3, 0.4, 0.004], [0.0, 0.0, 1.0]])
    assert M.edge_metrics(gt_e, pred_e, "ndc")["ecd"] == pytest.approx(0.000016)
    assert M.edge_metrics(gt_e, pred_e, "ndc")["ef1"] == 1.0
    got = M.edge_metrics(gt_e, pred_e, "default", gt_diagonal=1.0)
    assert got["ecd"] == pytest.approx(0.002) and got["ef1"] == 1.0
    # the default EF1 threshold scales with D: at D = 0.5, tau_e = 0.0025 < 0.004 -> recall 1/2
    assert M.edge_metrics(gt_e, pred_e, "default", gt_diagonal=0.5)["ef1"] == pytest.approx(0.5)
    # GT without edge points: ECD 0, EF1 1 whatever the prediction
    assert M.edge_metrics(none, pred_e, "ndc")["ecd"] == 0.0 and M.edge_metrics(none, none)["ef1"] == 1.0


def test_ndc_frame_is_gt_bbox_centred_with_diagonal_one():
    # a 2 x 2 x 2 cube vs the same cube shifted by 0.02 along x: in the diag-1 frame the shift is
    # 0.02 / (2 sqrt 3); the edge radius there is the absolute 0.004
    v, f = box(2.0)
    r = M.evaluate(v, f, v + [0.02, 0, 0], f, preset="ndc", n_points=20_000)
    assert r["gt_diagonal"] == pytest.approx(1.0) and r["edge_radius"] == 0.004 and r["ef1_threshold"] == 0.005
    assert set(r) >= {"cd", "nc", "f1_003", "ecd", "ef1"} and "f1_005" not in r


# ---------------------------------------------------------------- degenerate predictions


@pytest.mark.parametrize("kind", ["no_faces", "nan_vertices", "zero_area", "bad_indices"])
def test_empty_or_degenerate_prediction_gives_nan_and_flags(kind):
    v, f = box(2.0)
    if kind == "no_faces":
        pv, pf = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    elif kind == "nan_vertices":
        pv, pf = np.full_like(v, np.nan), f
    elif kind == "zero_area":
        pv, pf = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2.0]]), np.array([[0, 1, 2]])
    else:
        pv, pf = v, f + 100
    r = M.evaluate(v, f, pv, pf, n_points=5000)
    assert r["empty_prediction"] is True
    assert math.isnan(r["cd"]) and math.isnan(r["nc"]) and math.isnan(r["ecd"])
    assert r["f1_005"] == 0.0 and r["f1_01"] == 0.0 and r["ef1"] == 0.0 and r["pred_edge_points"] == 0
    assert r["n_faces"] == len(pf)
    if kind in ("nan_vertices", "bad_indices"):
        assert r["dropped_faces"] == 12


def test_partly_nan_prediction_drops_only_those_faces():
    v, f = box(2.0)
    pv = v.copy()
    pv[0] = np.nan  # vertex 0 is used by some faces of the box
    r = M.evaluate(v, f, pv, f, n_points=5000)
    used_by_0 = int(np.any(f == 0, axis=1).sum())
    assert r["empty_prediction"] is False and r["dropped_faces"] == used_by_0 and np.isfinite(r["cd"])


def test_prediction_without_edge_points_default_nan_flag():
    v, f = box(2.0)
    sv, sf = sphere()
    r = M.evaluate(v, f, sv, sf, n_points=50_000)
    assert r["gt_edge_points"] > 0 and r["pred_edge_points"] == 0
    assert math.isnan(r["ecd"]) and r["ecd_flag"] is True and r["ef1"] == 0.0 and np.isfinite(r["cd"])
    q = M.evaluate(v, f, sv, sf, preset="ndc", n_points=20_000)  # ndc: 486 origin points instead
    assert q["ecd_flag"] is True and np.isfinite(q["ecd"]) and q["ef1"] == 0.0


@pytest.mark.filterwarnings("error")
def test_a_prediction_2_to_the_1000_times_too_large_is_scored_not_called_empty():
    """GT: cube [-1, 1]^3; prediction: the same cube scaled by s = 2^1000 (~1e301): a valid, absurdly
    large mesh, not "EMPTY or degenerate" (its cross products must not overflow).
    Relative to s the GT is a point at the origin: pred -> gt is the mean distance of a point
    uniform on a face of the cube [-s, s]^3 from the origin, s * int int_[0,1]^2 sqrt(1 + y^2 + z^2)
    = 1.28079 s (quadrature, see the concentric-cubes test); gt -> pred lies in [s - sqrt 3, sqrt 3 s]
    and, with 20k samples on the faces, within 1% of s. Every distance exceeds 0.01: F1 = 0."""
    v, f = box(2.0)
    s = 2.0**1000
    c = dblquad(lambda t, u: math.sqrt(1 + u * u + t * t), 0, 1, 0, 1)[0]
    r = M.evaluate(v, f, v * s, f, n_points=20_000)
    assert r["empty_prediction"] is False and r["dropped_faces"] == 0
    assert r["cd_pred_to_gt"] / s == pytest.approx(c, rel=0.01)
    assert 1.0 <= r["cd_gt_to_pred"] / s <= 1.01
    assert r["f1_005"] == 0.0 and r["f1_01"] == 0.0
    # ndc's squared CD of such a prediction exceeds float64: inf, and still no warning
    assert M.evaluate(v, f, v * s, f, preset="ndc", n_points=5_000)["cd"] == math.inf


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("exponent", [-1000, 1000])
def test_ndc_scores_a_pair_at_2_to_the_1000_or_its_inverse_exactly_like_at_1(exponent):
    """ndc maps both meshes by the GT's box, so scaling GT and prediction by a power of two (exact)
    must not change one bit: the diagonal of a 2^-1000 box must not underflow to 0 ("GT bounding
    box has zero size") nor that of a 2^1000 box overflow."""
    v, f = box(2.0)
    pv = v * 1.01 + 0.003
    unit = metric_values(M.evaluate(v, f, pv, f, preset="ndc", n_points=5_000))
    scale = 2.0**exponent
    assert metric_values(M.evaluate(v * scale, f, pv * scale, f, preset="ndc", n_points=5_000)) == unit


def test_a_prediction_whose_faces_lie_on_a_line_is_empty():
    """Area 0.5e-14 on a box of side 1: below MIN_RELATIVE_AREA (1e-12) of its own size, so a line
    up to rounding, not sampled (its total area > 0) into points with meaningless normals."""
    v, f = box(2.0)
    sliver = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-14, 0]])
    r = M.evaluate(v, f, sliver, [[0, 1, 2]], n_points=5_000)
    assert r["empty_prediction"] is True and math.isnan(r["cd"]) and r["f1_005"] == 0.0 and r["dropped_faces"] == 0


def test_a_degenerate_gt_is_one_line():
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float)
    with pytest.raises(ValueError, match=r"^GT mesh is degenerate: total area 0 x its largest bounding-box side "
                                         r"squared \(below 1e-12: its faces lie on a line or a point\)$"):
        M.evaluate(line, [[0, 1, 2]], *box(2.0), n_points=100)


def test_nearest_distances_of_points_near_1e300_are_exact_not_inf():
    """(0, 0, 0) and (3, 4, 0) scaled by 2^1000: distance 5 * 2^1000 (its square overflows)."""
    s = 2.0**1000
    d, i = M.nearest_distances(np.array([[0.0, 0.0, 0.0]]) * s, np.array([[3.0, 4.0, 0.0], [30.0, 0.0, 0.0]]) * s)
    assert d.tolist() == [5 * s] and i.tolist() == [0]


# ---------------------------------------------------------------- determinism


def test_same_seed_same_numbers_other_seed_other_numbers():
    v, f = box(2.0)
    pv = v * 1.01
    a = M.evaluate(v, f, pv, f, n_points=20_000, seed=5)
    b = M.evaluate(v, f, pv, f, n_points=20_000, seed=5)
    c = M.evaluate(v, f, pv, f, n_points=20_000, seed=6)
    assert metric_values(a) == metric_values(b)
    assert a["cd"] != c["cd"]


def test_a_seed_sequence_seeds_like_its_int_and_ignores_earlier_spawns():
    """``SeedSequence(5)`` spawns the same two children as the int 5, so the numbers are equal; a
    SeedSequence that already spawned children (as the run layer's job stream may have) still gives
    the same numbers, because evaluate rebuilds it from its state. The result records its state."""
    v, f = box(2.0)
    pv = v * 1.01
    as_int = M.evaluate(v, f, pv, f, n_points=20_000, seed=5)
    sequence = np.random.SeedSequence(5)
    first = M.evaluate(v, f, pv, f, n_points=20_000, seed=sequence)
    sequence.spawn(3)  # a caller used the same sequence for something else in between
    second = M.evaluate(v, f, pv, f, n_points=20_000, seed=sequence)
    drop = ("seconds", "seed")
    assert {k: x for k, x in first.items() if k not in drop} == {k: x for k, x in as_int.items() if k not in drop}
    assert metric_values(second) == metric_values(first)
    assert first["seed"] == "SeedSequence(entropy=5, spawn_key=(), pool_size=4)" and as_int["seed"] == 5
    # the run layer's metric stream of (shape, seed): a spawned child, recorded with its spawn key
    stream = job_streams("shape-a", 5).metrics
    r = M.floor(v, f, n_points=5_000, seed=stream)
    assert r["seed"] == f"SeedSequence(entropy={stream.entropy}, spawn_key=(2,), pool_size=4)"
    assert metric_values(M.floor(v, f, n_points=5_000, seed=stream)) == metric_values(r)
    json.dumps(r)  # JSON-able as it is


@pytest.mark.parametrize("seed", [-1, 1.5, "7", True])
def test_a_seed_that_is_neither_a_non_negative_int_nor_a_seed_sequence_is_refused(seed):
    v, f = box(2.0)
    with pytest.raises(ValueError, match="^seed must be a non-negative int or a numpy.random.SeedSequence, got "):
        M.evaluate(v, f, v, f, n_points=100, seed=seed)


def test_a_prediction_without_a_gt_gets_its_validity_only():
    """A tetrahedron: 4 faces, closed (0 boundary, 0 non-manifold edges, 1 component); no metric key,
    scored False; a mesh of points on a line is empty; evaluate() says scored True."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    r = M.evaluate_without_gt(V, F)
    assert r["scored"] is False and r["empty_prediction"] is False and r["dropped_faces"] == 0
    assert (r["n_faces"], r["boundary_edges"], r["nonmanifold_edges"], r["components"], r["watertight"]) == (4, 0, 0, 1, True)
    assert not {"cd", "nc", "ecd", "ef1", "f1_005"} & set(r)
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float)
    assert M.evaluate_without_gt(line, [[0, 1, 2]])["empty_prediction"] is True
    assert M.evaluate_without_gt(np.zeros((0, 3)), np.zeros((0, 3)))["n_faces"] == 0
    assert M.evaluate(V, F, V, F, n_points=2000)["scored"] is True


def test_the_scene_preset_scores_in_metres():
    """A square of side 0.5 units and its copy 0.015 units above, at 2 m per unit: a 1 m square and
    its copy 3 cm above, so CD = 0.03 m up to the samples' spacing (2 mm at 200k points), F1 is 0 at
    2 cm and 1 at 5 and 10 cm."""
    V = 0.5 * np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    r = M.evaluate(V, F, V + [0, 0, 0.015], F, preset="scene", n_points=200_000, metres_per_unit=2.0)
    assert r["cd"] == pytest.approx(0.03, rel=2e-3)
    assert (r["f1_02"], r["f1_05"], r["f1_1"]) == (0.0, 1.0, 1.0)
    assert r["gt_diagonal"] == pytest.approx(np.sqrt(2))
    with pytest.raises(ValueError, match="scores in metres: the shape states no metres per unit"):
        M.evaluate(V, F, V, F, preset="scene", n_points=1000)


def test_the_gt_samples_reused_for_a_second_prediction_give_the_numbers_it_gets_alone():
    """Every method of a shape is scored against the same GT samples, which a process computes
    once: a prediction scored after another equals, to the bit, its scores in a fresh process."""
    import importlib

    evaluate_module = importlib.import_module("foundation.metrics.evaluate")
    gt = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    first = trimesh.creation.box(extents=(1.02, 0.6, 0.4))
    second = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    evaluate_module._GT_MEMO.clear()
    M.evaluate(gt.vertices, gt.faces, first.vertices, first.faces, n_points=20000, seed=3)
    assert len(evaluate_module._GT_MEMO) == 1
    after_first = M.evaluate(gt.vertices, gt.faces, second.vertices, second.faces, n_points=20000, seed=3)
    evaluate_module._GT_MEMO.clear()
    alone = M.evaluate(gt.vertices, gt.faces, second.vertices, second.faces, n_points=20000, seed=3)
    after_first.pop("seconds"), alone.pop("seconds")
    assert after_first.keys() == alone.keys()
    for key, value in alone.items():
        assert after_first[key] == value or (value != value and after_first[key] != after_first[key]), key
    other_seed = M.evaluate(gt.vertices, gt.faces, second.vertices, second.faces, n_points=20000, seed=4)
    assert other_seed["cd"] != alone["cd"] and len(evaluate_module._GT_MEMO) == 2
