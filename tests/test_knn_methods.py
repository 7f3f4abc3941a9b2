"""The three learned reconstruction methods (methods/pointcloud/knn/sals_knn.py, udf_knn.py, occ_knn.py) end to end:
trained at the ``tiny`` budget on its four built-in training parts (seconds), each reconstructs a
held-out cube from a raw cloud within a stated Chamfer bound, and does clearly better than its
untrained network.

The held-out shape is an axis-aligned box 1.2 x 1.0 x 0.8 centred at the origin: no built-in part is
a plain box (every part is cut, drilled or extruded), so it is unseen. Input: ``tiny``'s
``points_per_item`` (10,000) area-uniform points, seed 0, the density the networks trained at;
grid 32 (h = 0.065). CD-L1 (GT <-> prediction, 20k samples each).

A ``tiny`` training is 400 steps of a 32-wide network: on another seed or another CPU float path it
lands elsewhere, so each test trains three networks (seeds ``fit_seed`` to ``fit_seed + 2``) and
bounds their *median* CD. Spread of single trainings over seeds 0-4 x float paths (default, avx2,
native) x 1 and 2 threads (scripts/measure_learned_spread.py, docs/spread/learned.md), and of the
median of three consecutive seeds (the quantity asserted), which every bound keeps a margin of at
least 1.2 over (completeness: CD's GT -> prediction side; on the measuring machine the avx2 and
native paths gave the same numbers, the thread count did not):

  ============  ===================  ======================  ===================  =================
  method        single training CD   median of 3 trainings   median completeness  untrained control
  ============  ===================  ======================  ===================  =================
  occ-knn       0.049-0.126          0.057-0.108             0.032-0.099          0.221-0.265
  sals-knn      0.011-0.034          0.012-0.031             0.011-0.013          0.074-0.081
  udf-knn       0.011-0.015          0.011-0.015             0.012-0.018          0.064-0.128
  ============  ===================  ======================  ===================  =================

* ``udf-knn``: CD <= 0.02 (under a third of h: a reconstruction with spurious sheets in the 4h
  query band, or one a voxel off the box, exceeds it) and completeness <= 0.022. Grid 32 rather
  than 64 because the MeshUDF face filter keeps a face only where the network's UDF is below h/6:
  at grid 64 (h/6 = 0.0053) the ``tiny`` UDF network, biased to ~0.008 on the surface after 400 steps, loses
  all but 593 faces (CD 0.089).
* ``sals-knn``: completeness <= 0.016 (the networks find the box's faces) and CD <= 0.037:
  a ``tiny`` segment network sometimes marks band edges off the surface as hit (seeds 1 and 2 on
  torch's scalar kernels with 2 threads: accuracy side 0.048-0.053, CD 0.030-0.034), and a single
  training reached CD 0.021 on another machine.
* ``occ-knn``: CD <= 0.13. A purely local encoder cannot tell the inside of a flat patch from its
  outside (the K neighbours of a point at +d and at -d from a face look the same), so the band's
  occupancy is ambiguous and marching cubes leaves sheets inside the band, more or fewer from one
  training to the next (0.042 with the ``cpu`` network on the same cube at 40k points and grid 64,
  against 0.0042 for sals-knn and 0.0041 for udf-knn there: the unsigned representations need no
  sign). A single ``tiny`` training reached CD 0.164 on another machine.

The untrained control (the same architecture at its initial weights, seed ``fit_seed``, eval mode)
must score at least twice the trained median (occ-knn: 1.5 times; measured at least 2.4, 4.4 and
2.0 times for sals-knn, udf-knn, occ-knn), so each bound checks what training taught
(an untrained udf-knn network may also give no face at all).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from foundation.metrics import evaluate
from foundation.surface import sample_surface
from methods.base import get_method
from methods.pointcloud.knn.network import make_knn_network
from methods.pointcloud.knn.training import KNN_BUDGETS
from methods.pointcloud.knn.training import train
from methods.pointcloud.training_set import training_shapes

pytestmark = pytest.mark.usefixtures("torch_threads")

GRID = 32
TINY = KNN_BUDGETS.get("tiny")
TRAININGS = 3
CD_BOUND = {"sals-knn": 0.037, "udf-knn": 0.02, "occ-knn": 0.13}
COMPLETENESS_BOUND = {"sals-knn": 0.016, "udf-knn": 0.022}
#: The untrained control's CD over the trained median must exceed this.
CONTROL_RATIO = {"sals-knn": 2.0, "udf-knn": 2.0, "occ-knn": 1.5}


@pytest.fixture(scope="module")
def cube():
    box = trimesh.creation.box(extents=(1.2, 1.0, 0.8))
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    points, _ = sample_surface(V, F, TINY.points_per_item, np.random.default_rng(0))
    return V, F, points


@pytest.fixture(scope="module")
def parts():
    return training_shapes(TINY.training_shapes)


def _scores(method, model, cube) -> dict:
    """CD-L1 and its two sides (GT -> prediction: completeness; prediction -> GT: accuracy), faces."""
    V, F, points = cube
    out = method.reconstruct(points, GRID, model=model)
    r = evaluate(V, F, out.vertices, out.faces, n_points=20_000)
    return {"cd": r["cd"], "completeness": r["cd_gt_to_pred"], "accuracy": r["cd_pred_to_gt"], "faces": len(out.faces)}


@pytest.mark.learned
@pytest.mark.parametrize("name", sorted(CD_BOUND))
@pytest.mark.slow
def test_tiny_training_reconstructs_a_held_out_cube_within_the_bound(name, parts, cube, fit_seed, measured):
    method = get_method(name)
    cds, completeness = [], []
    for seed in range(fit_seed, fit_seed + TRAININGS):
        score = _scores(method, train(method, parts, TINY, seed=seed).model, cube)
        measured(training_seed=seed, **score)
        assert score["faces"] > 0, f"{name}: the network of seed {seed} gave no face"
        cds.append(score["cd"])
        completeness.append(score["completeness"])
    torch.manual_seed(fit_seed)
    untrained = make_knn_network(method.network_kind, out_dim=method.output_dim, **TINY.network_config()).eval()
    untrained.knn_k = TINY.k
    control = _scores(method, untrained, cube)
    cd = float(np.median(cds))
    assert cd <= CD_BOUND[name], f"{name}: median CD {cd:.4f} > {CD_BOUND[name]} (trainings: {np.round(cds, 4)})"
    if name in COMPLETENESS_BOUND:
        assert np.median(completeness) <= COMPLETENESS_BOUND[name], (name, np.round(completeness, 4))
    assert control["faces"] == 0 or control["cd"] > CONTROL_RATIO[name] * cd, \
        f"{name}: the untrained control scores CD {control['cd']:.4f} against a trained median of {cd:.4f}"
