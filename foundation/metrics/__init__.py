"""Surface metrics between a ground-truth and a predicted triangle mesh.

Protocol (preset ``default``, all lengths in the canonical frame of the GT):

* Sample ``n`` points area-uniformly on each mesh (:func:`foundation.surface.sample_surface`), each
  with the unit normal of the face it came from. GT and prediction use two independent streams spawned from one
  seed, so every prediction of a shape is scored against the same GT samples.
* Nearest neighbours by KD-tree in both directions (pykdtree, exact): ``d(g -> P)`` for every GT
  sample ``g`` and ``d(p -> G)`` for every predicted sample ``p``.
* **CD** (Chamfer-L1) ``= 1/2 (mean_g d(g -> P) + mean_p d(p -> G))``, unsquared; tables x 1e3.
* **NC** ``= 1/2 (mean_g |n_g . n_nn(g)| + mean_p |n_p . n_nn(p)|)`` (orientation-agnostic).
* **F1@tau**: precision ``P = #{p : d(p -> G) < tau} / n_pred``, recall
  ``R = #{g : d(g -> P) < tau} / n_gt``, ``F1 = 2PR / (P + R)`` (0 when both are 0); tau = 0.005, 0.01;
  each threshold's P and R are reported too (``precision_005``, ``recall_005``, ...).
* **Distance distribution**: the same nearest distances, both directions pooled (2n values):
  ``dist_median``, ``dist_p90``, ``dist_p99`` and ``hausdorff`` (the largest), unsquared.
* **IoU** (both meshes watertight, else NaN): ``|inside both| / |inside either|`` over 100,000
  uniform points in the union of the two bounding boxes (child 2 of the seed), inside where
  ``|winding number| > 1/2`` (libigl's fast winding number; :mod:`~foundation.metrics.iou`).
* **Sharp-edge points** (Neural Dual Contouring's test): a sample ``p`` is an edge point when a sample
  ``q`` of the same mesh lies within ``r`` of it (``|p - q| <= r``) with ``|n_p . n_q| < 0.2``;
  ``r = 0.004 D`` with ``D`` the GT bounding-box diagonal (:func:`sharp_edge_points`).
* **ECD** = the CD formula between the two edge-point sets (tables x 1e2); **EF1** = F1 at
  ``tau_e = 0.005 D``. GT without edge points: ECD = 0, EF1 = 1. Prediction without edge points
  (GT has some): ECD = NaN with ``ecd_flag`` set, EF1 = 0.

Preset ``ndc`` reproduces NDC's evaluation script (Chen et al. 2022, ``eval_cd_nc_f1_ecd_ef1.py``):
both meshes mapped to the frame where the GT bounding box is centred with diagonal 1, n = 100,000,
CD = ``mean_g d^2 + mean_p d^2`` (squared, summed, tables x 1e5), F1@0.003, edge radius 0.004,
ECD squared and summed (tables x 100), EF1@0.005, and 486 points at the origin standing in for the
prediction's edge points when it has none. Presets are data (:class:`MetricPreset`), not code paths.

The raw values are returned (never scaled); :attr:`MetricPreset.report_scale` gives the table
multipliers. Predictions that are empty or degenerate (no usable face, or faces that lie on a line
or a point relative to their own size) never raise: their distance metrics are NaN, F1/EF1 are 0
and ``empty_prediction`` is set. Any scale works (1e-300 to 1e300: exact power-of-two rescales,
:mod:`foundation.surface`). Mesh validity (vertex/face counts, boundary and non-manifold edges,
components, watertightness, Euler characteristic, genus when watertight) is counted on the
prediction's faces *as given*, vertices not merged (:func:`mesh_validity`); its self-intersecting
face pairs by libigl's exact search (:func:`self_intersections`). A prediction without a GT (a point
cloud reconstructed with no mesh beside it) gets only those counts, ``scored`` False
(:func:`evaluate_without_gt`).

Modules: :mod:`~foundation.metrics.presets` (protocols as data), :mod:`~foundation.metrics.distances`
(CD, NC, F1, ECD, EF1 on point sets), :mod:`~foundation.metrics.edges` (sharp-edge points),
:mod:`~foundation.metrics.validity` (topology counts), :mod:`~foundation.metrics.self_intersections`,
:mod:`~foundation.metrics.iou` (volumetric IoU), :mod:`~foundation.metrics.evaluate` (meshes
in, one result row out), ``__main__`` (the command line: ``python -m foundation.metrics GT PRED
[--points N] [--preset default|ndc] [--seed S] [--json] [--no-normalize]``).
"""

from foundation.metrics.distances import (distance_distribution, edge_metrics, nearest_distances, spatial_order,
                                         surface_metrics)
from foundation.metrics.edges import MAX_EDGE_PAIRS, MAX_NORMAL_GROUPS, EdgeSearchTooDense, sharp_edge_points
from foundation.metrics.evaluate import evaluate, evaluate_without_gt, floor
from foundation.metrics.iou import IOU_POINTS, volumetric_iou
from foundation.metrics.presets import PRESETS, HeadlineMetric, MetricPreset, f1_column
from foundation.metrics.self_intersections import self_intersections
from foundation.metrics.validity import mesh_validity

__all__ = [
    "MetricPreset",
    "HeadlineMetric",
    "f1_column",
    "PRESETS",
    "evaluate",
    "evaluate_without_gt",
    "floor",
    "sharp_edge_points",
    "EdgeSearchTooDense",
    "MAX_NORMAL_GROUPS",
    "MAX_EDGE_PAIRS",
    "nearest_distances",
    "spatial_order",
    "surface_metrics",
    "edge_metrics",
    "distance_distribution",
    "mesh_validity",
    "self_intersections",
    "volumetric_iou",
    "IOU_POINTS",
]
