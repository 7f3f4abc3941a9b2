"""Distance metrics between point sets: CD, NC, F1 and the distribution of the nearest distances
(median, p90, p99, Hausdorff) on surface samples and ECD, EF1 on sharp-edge points, each in the
form its :class:`~foundation.metrics.presets.MetricPreset` states. Nearest neighbours are exact
(pykdtree, k = 1)."""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree

from foundation.metrics.presets import MetricPreset, get_preset
from foundation.surface import binary_exponent

__all__ = ["spatial_order", "nearest_distances", "distance_distribution", "surface_metrics", "edge_metrics"]


def spatial_order(points: np.ndarray, cells_per_axis: int = 256) -> np.ndarray:
    """A permutation listing the points cell by cell (x-major cells of a 256^3 grid on their bbox).

    KD-tree queries on spatially sorted points are faster (cache locality) than on the random order
    that sampling produces; metrics are order-independent, so :func:`evaluate` sorts.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = points.min(axis=0)
    size = float(np.max(points.max(axis=0) - lo))
    scale = cells_per_axis / size if size > 0 else 0.0
    ijk = np.minimum(((points - lo) * scale).astype(np.int64), cells_per_axis - 1)
    keys = (ijk[:, 0] * cells_per_axis + ijk[:, 1]) * cells_per_axis + ijk[:, 2]
    return np.argsort(keys, kind="stable")


def nearest_distances(query: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Euclidean distance from every query point to its nearest reference point, and its index.

    Exact k = 1 search with pykdtree (multi-threaded, deterministic), on both sets rescaled by one
    power of two (:func:`foundation.surface.binary_exponent`: exact, so the distances equal the
    unscaled ones, and squared distances of points at 1e300 do not overflow).

    Parameters
    ----------
    query : (m, 3) array_like
    reference : (r, 3) array_like, r >= 1
        Points in one frame (any unit).

    Returns
    -------
    d : (m,) float64 ndarray
        Distances, in the points' unit.
    idx : (m,) int64 ndarray
        Index into ``reference`` of each query point's nearest neighbour.
    """
    reference = np.ascontiguousarray(reference, dtype=np.float64)
    query = np.ascontiguousarray(query, dtype=np.float64)
    k = max(binary_exponent(reference), binary_exponent(query))
    dist, idx = KDTree(np.ldexp(reference, -k)).query(np.ldexp(query, -k), k=1)
    return np.ldexp(np.asarray(dist, dtype=np.float64), k), np.asarray(idx, dtype=np.int64)


def _chamfer(d_gt_to_pred: np.ndarray, d_pred_to_gt: np.ndarray, form: str) -> tuple[float, float, float]:
    """(total, gt->pred term, pred->gt term) for the chamfer ``form``; inf where a term exceeds
    the float64 range (a squared distance of 1e200, say)."""
    with np.errstate(over="ignore"):
        if form == "l1_half_mean":
            a, b = float(np.mean(d_gt_to_pred)), float(np.mean(d_pred_to_gt))
            return 0.5 * (a + b), a, b
        a, b = float(np.mean(np.square(d_gt_to_pred))), float(np.mean(np.square(d_pred_to_gt)))
        return a + b, a, b


def _f1(d_gt_to_pred: np.ndarray, d_pred_to_gt: np.ndarray, tau: float) -> tuple[float, float, float]:
    """(F1, precision, recall) at threshold tau, strict ``d < tau``."""
    recall = float(np.mean(d_gt_to_pred < tau))
    precision = float(np.mean(d_pred_to_gt < tau))
    f1 = 2.0 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return f1, precision, recall


def distance_distribution(d_gt_to_pred: np.ndarray, d_pred_to_gt: np.ndarray) -> dict:
    """The distribution of the nearest distances of both directions pooled into one set (the
    distances CD averages): ``dist_median``, ``dist_p90``, ``dist_p99`` (numpy's linear
    quantiles) and ``hausdorff`` (the largest: the symmetric Hausdorff distance of the two point
    sets), in the distances' unit, never squared. NaN for an empty set."""
    pooled = np.concatenate([np.ravel(d_gt_to_pred), np.ravel(d_pred_to_gt)]).astype(np.float64, copy=False)
    if len(pooled) == 0:
        return dict.fromkeys(("dist_median", "dist_p90", "dist_p99", "hausdorff"), float("nan"))
    median, p90, p99 = np.quantile(pooled, [0.5, 0.9, 0.99])
    return {"dist_median": float(median), "dist_p90": float(p90), "dist_p99": float(p99),
            "hausdorff": float(pooled.max())}


