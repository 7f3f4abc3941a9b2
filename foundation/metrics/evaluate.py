"""``evaluate``: every metric of a predicted mesh against a GT mesh, and ``floor``,
the protocol's noise floor (the GT against an independent resample of itself)."""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from foundation.metrics.distances import edge_metrics, spatial_order, surface_metrics
from foundation.metrics.edges import EdgeSearchTooDense, sharp_edge_points
from foundation.metrics.iou import IOU_POINTS, volumetric_iou
from foundation.metrics.presets import MetricPreset, get_preset
from foundation.metrics.self_intersections import self_intersections
from foundation.metrics.validity import mesh_validity
from foundation.surface import MIN_RELATIVE_AREA, binary_exponent, relative_area, sample_surface
from foundation.timing import StageTimer

__all__ = ["evaluate", "floor"]

Seed = int | np.random.SeedSequence


def _sampling_streams(seed: Seed) -> tuple[np.random.Generator, np.random.Generator, np.random.Generator, int | str]:
    """The GT, prediction and IoU generators (children 0, 1 and 2 of the seed's SeedSequence) and
    the seed as the result records it (the int itself; for a SeedSequence, its state as a string).
    Children 0 and 1 of a three-way spawn are those of a two-way spawn (the same spawn keys), so the
    IoU's points changed no number drawn before it existed.

    A SeedSequence is rebuilt from its entropy, spawn key and pool size before spawning, so the
    streams do not depend on how many children it spawned before this call."""
    if isinstance(seed, np.random.SeedSequence):
        root = np.random.SeedSequence(seed.entropy, spawn_key=seed.spawn_key, pool_size=seed.pool_size)
        record = f"SeedSequence(entropy={seed.entropy}, spawn_key={seed.spawn_key}, pool_size={seed.pool_size})"
    elif isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)) and seed >= 0:
        root, record = np.random.SeedSequence(int(seed)), int(seed)
    else:
        raise ValueError(f"seed must be a non-negative int or a numpy.random.SeedSequence, got {seed!r}")
    gt_stream, pred_stream, iou_stream = (np.random.default_rng(s) for s in root.spawn(3))
    return gt_stream, pred_stream, iou_stream, record


