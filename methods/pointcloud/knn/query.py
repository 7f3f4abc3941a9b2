"""Grid queries of the K-NN reconstruction networks: the network on grid points or edges near the
input cloud (the band of :mod:`methods.pointcloud.neighbourhoods`), each query with its K nearest
input points.

A query's K neighbours come from one KD-tree query over all queries (``knn_neighbourhoods``), then
the network runs in chunks (:func:`chunk_size` queries, eval mode; the KD-tree query is timed as the
sub-stage ``knn`` of the caller's stage); with ``grad_output`` it also returns
the gradient of that output w.r.t. the query's anchor coordinates (the neighbours held fixed).
"""

from __future__ import annotations

import numpy as np
import torch

from foundation.timing import stage
from methods.pointcloud.neighbourhoods import knn_neighbourhoods

#: Queries per forward pass, by device type. Each query carries K point features through the
#: encoders, so a chunk's activations are ``chunk x K x width`` floats: on a CPU the pass is bound by
#: cache, not arithmetic, and small chunks are fastest (docs/PERFORMANCE.md, section 10). A GPU
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