def surface_metrics(gt_points, gt_normals, pred_points, pred_normals, preset: str | MetricPreset = "default") -> dict:
    """CD, NC, F1 and the distance distribution between two oriented point sets (already in the
    preset's frame).

    Returns ``cd`` (preset's chamfer form), ``cd_gt_to_pred`` and ``cd_pred_to_gt`` (its two terms:
    means of d or d^2), ``nc``, per threshold ``f1_*``, ``precision_*``, ``recall_*``, and
    :func:`distance_distribution` of the same nearest distances (``dist_median``, ``dist_p90``,
    ``dist_p99``, ``hausdorff``: unsquared whatever the chamfer form).
    """
    preset = get_preset(preset)
    d_gp, i_gp = nearest_distances(gt_points, pred_points)
    d_pg, i_pg = nearest_distances(pred_points, gt_points)
    out = {}
    out["cd"], out["cd_gt_to_pred"], out["cd_pred_to_gt"] = _chamfer(d_gp, d_pg, preset.chamfer)
    nc_gp = np.mean(np.abs(np.einsum("ij,ij->i", gt_normals, pred_normals[i_gp])))
    nc_pg = np.mean(np.abs(np.einsum("ij,ij->i", pred_normals, gt_normals[i_pg])))
    out["nc"] = float(0.5 * (nc_gp + nc_pg))
    for tau, key in zip(preset.f1_thresholds, preset.f1_keys):
        suffix = key[3:]
        out[key], out[f"precision_{suffix}"], out[f"recall_{suffix}"] = _f1(d_gp, d_pg, tau)
    out.update(distance_distribution(d_gp, d_pg))
    return out


def edge_metrics(gt_edge_points, pred_edge_points, preset: str | MetricPreset = "default", gt_diagonal: float = 1.0) -> dict:
    """ECD and EF1 between two edge-point sets (in the preset's frame).

    ``gt_diagonal`` is D, the GT bounding-box diagonal, used when ``preset.edge_units`` is
    'gt_diagonal' (tau_e = ef1_threshold * D). Rules: GT without edge points -> ECD 0, EF1 1;
    prediction without edge points -> ``empty_edge_fallback`` origin points if the preset has one,
    else ECD NaN and EF1 0. ``ecd_flag`` is True when the prediction has no edge points but the GT
    has some. Returns ``ecd, ef1, eprecision, erecall, ecd_flag``.
    """
    preset = get_preset(preset)
    gt_edge_points = np.asarray(gt_edge_points, dtype=np.float64).reshape(-1, 3)
    pred_edge_points = np.asarray(pred_edge_points, dtype=np.float64).reshape(-1, 3)
    unit = gt_diagonal if preset.edge_units == "gt_diagonal" else 1.0
    if len(gt_edge_points) == 0:
        return {"ecd": 0.0, "ef1": 1.0, "eprecision": 1.0, "erecall": 1.0, "ecd_flag": False}
    flag = len(pred_edge_points) == 0
    if flag:
        if preset.empty_edge_fallback <= 0:
            return {"ecd": float("nan"), "ef1": 0.0, "eprecision": 0.0, "erecall": 0.0, "ecd_flag": True}
        pred_edge_points = np.zeros((preset.empty_edge_fallback, 3))
    d_gp, _ = nearest_distances(gt_edge_points, pred_edge_points)
    d_pg, _ = nearest_distances(pred_edge_points, gt_edge_points)
    ecd, _, _ = _chamfer(d_gp, d_pg, preset.ecd)
    ef1, eprecision, erecall = _f1(d_gp, d_pg, preset.ef1_threshold * unit)
    return {"ecd": ecd, "ef1": ef1, "eprecision": eprecision, "erecall": erecall, "ecd_flag": flag}

