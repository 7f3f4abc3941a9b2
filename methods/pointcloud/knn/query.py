"""Grid queries of the K-NN reconstruction networks: which grid points and edges
lie near the input cloud, and the network on them with the neighbourhoods of the cloud.

Only queries near the cloud are evaluated: grid points (or edge midpoints) within ``radius`` of
their nearest input point (the paper: 4 h); everything farther is "no surface". The band is found
by marking the voxels holding input points, dilating them by ``ceil(radius / h) + 1`` grid steps
(scipy.ndimage) and keeping the candidates whose exact KD-tree distance is within the radius.
A query's K neighbours come from one KD-tree query over all queries (``knn_neighbourhoods``), then
the network runs in chunks (:func:`chunk_size` queries, eval mode; the KD-tree query is timed as the
sub-stage ``knn`` of the caller's stage); with ``grad_output`` it also returns
the gradient of that output w.r.t. the query's anchor coordinates (the neighbours held fixed).
"""

from __future__ import annotations

import numpy as np
import torch
from pykdtree.kdtree import KDTree
from scipy import ndimage

from benchmark.grid import LOWER, spacing
from benchmark.timing import stage
from methods.pointcloud.knn.network import knn_neighbourhoods
from benchmark.grid import edge_inputs, edges_in_points, point_inputs

#: Queries per forward pass, by device type. Each query carries K point features through the
#: encoders, so a chunk's activations are ``chunk x K x width`` floats: on a CPU the pass is bound by
#: cache, not arithmetic, and small chunks are fastest (docs/PERFORMANCE.md, section 8). A GPU
#: wants large chunks.
CHUNK = {"cpu": 256, "cuda": 16_384}
DEFAULT_CHUNK = 4_096


def chunk_size(device) -> int:
    """Queries per forward pass on ``device`` (:data:`CHUNK`, else :data:`DEFAULT_CHUNK`)."""
    return CHUNK.get(torch.device(device).type, DEFAULT_CHUNK)


def knn_k(model) -> int:
    """The neighbour count K a K-NN network was trained with (its ``knn_k`` attribute, set by
    whoever trains or loads it from its budget)."""
    k = getattr(model, "knn_k", None)
    if k is None:
        raise ValueError("a K-NN network needs its training neighbour count (model.knn_k); none set")
    return int(k)


def nearest_distance(cloud: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Distance (Q,) float64 of each query to its nearest point of ``cloud``."""
    if len(queries) == 0:
        return np.zeros(0)
    dist, _ = KDTree(np.asarray(cloud, dtype=np.float64)).query(np.asarray(queries, dtype=np.float64), k=1)
    return np.asarray(dist, dtype=np.float64).reshape(-1)


def near_cloud_mask(cloud: np.ndarray, N: int, radius: float) -> np.ndarray:
    """(N, N, N) bool: grid points within ``radius`` (canonical units) of the cloud, plus the points
    of the dilation margin that the exact test then decides (module docstring)."""
    h = spacing(N)
    ijk = np.clip(np.rint((np.asarray(cloud) - LOWER) / h).astype(np.int64), 0, N - 1)
    mask = np.zeros((N, N, N), dtype=bool)
    mask[tuple(ijk.T)] = True
    steps = int(np.ceil(radius / h)) + 1
    ball = np.linalg.norm(np.indices((2 * steps + 1,) * 3) - steps, axis=0) <= steps
    return ndimage.binary_dilation(mask, structure=ball)


def band_points(cloud: np.ndarray, N: int, radius: float) -> np.ndarray:
    """Integer indices (n, 3) of the grid points within ``radius`` of the cloud."""
    ijk = np.argwhere(near_cloud_mask(cloud, N, radius))
    return ijk[nearest_distance(cloud, point_inputs(N, ijk)) <= radius]


def band_edges(cloud: np.ndarray, N: int, radius: float) -> np.ndarray:
    """Flat ids of the grid edges whose midpoint lies within ``radius`` of the cloud."""
    ids = np.flatnonzero(edges_in_points(N, near_cloud_mask(cloud, N, radius + spacing(N))))
    ends = edge_inputs(N, ids).reshape(-1, 2, 3)
    return ids[nearest_distance(cloud, ends.mean(axis=1)) <= radius]


def evaluate_knn(model, anchors: np.ndarray, cloud: np.ndarray, k: int, device=None,
                 grad_output: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The K-NN network on ``anchors`` ((Q, 3) points or (Q, 2, 3) segments) with their ``k``
    nearest points of ``cloud`` (of the point, or of the segment's midpoint): outputs (Q, out)
    float32, and with ``grad_output`` the gradient of that output w.r.t. the anchors (same shape as
    ``anchors``), else None."""
    anchors = np.ascontiguousarray(anchors, dtype=np.float32)
    centres = anchors.mean(axis=1) if anchors.ndim == 3 else anchors
    cloud32 = np.ascontiguousarray(cloud, dtype=np.float32)
    with stage("knn"):
        index = knn_neighbourhoods(cloud, centres, k) if len(anchors) else np.zeros((0, k), np.int64)
    device = device or next(model.parameters()).device
    outs, grads = [], []
    chunk = chunk_size(device)
    for i in range(0, len(anchors), chunk):
        a = torch.from_numpy(anchors[i:i + chunk]).to(device)
        q = torch.from_numpy(cloud32[index[i:i + chunk]]).to(device)
        if grad_output is None:
            with torch.inference_mode():
                outs.append(model(a, q).float().cpu().numpy())
            continue
        with torch.enable_grad():
            a.requires_grad_(True)
            y = model(a, q)
            (g,) = torch.autograd.grad(y[:, grad_output].sum(), a)
        outs.append(y.detach().float().cpu().numpy())
        grads.append(g.float().cpu().numpy())
    out_dim = model.config.get("out_dim", 1)
    out = np.concatenate(outs) if outs else np.zeros((0, out_dim), np.float32)
    if grad_output is None:
        return out, None
    return out, (np.concatenate(grads) if grads else np.zeros_like(anchors))
