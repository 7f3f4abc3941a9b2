"""SALS's line segment field: its labels from the exact fields, its loss and its normals, shared
by every method that learns it (the per-shape ``sals`` field and the K-NN network ``sals-knn``).

A segment (u, v) in the canonical frame is labelled o (1 when it crosses the surface, else 0) and s
(the hit point is s u + (1 - s) v, in [0, 1]); the network predicts two logits, o_hat = sigmoid(out_0)
and s_hat = sigmoid(out_1).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

#: Weight of the s term.
S_WEIGHT = 10.0


def segment_targets(fields, segments: np.ndarray) -> dict[str, np.ndarray]:
    """SALS labels of segments (M, 2, 3) from the exact fields: o (hit, 0/1) and s (hit point
    s u + (1 - s) v), float32."""
    hit, s, _ = fields.segments(segments[:, 0], segments[:, 1])
    return {"o": hit.astype(np.float32), "s": s.astype(np.float32)}


def segment_loss(prediction, targets):
    """``10 * mean_{o = 1} |sigmoid(s logit) - s| + BCE(o logit, o)``."""
    o = targets["o"]
    bce = F.binary_cross_entropy_with_logits(prediction[:, 0], o)
    s_err = (torch.sigmoid(prediction[:, 1]) - targets["s"]).abs()
    return S_WEIGHT * (s_err * o).sum() / o.sum().clamp(min=1.0) + bce


def nearer_endpoint_normals(s: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Unit normals from the gradient of s w.r.t. the endpoints (E, 6): d s/d u where s > 0.5 (the
    hit is nearer u), else d s/d v; zero where the gradient vanishes."""
    g = np.where((s > 0.5)[:, None], grad[:, :3], grad[:, 3:])
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    return np.divide(g, norm, out=np.zeros_like(g), where=norm > 0)


def band_field(model, N: int, o_low: float, device=None, stride: int | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A fitted segment network on the grid edges near the surface (the sparse edge query of
    :func:`methods.core.query.sparse_grid_edges`: blocks whose coarse edges have o_hat > ``o_low``):
    ``(edge_ids (E,) int64 sorted, o_hat (E,) float32, s_hat (E,) float32, query fraction)`` of every
    edge the query evaluated."""
    from scipy.special import expit

    from methods.core import query

    low = float(np.log(o_low / (1.0 - o_low)))
    out, evaluated, info = query.sparse_grid_edges(model, N, lambda values: values[:, 0] > low, device,
                                                   stride=query.DEFAULT_STRIDE if stride is None else stride,
                                                   edge_fill=np.array([-30.0, 0.0], dtype=np.float32))
    ids = np.flatnonzero(evaluated)
    o = expit(out[ids, 0].astype(np.float64)).astype(np.float32)
    s = expit(out[ids, 1].astype(np.float64)).astype(np.float32)
    return ids, o, s, info.fraction