def _bbox(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used = vertices[np.unique(faces)]
    return used.min(axis=0), used.max(axis=0)


def _diagonal(lo: np.ndarray, hi: np.ndarray) -> float:
    """``|hi - lo|`` on a power-of-two rescale of the box (exact: no overflow at 1e300, no
    underflow at 1e-300); inf only when the diagonal itself exceeds the float64 range."""
    k = binary_exponent(np.stack([lo, hi]))
    with np.errstate(over="ignore"):
        return float(np.ldexp(np.linalg.norm(np.ldexp(hi, -k) - np.ldexp(lo, -k)), k))


def _usable_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces with in-range indices and finite vertex coordinates (the rest are dropped)."""
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or vertices.ndim != 2 or len(vertices) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    ok = np.all((faces >= 0) & (faces < len(vertices)), axis=1)
    finite = np.all(np.isfinite(vertices), axis=1)
    ok[ok] = np.all(finite[faces[ok]], axis=1)
    return faces[ok]


def _check_gt(vertices: np.ndarray, faces: np.ndarray) -> None:
    """One-line ValueError for a GT that cannot be scored against."""
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError("GT mesh has no triangles")
    if len(_usable_faces(vertices, faces)) != len(faces):
        raise ValueError("GT mesh has out-of-range face indices or non-finite vertices")
    area = relative_area(vertices, faces)
    if not area >= MIN_RELATIVE_AREA:
        raise ValueError(f"GT mesh is degenerate: total area {area:.3g} x its largest bounding-box side squared "
                         f"(below {MIN_RELATIVE_AREA:g}: its faces lie on a line or a point)")


@dataclass(frozen=True)
class _GTSamples:
    """What :func:`evaluate` computes from the GT alone: its samples (spatially ordered) with their
    normals, their sharp-edge mask (None when the search was refused, with ``edge_search_error``)
    and whether the GT mesh is watertight."""

    points: np.ndarray
    normals: np.ndarray
    edges: np.ndarray | None
    edge_search_error: str
    watertight: bool


#: The GT sides of the last few evaluations in this process: every method of a shape and seed is
#: scored against the same GT samples, so the second and later jobs of a shape reuse them.
_GT_MEMO: OrderedDict[str, _GTSamples] = OrderedDict()
_GT_MEMO_SIZE = 2


def _gt_samples(vertices: np.ndarray, faces: np.ndarray, n: int, stream: np.random.Generator, seed_record,
                radius: float, dot_threshold: float) -> _GTSamples:
    """The GT side of :func:`evaluate` (``stream``: the GT's sampling generator of ``seed_record``),
    from the memo when this process has computed it for the same mesh, sample count, seed and edge
    test: the same arrays either way (the sampling is a function of the seed)."""
    h = hashlib.sha256(np.ascontiguousarray(vertices).tobytes())
    h.update(np.ascontiguousarray(faces).tobytes())
    h.update(repr((n, str(seed_record), float(radius), float(dot_threshold))).encode())
    key = h.hexdigest()
    if key in _GT_MEMO:
        _GT_MEMO.move_to_end(key)
        return _GT_MEMO[key]
    points, normals = sample_surface(vertices, faces, n, stream)
    order = spatial_order(points)
    points, normals = points[order], normals[order]
    try:
        edges, error = sharp_edge_points(points, normals, radius, dot_threshold), ""
    except EdgeSearchTooDense as exc:
        edges, error = None, str(exc)
    for array in (points, normals, edges):
        if array is not None:
            array.setflags(write=False)
    gt = _GTSamples(points, normals, edges, error, bool(mesh_validity(vertices, faces)["watertight"]))
    _GT_MEMO[key] = gt
    while len(_GT_MEMO) > _GT_MEMO_SIZE:
        _GT_MEMO.popitem(last=False)
    return gt


def evaluate(
    gt_vertices,
    gt_faces,
    pred_vertices,
    pred_faces,
    preset: str | MetricPreset = "default",
    seed: Seed = 0,
    n_points: int | None = None,
    metres_per_unit: float | None = None,
) -> dict:
    """All the metrics of a prediction against a GT mesh. Never raises on the prediction.

    Parameters
    ----------
    gt_vertices, gt_faces : (V, 3) float and (F, 3) int array_like
        The GT mesh, in the GT's canonical frame for the ``default`` preset (used as given); for
        ``ndc`` both meshes are first mapped by ``x -> (x - c) / D`` (c, D: GT bounding-box centre
        and diagonal).
    pred_vertices, pred_faces : array_like
        The prediction, in the same frame; anything goes (empty, NaN, out-of-range indices).
    preset : str or MetricPreset
        The protocol (:data:`PRESETS` name or a preset).
    seed : int >= 0 or numpy.random.SeedSequence
        GT samples come from child 0, prediction samples from child 1 and the IoU's points from
        child 2 of ``SeedSequence(seed)``
        for an int, or of the SeedSequence itself (the run layer passes
        ``foundation.seeding.job_streams(shape_hash, seed).metrics``), rebuilt from its state first so
        its earlier spawns do not matter.
    n_points : int, optional
        Samples per mesh (default: the preset's).
    metres_per_unit : float, optional
        Metres per unit of the meshes' frame, for a preset in metres (``scene``); ignored by the
        others.

    Returns
    -------
    dict
        Flat, raw (unscaled) values in the preset's frame: ``cd, cd_gt_to_pred, cd_pred_to_gt, nc``,
        ``f1_*/precision_*/recall_*`` per threshold, ``dist_median, dist_p90, dist_p99,
        hausdorff`` (the distribution of CD's nearest distances, both directions pooled:
        :func:`~foundation.metrics.distances.distance_distribution`), ``iou`` (volumetric IoU on
        min(:data:`~foundation.metrics.iou.IOU_POINTS`, n) points, :func:`~foundation.metrics.iou.volumetric_iou`;
        NaN unless the GT and the prediction are both watertight with no dropped face),
        ``ecd, ef1, eprecision, erecall, ecd_flag``,
        ``gt_edge_points, pred_edge_points`` (counts; -1 = not computed), ``edge_search_skipped``
        ('' or why the exact edge search was refused, :class:`EdgeSearchTooDense`: ECD/EF1 are then
        NaN; happens for samples far denser than r, e.g. a prediction 100x smaller than the GT),
        ``empty_prediction`` (no usable face, or its faces lie on a line or a point: total area
        below :data:`~foundation.surface.MIN_RELATIVE_AREA` of its own bounding box's largest side
        squared, whatever its size; distance metrics NaN, F1 0), ``dropped_faces`` (faces with
        out-of-range indices or non-finite vertices, excluded from sampling), the validity columns
        of the prediction as given (:func:`mesh_validity`, with ``euler_characteristic`` and
        ``genus``), its self-intersections (:func:`~foundation.metrics.self_intersections.self_intersections`:
        ``self_intersecting_pairs, self_intersecting_faces``, NaN for an empty prediction, and
        ``self_intersections_skipped``, '' or why they were not searched), the protocol: ``preset, n_points,
        seed`` (the int, or the SeedSequence's state as a string), ``gt_diagonal, edge_radius,
        ef1_threshold`` (absolute, in the frame), ``scored`` (True: scored against a GT; see
        :func:`evaluate_without_gt`), and ``seconds``: ``<stage>_s`` wall-clock seconds
        per stage and ``total_s``.

    Raises
    ------
    ValueError
        Only for an unusable GT (no triangles, out-of-range indices, non-finite vertices, faces on a
        line or a point, a bounding box beyond float64), a bad ``n_points`` or ``seed``, a preset in
        metres without a positive ``metres_per_unit``.
    """
    timer = StageTimer()
    t_start = time.perf_counter()
    preset = get_preset(preset)
    n = int(preset.n_points if n_points is None else n_points)
    if n < 1:
        raise ValueError(f"n_points must be >= 1, got {n}")
    gt_stream, pred_stream, iou_stream, seed_record = _sampling_streams(seed)
    gt_vertices = np.asarray(gt_vertices, dtype=np.float64)
    gt_faces = np.asarray(gt_faces, dtype=np.int64)
    pred_vertices = np.asarray(pred_vertices, dtype=np.float64)
    pred_faces = np.asarray(pred_faces)
    pred_faces = pred_faces.astype(np.int64) if pred_faces.size else np.zeros((0, 3), dtype=np.int64)
    if pred_vertices.size == 0:
        pred_vertices = np.zeros((0, 3))

    _check_gt(gt_vertices, gt_faces)
    if preset.frame == "metres":
        if not (metres_per_unit is not None and np.isfinite(metres_per_unit) and metres_per_unit > 0):
            raise ValueError(f"metric preset '{preset.name}' scores in metres: the shape states no metres per "
                             f"unit (a scene dataset such as 'street' does)")
        with np.errstate(over="ignore", invalid="ignore"):
            gt_vertices, pred_vertices = gt_vertices * metres_per_unit, pred_vertices * metres_per_unit
    lo, hi = _bbox(gt_vertices, gt_faces)
    if preset.frame == "diag1":
        diag = _diagonal(lo, hi)
        with np.errstate(over="ignore", invalid="ignore"):  # a prediction beyond float64 there: inf, dropped
            centre = 0.5 * (lo + hi)
            gt_vertices = (gt_vertices - centre) / diag
            pred_vertices = (pred_vertices - centre) / diag
            lo, hi = (lo - centre) / diag, (hi - centre) / diag
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError(f"GT bounding box (diagonal {diag:.3g}) is beyond the float64 range")
    gt_diagonal = _diagonal(lo, hi)
    if not np.isfinite(gt_diagonal):
        raise ValueError("GT bounding-box diagonal is beyond the float64 range: normalise the GT first")
    unit = gt_diagonal if preset.edge_units == "gt_diagonal" else 1.0
    radius, tau_e = preset.edge_radius * unit, preset.ef1_threshold * unit

    with timer.stage("validity"):
        validity = mesh_validity(pred_vertices, pred_faces)
        usable = _usable_faces(pred_vertices, pred_faces)
        empty = not relative_area(pred_vertices, usable) >= MIN_RELATIVE_AREA

    with timer.stage("sample"):
        gt = _gt_samples(gt_vertices, gt_faces, n, gt_stream, seed_record, radius, preset.edge_dot_threshold)
        gt_points, gt_normals = gt.points, gt.normals
        if empty:
            pred_points = pred_normals = np.zeros((0, 3))
        else:
            pred_points, pred_normals = sample_surface(pred_vertices, usable, n, pred_stream)
        order = spatial_order(pred_points)  # same point set, much faster KD-tree queries
        pred_points, pred_normals = pred_points[order], pred_normals[order]

    result = {"preset": preset.name, "n_points": n, "seed": seed_record}
    nan = float("nan")
    with timer.stage("distances"):
        if empty:
            result.update(cd=nan, cd_gt_to_pred=nan, cd_pred_to_gt=nan, nc=nan)
            for key in preset.f1_keys:
                result.update({key: 0.0, f"precision_{key[3:]}": 0.0, f"recall_{key[3:]}": 0.0})
            result.update(dist_median=nan, dist_p90=nan, dist_p99=nan, hausdorff=nan)
        else:
            result.update(surface_metrics(gt_points, gt_normals, pred_points, pred_normals, preset))

    with timer.stage("edge_points"):
        gt_edge, skipped = gt.edges, "" if gt.edges is not None else f"GT {gt.edge_search_error}"
        try:
            pred_edge = sharp_edge_points(pred_points, pred_normals, radius, preset.edge_dot_threshold)
        except EdgeSearchTooDense as exc:
            pred_edge, skipped = None, skipped or f"prediction {exc}"
    with timer.stage("edge_metrics"):
        if empty:
            has_gt_edges = gt_edge is None or bool(gt_edge.any())
            edges = {"ecd": nan, "ef1": 0.0, "eprecision": 0.0, "erecall": 0.0, "ecd_flag": has_gt_edges}
        elif skipped:
            edges = {"ecd": nan, "ef1": nan, "eprecision": nan, "erecall": nan, "ecd_flag": False}
        else:
            edges = edge_metrics(gt_points[gt_edge], pred_points[pred_edge], preset, gt_diagonal)
    result.update(edges)

    with timer.stage("iou"):
        closed = not empty and validity["watertight"] and len(usable) == len(pred_faces) and gt.watertight
        iou = (volumetric_iou(gt_vertices, gt_faces, pred_vertices, usable, iou_stream, min(IOU_POINTS, n))
               if closed else nan)
    with timer.stage("self_intersections"):
        crossings = _self_intersections(pred_vertices, usable, empty)
    result.update(
        gt_edge_points=-1 if gt_edge is None else int(gt_edge.sum()),
        pred_edge_points=-1 if pred_edge is None else int(pred_edge.sum()),
        edge_search_skipped=skipped,
        empty_prediction=empty,
        dropped_faces=int(len(pred_faces) - len(usable)),
    )
    result.update(validity)
    result.update(crossings, iou=iou)
    result.update(gt_diagonal=gt_diagonal, edge_radius=radius, ef1_threshold=tau_e, scored=True)
    result["seconds"] = {**timer.seconds, "total_s": time.perf_counter() - t_start}
    return result


def _self_intersections(vertices: np.ndarray, usable: np.ndarray, empty: bool) -> dict:
    """:func:`self_intersections` of the usable faces; NaN counts for an empty prediction."""
    if empty:
        return {"self_intersecting_pairs": float("nan"), "self_intersecting_faces": float("nan"),
                "self_intersections_skipped": ""}
    return self_intersections(vertices, usable)


def evaluate_without_gt(pred_vertices, pred_faces) -> dict:
    """What can be said of a prediction that has no GT (a point cloud reconstructed without a mesh
    beside it): ``scored`` False, ``empty_prediction`` (the rule of :func:`evaluate`),
    ``dropped_faces``, the validity columns of the prediction as given and its self-intersections
    (as in :func:`evaluate`); no distance, IoU or edge metric (they need a GT). Never raises."""
    t_start = time.perf_counter()
    pred_vertices = np.asarray(pred_vertices, dtype=np.float64).reshape(-1, 3)
    pred_faces = np.asarray(pred_faces)
    pred_faces = pred_faces.astype(np.int64).reshape(-1, 3) if pred_faces.size else np.zeros((0, 3), dtype=np.int64)
    usable = _usable_faces(pred_vertices, pred_faces)
    empty = not relative_area(pred_vertices, usable) >= MIN_RELATIVE_AREA
    result = {"scored": False, "empty_prediction": empty, "dropped_faces": int(len(pred_faces) - len(usable)),
              **mesh_validity(pred_vertices, pred_faces), **_self_intersections(pred_vertices, usable, empty)}
    result["seconds"] = {"total_s": time.perf_counter() - t_start}
    return result


def floor(gt_vertices, gt_faces, preset: str | MetricPreset = "default", seed: Seed = 0, n_points: int | None = None,
          metres_per_unit: float | None = None) -> dict:
    """The protocol's noise floor: the GT scored against an independent resample of itself.

    Identical to ``evaluate(gt, gt, preset, seed)``: the prediction's samples come from a
    different stream of the seed than the GT's, so the two point sets are independent draws.
    """
    return evaluate(gt_vertices, gt_faces, gt_vertices, gt_faces, preset=preset, seed=seed, n_points=n_points,
                    metres_per_unit=metres_per_unit)
