"""Volumetric IoU (foundation.metrics.iou) on shapes whose overlap is known exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from foundation import metrics as M
from foundation.metrics.evaluate import _sampling_streams
from tests.test_metrics import box, square

N = M.IOU_POINTS  # 100,000


def unit_cube(shift=(0.0, 0.0, 0.0)):
    v, f = box(1.0)
    return v + np.asarray(shift), f


def test_a_unit_cube_and_its_copy_shifted_by_half_a_side_have_iou_one_third():
    """Cubes [-0.5, 0.5]^3 and [0, 1] x [-0.5, 0.5]^2: both 1, overlap 0.5, union 1.5: IoU 1/3. The
    union of the boxes, [-0.5, 1] x [-0.5, 0.5]^2 (1.5), is all inside either mesh, so the
    estimate is a binomial share of N points: sigma = sqrt((1/3)(2/3) / N) = 0.0015; within 3 sigma."""
    gv, gf = unit_cube()
    pv, pf = unit_cube((0.5, 0.0, 0.0))
    iou = M.volumetric_iou(gv, gf, pv, pf, np.random.default_rng(0), N)
    sigma = math.sqrt((1 / 3) * (2 / 3) / N)
    assert abs(iou - 1 / 3) < 3 * sigma
    # the same through evaluate (its own stream: child 2 of the seed; min(IOU_POINTS, n) points)
    r = M.evaluate(gv, gf, pv, pf, n_points=2000, seed=4)
    assert abs(r["iou"] - 1 / 3) < 3 * math.sqrt((1 / 3) * (2 / 3) / 2000)


def test_identical_meshes_give_1_disjoint_ones_0_and_an_inverted_prediction_the_same():
    """Identical: the same points inside both, IoU 1 exactly (the floor row too). Cubes 2 apart:
    no point inside both, 0. The shifted cube with every face reversed (inward orientation, winding
    number -1 inside): |w| > 1/2 is inside either way, so the same points and the same IoU."""
    gv, gf = unit_cube()
    assert M.volumetric_iou(gv, gf, gv, gf, np.random.default_rng(1), 1000) == 1.0
    assert M.floor(gv, gf, n_points=2000)["iou"] == 1.0
    far_v, far_f = unit_cube((2.0, 0.0, 0.0))
    assert M.volumetric_iou(gv, gf, far_v, far_f, np.random.default_rng(1), 10_000) == 0.0
    pv, pf = unit_cube((0.5, 0.0, 0.0))
    outward = M.volumetric_iou(gv, gf, pv, pf, np.random.default_rng(2), 10_000)
    inward = M.volumetric_iou(gv, gf, pv, pf[:, ::-1], np.random.default_rng(2), 10_000)
    assert inward == outward


def test_a_sphere_inside_a_cube_gives_the_volume_ratio():
    """An icosphere of radius 0.4 (volume V_s, trimesh's exact polyhedron volume) inside the cube
    [-0.5, 0.5]^3: IoU = V_s / 1. Union box = the cube, so again binomial: within 3 sigma."""
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    gv, gf = unit_cube()
    iou = M.volumetric_iou(gv, gf, s.vertices, s.faces, np.random.default_rng(3), N)
    expected = s.volume  # ~0.264, a little under 4/3 pi 0.4^3 = 0.268
    assert abs(iou - expected) < 3 * math.sqrt(expected * (1 - expected) / N)


def test_iou_is_scale_free_an_exact_power_of_two_rescale_gives_the_same_number():
    """[-0.5, 0.5]^3 and [0, 1] x [-0.25, 0.75] x [-0.5, 0.5]: overlap 0.5 * 0.75 * 1 = 0.375, union
    2 - 0.375 = 1.625, IoU 0.375 / 1.625 = 0.2308. The union of the boxes (1.5 x 1.25 x 1 = 1.875) is
    inside either mesh with share u = 1.625 / 1.875: sigma = sqrt(J (1 - J) / (N u)). Both meshes at
    2^900 (~8e270) are rescaled by one power of two inside: the same points, the same IoU."""
    gv, gf = unit_cube()
    pv, pf = unit_cube((0.5, 0.25, 0.0))
    one = M.volumetric_iou(gv, gf, pv, pf, np.random.default_rng(5), N)
    big = M.volumetric_iou(np.ldexp(gv, 900), gf, np.ldexp(pv, 900), pf, np.random.default_rng(5), N)
    expected, u = 0.375 / 1.625, 1.625 / 1.875
    assert big == one and abs(one - expected) < 3 * math.sqrt(expected * (1 - expected) / (N * u))


def test_a_non_closed_gt_or_prediction_gives_nan():
    """evaluate computes the IoU only when both meshes are watertight and no face was dropped."""
    gv, gf = unit_cube()
    open_pred = gf[:-2]  # one side's two triangles removed: 4 boundary edges
    r = M.evaluate(gv, gf, gv, open_pred, n_points=2000)
    assert r["watertight"] is False and math.isnan(r["iou"]) and math.isfinite(r["cd"])
    sv, sf = square()
    r = M.evaluate(sv, sf, gv, gf, n_points=2000)  # an open GT
    assert math.isnan(r["iou"])
    bad = np.vstack([gv, [[np.nan, 0, 0]]])  # closed by indices, one face on a NaN vertex: dropped
    faces = gf.copy()
    faces[0, 0] = 8
    assert math.isnan(M.evaluate(gv, gf, bad, faces, n_points=2000)["iou"])
    assert math.isnan(M.evaluate(gv, gf, np.zeros((0, 3)), np.zeros((0, 3)), n_points=500)["iou"])


def test_the_iou_points_come_from_a_third_child_so_the_samples_are_unchanged():
    """Children 0 and 1 of the three-way spawn are those of the two-way spawn the samples always came
    from (same spawn keys), so every other metric keeps its value; child 2 is another stream."""
    for seed in (0, 7, np.random.SeedSequence(11, spawn_key=(2,))):
        gt, pred, iou, _ = _sampling_streams(seed)
        root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        two = [np.random.default_rng(s).random(4) for s in root.spawn(2)]
        assert np.array_equal(gt.random(4), two[0]) and np.array_equal(pred.random(4), two[1])
        assert not np.array_equal(iou.random(4), two[0])


def test_iou_is_the_same_for_the_same_seed_and_another_draw_for_another():
    gv, gf = unit_cube()
    pv, pf = unit_cube((0.5, 0.0, 0.0))
    a, b, c = (M.evaluate(gv, gf, pv, pf, n_points=500, seed=s)["iou"] for s in (3, 3, 4))
    assert a == b and a != c


@pytest.mark.parametrize("preset", ["default", "ndc"])
def test_iou_does_not_depend_on_the_preset_frame(preset):
    """ndc maps both meshes by one similarity (x - c) / D: volumes scale alike, the IoU is 1/3 in both
    (evaluate draws min(IOU_POINTS, n) = 20,000 points here)."""
    gv, gf = unit_cube()
    pv, pf = unit_cube((0.5, 0.0, 0.0))
    r = M.evaluate(gv, gf, pv, pf, preset=preset, n_points=20_000)
    assert abs(r["iou"] - 1 / 3) < 3 * math.sqrt((1 / 3) * (2 / 3) / 20_000)
