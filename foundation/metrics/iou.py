"""Volumetric IoU of two closed meshes: Monte-Carlo points in the union of their bounding boxes,
inside a mesh by ray parity (embree, through trimesh's ``contains``)."""

from __future__ import annotations

import numpy as np
import trimesh

from foundation.surface import binary_exponent

__all__ = ["volumetric_iou", "IOU_POINTS"]

#: Uniform points in the union of the two bounding boxes. The estimate's standard deviation is
#: about sqrt(IoU (1 - IoU) / (N u)), u the share of the box inside either mesh: at N = 1e5, 0.0016
#: at most for u = 1, 0.005 for a part filling a tenth of its box.
IOU_POINTS = 100_000


def _inside(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Whether each point is inside a closed mesh: the parity of a ray's crossings (trimesh's
    ``contains``: embree, rays re-cast in a second direction where the first is ambiguous), so
    either orientation counts; points outside the mesh's bounding box are outside without a ray.
    (On the 24 meshes of ../shared/data it agrees point for point with libigl's winding number
    |w| > 1/2 and is 1-6x faster.)"""
    used = np.unique(faces)
    corners = vertices[used]
    faces = np.searchsorted(used, faces)  # compact: only the used vertices enter the scene
    near = np.flatnonzero(np.all((points >= corners.min(axis=0)) & (points <= corners.max(axis=0)), axis=1))
    inside = np.zeros(len(points), dtype=bool)
    if len(near):
        mesh = trimesh.Trimesh(np.ascontiguousarray(corners), np.ascontiguousarray(faces, dtype=np.int64),
                               process=False, validate=False)
        inside[near] = mesh.contains(np.ascontiguousarray(points[near]))
    return inside


def volumetric_iou(gt_vertices, gt_faces, pred_vertices, pred_faces, rng: np.random.Generator,
                   n_points: int = IOU_POINTS) -> float:
    """``|inside both| / |inside either|`` over ``n_points`` uniform points in the union of the two
    meshes' bounding boxes (of their used vertices), inside by ray parity.

    Both meshes must be closed (the caller checks: :func:`foundation.metrics.mesh_validity`'s
    ``watertight``), with in-range indices and finite vertices, so a ray's crossing parity is
    well defined (and does not depend on the orientation). Any scale:
    both meshes are rescaled by one power of two first (exact). Identical meshes (the floor) are
    queried once: IoU 1.

    Returns
    -------
    float
        The IoU in [0, 1]; NaN when no point falls inside either mesh.
    """
    gt_vertices = np.asarray(gt_vertices, dtype=np.float64)
    pred_vertices = np.asarray(pred_vertices, dtype=np.float64)
    gt_faces = np.asarray(gt_faces, dtype=np.int64).reshape(-1, 3)
    pred_faces = np.asarray(pred_faces, dtype=np.int64).reshape(-1, 3)
    same = np.array_equal(gt_vertices, pred_vertices) and np.array_equal(gt_faces, pred_faces)
    gt_used, pred_used = gt_vertices[np.unique(gt_faces)], pred_vertices[np.unique(pred_faces)]
    k = max(binary_exponent(gt_used), binary_exponent(pred_used))
    gt_vertices, pred_vertices = np.ldexp(gt_vertices, -k), np.ldexp(pred_vertices, -k)
    lo = np.ldexp(np.minimum(gt_used.min(axis=0), pred_used.min(axis=0)), -k)
    hi = np.ldexp(np.maximum(gt_used.max(axis=0), pred_used.max(axis=0)), -k)
    points = lo + (hi - lo) * rng.random((int(n_points), 3))
    in_gt = _inside(gt_vertices, gt_faces, points)
    in_pred = in_gt if same else _inside(pred_vertices, pred_faces, points)
    either = np.count_nonzero(in_gt | in_pred)
    return float(np.count_nonzero(in_gt & in_pred) / either) if either else float("nan")
